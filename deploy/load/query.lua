-- wrk -t2 -c64 -d60s -s deploy/load/query.lua http://HOST:PORT/v1/query
-- Each request queries a random stored motion (ids from ids.lua, written by
-- run.sh) at a random start, k = 10, STFT / cosine through HNSW.
package.path = package.path .. ";" .. (os.getenv("LOAD_DIR") or "deploy/load") .. "/?.lua"
require("common")
local ids = require("ids")

wrk.method = "POST"
wrk.headers["Content-Type"] = "application/json"

function request()
  local m = ids[math.random(#ids)]
  local start = math.random() * m[2]
  local body = string.format('{"motion":{"id":%d},"start_s":%.3f,"k":10}', m[1], start)
  return wrk.format(nil, nil, nil, body)
end
