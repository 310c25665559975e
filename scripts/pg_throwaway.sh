#!/usr/bin/env bash
# A throwaway PostgreSQL from the machine's own packages, for the tests:
#   scripts/pg_throwaway.sh start DIR PORT   # initdb (trust, loopback only) + start; prints the URL
#   scripts/pg_throwaway.sh restart DIR [PAUSE_S]  # down for PAUSE_S seconds (default 0), then up:
#                                             # what the outage test does mid-load
#   scripts/pg_throwaway.sh stop DIR
# Runs initdb / pg_ctl as the `postgres` user when started as root.
set -euo pipefail
cmd=$1
dir=$2
bin=$(ls -d /usr/lib/postgresql/*/bin 2>/dev/null | sort -V | tail -1)
[ -x "$bin/initdb" ] || { echo "no PostgreSQL server here (apt-get install postgresql)" >&2; exit 2; }
as_pg() {
    if [ "$(id -u)" = 0 ]; then su postgres -s /bin/bash -c "$*"; else bash -c "$*"; fi
}
case "$cmd" in
start)
    port=$3
    mkdir -p "$dir"
    [ "$(id -u)" = 0 ] && chown postgres "$dir"
    if [ ! -f "$dir/data/PG_VERSION" ]; then
        as_pg "'$bin/initdb' -D '$dir/data' -A trust -U postgres -E UTF8 >'$dir/initdb.log'"
    fi
    as_pg "'$bin/pg_ctl' -D '$dir/data' -l '$dir/server.log' -w -o \"-p $port -k '$dir' -c listen_addresses=127.0.0.1 -c fsync=on\" start >/dev/null"
    echo "$port" >"$dir/port"
    as_pg "'$bin/createdb' -h 127.0.0.1 -p $port -U postgres choreo_test" 2>/dev/null || true
    echo "postgres://postgres@127.0.0.1:$port/choreo_test"
    ;;
restart)
    as_pg "'$bin/pg_ctl' -D '$dir/data' -w -m fast stop >/dev/null"
    sleep "${3:-0}"
    port=$(cat "$dir/port")
    as_pg "'$bin/pg_ctl' -D '$dir/data' -l '$dir/server.log' -w -o \"-p $port -k '$dir' -c listen_addresses=127.0.0.1 -c fsync=on\" start >/dev/null"
    ;;
stop)
    as_pg "'$bin/pg_ctl' -D '$dir/data' -w -m fast stop >/dev/null" || true
    ;;
*)
    echo "usage: $0 start DIR PORT | restart DIR | stop DIR" >&2
    exit 2
    ;;
esac
