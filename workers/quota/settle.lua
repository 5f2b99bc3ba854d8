-- Replace a reservation with the reported time (correcting the charge of one that lapsed), booked
-- on today's date (after now.lua and period.lua).
-- KEYS quota, held, deadline, lapsed, seconds, days, last, problems, first (charge dates per job);
-- ARGV rid, actual, job, problems, @now
-- -> seconds added to `used` (string)
dated(KEYS[1], KEYS[6], KEYS[5], KEYS[7])
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
  book(KEYS[6], charge, now)
end
if tonumber(ARGV[4]) > 0 then redis.call('HINCRBY', KEYS[8], ARGV[3], ARGV[4]) end
if charge ~= 0 or tonumber(ARGV[4]) > 0 then
  redis.call('HSETNX', KEYS[9], ARGV[3], string.format('%.6f', now))
  redis.call('HSET', KEYS[7], ARGV[3], string.format('%.6f', now))
end
return string.format('%.17g', charge)
