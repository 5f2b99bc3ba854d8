-- Dated charges: `days` is a hash epoch day (UTC) -> seconds charged that day.
-- book(days, amount, now): add a charge to the day of `now`.
local function book(days, amount, now)
  redis.call('HINCRBYFLOAT', days, string.format('%d', math.floor(now / 86400)), amount)
end
-- dated(quota, days, seconds, last): once per user, book the charges made before days were kept
-- on the day each job was last charged (charges with no date count only in the lifetime total).
local function dated(quota, days, seconds, last)
  if redis.call('HSETNX', quota, 'dated', '1') == 0 then return end
  local charged = redis.call('HGETALL', seconds)
  for i = 1, #charged, 2 do
    local at = redis.call('HGET', last, charged[i])
    if at then book(days, charged[i + 1], tonumber(at)) end
  end
end
-- used_in(quota, days, first, stop): seconds charged on epoch days [first, stop); the whole
-- `used` (lifetime) when first is ''.
local function used_in(quota, days, first, stop)
  if first == '' then return tonumber(redis.call('HGET', quota, 'used') or '0') end
  local sum = 0
  for d = tonumber(first), tonumber(stop) - 1 do
    sum = sum + tonumber(redis.call('HGET', days, string.format('%d', d)) or '0')
  end
  return sum
end
