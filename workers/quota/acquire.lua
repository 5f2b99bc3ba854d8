-- Take a QPU slot unless the lab (or the user's share) is full (after now.lua).
-- KEYS slots, user slots; ARGV token, limit, user limit (0: none), ttl -> 1 taken / 0 full
redis.call('ZREMRANGEBYSCORE', KEYS[1], '-inf', now)
redis.call('ZREMRANGEBYSCORE', KEYS[2], '-inf', now)
if redis.call('ZCARD', KEYS[1]) >= tonumber(ARGV[2]) then return 0 end
local per_user = tonumber(ARGV[3])
if per_user > 0 and redis.call('ZCARD', KEYS[2]) >= per_user then return 0 end
local deadline = now + tonumber(ARGV[4])
redis.call('ZADD', KEYS[1], deadline, ARGV[1])
redis.call('ZADD', KEYS[2], deadline, ARGV[1])
return 1
