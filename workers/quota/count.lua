-- Live slots after dropping expired ones (after now.lua). KEYS slots -> count
redis.call('ZREMRANGEBYSCORE', KEYS[1], '-inf', now)
return redis.call('ZCARD', KEYS[1])
