-- A user's budget after expiring lapsed reservations (after now.lua, period.lua, expire.lua).
-- KEYS quota, held, deadline, lapsed, seconds, days, last; ARGV first day, stop day ('' '':
-- lifetime), @now -> {limit or "", used in the period, reserved, used in total}
dated(KEYS[1], KEYS[6], KEYS[5], KEYS[7])
expire(KEYS[1], KEYS[2], KEYS[3], KEYS[4], KEYS[5], KEYS[6], now)
local held = 0
for _, value in ipairs(redis.call('HVALS', KEYS[2])) do held = held + tonumber(value) end
return {redis.call('HGET', KEYS[1], 'limit') or '',
        string.format('%.17g', used_in(KEYS[1], KEYS[6], ARGV[1], ARGV[2])),
        string.format('%.17g', held), redis.call('HGET', KEYS[1], 'used') or '0'}
