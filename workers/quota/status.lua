-- A user's budget after expiring lapsed reservations (after now.lua and expire.lua).
-- KEYS quota, held, deadline, lapsed, seconds -> {limit or "", used, reserved}
expire(KEYS[1], KEYS[2], KEYS[3], KEYS[4], KEYS[5], now)
local held = 0
for _, value in ipairs(redis.call('HVALS', KEYS[2])) do held = held + tonumber(value) end
return {redis.call('HGET', KEYS[1], 'limit') or '', redis.call('HGET', KEYS[1], 'used') or '0',
        string.format('%.17g', held)}
