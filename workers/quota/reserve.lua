-- Hold ARGV[2] seconds of a user's budget for one problem (after now.lua, period.lua, expire.lua).
-- KEYS quota, held, deadline, lapsed, seconds, days, last, users;
-- ARGV rid, amount, ttl, user, first day, stop day ('' '': lifetime), @now
-- -> {ok (1/0), remaining before this reservation (string; "inf" when unlimited)}
dated(KEYS[1], KEYS[6], KEYS[5], KEYS[7])
expire(KEYS[1], KEYS[2], KEYS[3], KEYS[4], KEYS[5], KEYS[6], now)
redis.call('SADD', KEYS[8], ARGV[4])
local amount = tonumber(ARGV[2])
local limit = redis.call('HGET', KEYS[1], 'limit')
local remaining = 'inf'
if limit then
  local held = 0
  for _, value in ipairs(redis.call('HVALS', KEYS[2])) do held = held + tonumber(value) end
  local left = tonumber(limit) - used_in(KEYS[1], KEYS[6], ARGV[5], ARGV[6]) - held
  remaining = string.format('%.17g', left)
  if left < amount then return {0, remaining} end
end
redis.call('HSET', KEYS[2], ARGV[1], ARGV[2])
redis.call('ZADD', KEYS[3], now + tonumber(ARGV[3]), ARGV[1])
return {1, remaining}
