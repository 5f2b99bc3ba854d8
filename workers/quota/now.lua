-- `now` in seconds (prepended to the scripts that need it): the caller's clock when the last ARGV
-- is "@<seconds>" (the ledger passes Redis's TIME it read, or a test's frozen clock), else TIME.
local now
local given = ARGV[#ARGV]
if given and string.sub(given, 1, 1) == '@' then
  now = tonumber(string.sub(given, 2))
else
  local t = redis.call('TIME'); now = tonumber(t[1]) + tonumber(t[2]) / 1e6
end
