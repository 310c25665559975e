-- wrk -t2 -c64 -d60s -s deploy/load/generate.lua http://HOST:PORT/v1/generate
-- 40 frames (2 s at 20 fps) of conditioned generation per request, sampled
-- at temperature 1 with a random seed. With --workers W only W run at once;
-- the rest are answered 429 at once (the permit pool sheds load).
package.path = package.path .. ";" .. (os.getenv("LOAD_DIR") or "deploy/load") .. "/?.lua"
require("common")

wrk.method = "POST"
wrk.headers["Content-Type"] = "application/json"
local genres = {"BR", "JS"}  -- the genres the bundled model knows (the AIST++ samples)

function request()
  local body = string.format(
    '{"frames":40,"labels":{"genre":"%s"},"sampling":{"temperature":1.0,"top_k":40,"seed":%d}}',
    genres[math.random(#genres)], math.random(1, 1000000))
  return wrk.format(nil, nil, nil, body)
end
