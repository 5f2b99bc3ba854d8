-- expire(quota, held, deadline, lapsed, seconds, days, now): charge the reservations whose
-- deadline has passed at their estimate (the problem may have run), on today's date, record them
-- as lapsed, then drop them (after period.lua).
local function expire(quota, held, deadline, lapsed, seconds, days, now)
  for _, rid in ipairs(redis.call('ZRANGEBYSCORE', deadline, '-inf', now)) do
    local amount = redis.call('HGET', held, rid)
    if amount then
      local job = string.match(rid, '^(.*)#[^#]*$') or rid
      redis.call('HINCRBYFLOAT', quota, 'used', amount)
      redis.call('HINCRBYFLOAT', quota, 'expired', amount)
      redis.call('HINCRBYFLOAT', seconds, job, amount)
      book(days, amount, now)
      redis.call('HSET', lapsed, rid, amount)
      redis.call('HDEL', held, rid)
    end
    redis.call('ZREM', deadline, rid)
  end
end
