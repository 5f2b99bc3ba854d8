-- The Redis server's clock in seconds as `now` (prepended to the scripts that need it).
local t = redis.call('TIME'); local now = tonumber(t[1]) + tonumber(t[2]) / 1e6
