-- wrk -t2 -c64 -d60s -s deploy/load/query.lua http://HOST:PORT/v1/query
-- Each request queries a random stored motion (ids from ids.lua, written by
-- run.sh) at a random start, k = 10, STFT / cosine through HNSW. The
-- requests are drawn once per thread (4,096 of them, cycled) and there is
-- no response() callback: wrk's Lua work per request is then a table read,
-- so the client takes less of the two cores it shares with the server.
-- Statuses other than 2xx/3xx are still counted (by wrk; common.lua).
package.path = package.path .. ";" .. (os.getenv("LOAD_DIR") or "deploy/load") .. "/?.lua"
require("common")
local ids = require("ids")

wrk.method = "POST"
wrk.headers["Content-Type"] = "application/json"

local pool = {}
local next_request = 0

-- Each thread draws its own requests (a seed per thread, fixed so runs
-- repeat).
local common_setup = setup
local threads_made = 0
function setup(thread)
  threads_made = threads_made + 1
  thread:set("thread_no", threads_made)
  common_setup(thread)
end

function init(args)
  statuses = {}
  math.randomseed(1000 + (thread_no or 0))
  for i = 1, 4096 do
    local m = ids[math.random(#ids)]
    local start = math.random() * m[2]
    local body = string.format('{"motion":{"id":%d},"start_s":%.3f,"k":10}', m[1], start)
    pool[i] = wrk.format(nil, nil, nil, body)
  end
end

function request()
  next_request = next_request % #pool + 1
  return pool[next_request]
end

response = nil
