-- Hold ARGV[2] seconds of a user's budget for one problem (after now.lua and expire.lua).
-- KEYS quota, held, deadline, lapsed, seconds, users; ARGV rid, amount, ttl, user
-- -> {ok (1/0), remaining before this reservation (string; "inf" when unlimited)}
expire(KEYS[1], KEYS[2], KEYS[3], KEYS[4], KEYS[5], now)
redis.call('SADD', KEYS[6], ARGV[4])
local amount = tonumber(ARGV[2])
local limit = redis.call('HGET', KEYS[1], 'limit')
local remaining = 'inf'
if limit then
  local held = 0
  for _, value in ipairs(redis.call('HVALS', KEYS[2])) do held = held + tonumber(value) end
  local left = tonumber(limit) - tonumber(redis.call('HGET', KEYS[1], 'used') or '0') - held
  remaining = string.format('%.17g', left)
  if left < amount then return {0, remaining} end
end
redis.call('HSET', KEYS[2], ARGV[1], ARGV[2])
redis.call('ZADD', KEYS[3], now + tonumber(ARGV[3]), ARGV[1])
return {1, remaining}
