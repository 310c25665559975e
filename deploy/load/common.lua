-- Shared by the wrk scripts: count responses by status in every thread and
-- print throughput, latency percentiles and the status table at the end.
local threads = {}

function setup(thread)
  table.insert(threads, thread)
end

function init(args)
  statuses = {}
end

function response(status, headers, body)
  statuses[status] = (statuses[status] or 0) + 1
end

function done(summary, latency, requests)
  local totals = {}
  for _, t in ipairs(threads) do
    for code, n in pairs(t:get("statuses")) do
      totals[code] = (totals[code] or 0) + n
    end
  end
  local secs = summary.duration / 1e6
  io.write(string.format("requests %d in %.1f s: %.1f req/s\n",
    summary.requests, secs, summary.requests / secs))
  for _, code in ipairs({200, 201, 400, 404, 429, 500, 503}) do
    if totals[code] then
      io.write(string.format("status %d: %d (%.1f/s)\n", code, totals[code], totals[code] / secs))
    end
  end
  local fives = 0
  for code, n in pairs(totals) do
    if code >= 500 then fives = fives + n end
  end
  if next(totals) == nil then
    -- A script without a response() callback (cheaper for wrk): wrk
    -- itself counts answers that are not 2xx/3xx, 5xx among them.
    io.write(string.format("status not 2xx/3xx: %d (5xx at most that)\n", summary.errors.status))
    fives = summary.errors.status
  end
  io.write(string.format("5xx: %d; socket errors: connect %d read %d write %d timeout %d\n",
    fives, summary.errors.connect, summary.errors.read, summary.errors.write,
    summary.errors.timeout))
  io.write(string.format("latency ms (all responses): p50 %.1f  p95 %.1f  p99 %.1f  max %.1f\n",
    latency:percentile(50) / 1e3, latency:percentile(95) / 1e3,
    latency:percentile(99) / 1e3, latency.max / 1e3))
end
