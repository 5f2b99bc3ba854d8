-- Write a new job's record and indexes, unless its owner already has ARGV[5] jobs pricing,
-- queued or running (0: no cap): the cap is checked and taken in this one script, so
-- simultaneous submits cannot overshoot it. Index entries whose record is gone or final are dropped on the way.
-- KEYS job, jobs, active, owner's jobs; ARGV id, owner, record JSON, created (score), cap,
-- job key prefix ("{prefix}:job:") -> the owner's active jobs before this one, or -1 - that
-- count when refused.
local cap = tonumber(ARGV[5])
local active = 0
if cap > 0 then
  local entries = redis.call('HGETALL', KEYS[3])
  for i = 1, #entries, 2 do
    if entries[i + 1] == ARGV[2] then
      local raw = redis.call('GET', ARGV[6] .. entries[i])
      -- a record starts {"id":"...","state":"..." (JobRecord's first two fields)
      local state = raw and string.match(raw, '^{"id":"%x+","state":"(%a+)"')
      if state == 'pricing' or state == 'queued' or state == 'running' then
        active = active + 1
      else
        redis.call('HDEL', KEYS[3], entries[i])
      end
    end
  end
  if active >= cap then return -1 - active end
end
redis.call('SET', KEYS[1], ARGV[3])
redis.call('ZADD', KEYS[2], ARGV[4], ARGV[1])
redis.call('HSET', KEYS[3], ARGV[1], ARGV[2])
if ARGV[2] ~= '' then redis.call('ZADD', KEYS[4], ARGV[4], ARGV[1]) end
return active
