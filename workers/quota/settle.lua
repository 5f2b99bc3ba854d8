-- Replace a reservation with the reported time (correcting the charge of one that lapsed).
-- KEYS quota, held, deadline, lapsed, seconds, problems, first, last (charge dates per job);
-- ARGV rid, actual, job, problems
-- -> seconds added to `used` (string)
local actual = tonumber(ARGV[2])
local charge = actual
if redis.call('HDEL', KEYS[2], ARGV[1]) == 0 then
  local lapsed = redis.call('HGET', KEYS[4], ARGV[1])
  if lapsed then
    charge = actual - tonumber(lapsed)
    redis.call('HINCRBYFLOAT', KEYS[1], 'expired', -tonumber(lapsed))
    redis.call('HDEL', KEYS[4], ARGV[1])
  end
end
redis.call('ZREM', KEYS[3], ARGV[1])
if charge ~= 0 then
  redis.call('HINCRBYFLOAT', KEYS[1], 'used', charge)
  redis.call('HINCRBYFLOAT', KEYS[5], ARGV[3], charge)
end
if tonumber(ARGV[4]) > 0 then redis.call('HINCRBY', KEYS[6], ARGV[3], ARGV[4]) end
if charge ~= 0 or tonumber(ARGV[4]) > 0 then
  redis.call('HSETNX', KEYS[7], ARGV[3], string.format('%.6f', now))
  redis.call('HSET', KEYS[8], ARGV[3], string.format('%.6f', now))
end
return string.format('%.17g', charge)
