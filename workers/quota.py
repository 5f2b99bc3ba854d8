"""Per-user QPU-time budgets and the lab-wide limit on QPU problems in flight, in Redis.

One D-Wave token serves the whole lab; this module rations it per user. Before a metered bundle
(QPU or hybrid) is sent, the worker takes a *slot* from the lab-wide semaphore and *reserves*
the bundle's estimated time from the owner's budget; afterwards it *settles* the reservation with
the time the sample set reports (``qpu_access_time``; hybrid: ``charge_time``) and frees the
slot. Each step is one Lua script, so concurrent workers see consistent budgets: a reservation
is refused when ``limit - used - reserved < estimate``, and the budget can only be overspent by
what in-flight bundles use beyond their estimates.

Keys (under ``{key_prefix}:``):

    quota:{user}             hash  limit (absent: unlimited), used, expired (seconds)
    quota:{user}:held        hash  reservation id -> reserved seconds
    quota:{user}:deadline    zset  reservation id -> expiry (Redis server time)
    quota:{user}:lapsed      hash  reservation id -> seconds charged when it expired
    quota:users              set   users with a budget or usage
    usage:{user}:seconds     hash  job id -> charged seconds
    usage:{user}:problems    hash  job id -> problems sent
    qpu:slots                zset  slot token -> expiry        (lab-wide semaphore)
    qpu:slots:{user}         zset  slot token -> expiry        (per-user share, optional)

A worker killed mid-bundle cannot leak anything: its slot and its reservation expire after
``Settings.qpu_slot_ttl`` (+ the bundle's estimate). An expired reservation is *charged* at its
estimate, because the problem may well have run; if the worker was only slow and settles late,
the charge is corrected to the reported time.

Times are seconds (floats, HINCRBYFLOAT); the clock is Redis's (``TIME``), not the workers'.
"""

from __future__ import annotations

import random
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import redis

from shared.config import Settings
from shared.solvers import SolverError, TransientSolverError
from shared.solvers.base import uses_warm_start

# --- Lua scripts -------------------------------------------------------------------------------

_NOW = "local t = redis.call('TIME'); local now = tonumber(t[1]) + tonumber(t[2]) / 1e6\n"

#: Charge expired reservations at their estimate (the problem may have run), then drop them.
_EXPIRE = """
local function expire(quota, held, deadline, lapsed, seconds, now)
  for _, rid in ipairs(redis.call('ZRANGEBYSCORE', deadline, '-inf', now)) do
    local amount = redis.call('HGET', held, rid)
    if amount then
      local job = string.match(rid, '^(.*)#[^#]*$') or rid
      redis.call('HINCRBYFLOAT', quota, 'used', amount)
      redis.call('HINCRBYFLOAT', quota, 'expired', amount)
      redis.call('HINCRBYFLOAT', seconds, job, amount)
      redis.call('HSET', lapsed, rid, amount)
      redis.call('HDEL', held, rid)
    end
    redis.call('ZREM', deadline, rid)
  end
end
"""

#: KEYS quota, held, deadline, lapsed, seconds, users; ARGV rid, amount, ttl, user
#: -> {ok (1/0), remaining before this reservation (string; "inf" when unlimited)}
_RESERVE = (
    _NOW
    + _EXPIRE
    + """
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
"""
)

#: KEYS quota, held, deadline, lapsed, seconds, problems; ARGV rid, actual, job, problems
#: -> seconds added to ``used`` (string)
_SETTLE = """
local actual = tonumber(ARGV[2])
local charge = actual
if redis.call('HDEL', KEYS[2], ARGV[1]) == 0 then
  local lapsed = redis.call('HGET', KEYS[4], ARGV[1])
  if lapsed then
    charge = actual - tonumber(lapsed)
    redis.call('HINCRBYFLOAT', KEYS[1], 'expired', -tonumber(lapsed))
    redis.call('HDEL', KEYS[4], ARGV[1])
  end
end
redis.call('ZREM', KEYS[3], ARGV[1])
if charge ~= 0 then
  redis.call('HINCRBYFLOAT', KEYS[1], 'used', charge)
  redis.call('HINCRBYFLOAT', KEYS[5], ARGV[3], charge)
end
if tonumber(ARGV[4]) > 0 then redis.call('HINCRBY', KEYS[6], ARGV[3], ARGV[4]) end
return string.format('%.17g', charge)
"""

#: KEYS quota, held, deadline, lapsed, seconds -> {limit or "", used, reserved}
_STATUS = (
    _NOW
    + _EXPIRE
    + """
expire(KEYS[1], KEYS[2], KEYS[3], KEYS[4], KEYS[5], now)
local held = 0
for _, value in ipairs(redis.call('HVALS', KEYS[2])) do held = held + tonumber(value) end
return {redis.call('HGET', KEYS[1], 'limit') or '', redis.call('HGET', KEYS[1], 'used') or '0',
        string.format('%.17g', held)}
"""
)

#: KEYS slots, user slots; ARGV token, limit, user limit (0: none), ttl -> 1 taken / 0 full
_ACQUIRE = (
    _NOW
    + """
redis.call('ZREMRANGEBYSCORE', KEYS[1], '-inf', now)
redis.call('ZREMRANGEBYSCORE', KEYS[2], '-inf', now)
if redis.call('ZCARD', KEYS[1]) >= tonumber(ARGV[2]) then return 0 end
local per_user = tonumber(ARGV[3])
if per_user > 0 and redis.call('ZCARD', KEYS[2]) >= per_user then return 0 end
local deadline = now + tonumber(ARGV[4])
redis.call('ZADD', KEYS[1], deadline, ARGV[1])
redis.call('ZADD', KEYS[2], deadline, ARGV[1])
return 1
"""
)

#: KEYS slots -> live slot count
_COUNT = (
    _NOW
    + "redis.call('ZREMRANGEBYSCORE', KEYS[1], '-inf', now)\nreturn redis.call('ZCARD', KEYS[1])"
)


#: The user every request acts as (and owns jobs) while ``Settings.auth_enabled`` is off.
LOCAL_USER = "local"


# --- errors and records ------------------------------------------------------------------------


class QuotaExceeded(SolverError):
    """The owner's remaining QPU budget is below what the next problem needs (not retried)."""

    def __init__(self, user: str, remaining: float, needed: float, what: str = "the next bundle"):
        self.user, self.remaining, self.needed = user, remaining, needed
        super().__init__(
            f"not enough QPU budget left for user {user!r}: {max(remaining, 0.0):.3f} s remaining, "
            f"{needed:.3f} s estimated for {what}; ask an admin to raise it "
            "(qhsm admin set-quota) or use an unmetered solver"
        )


class NoQpuSlot(TransientSolverError):
    """Every lab-wide QPU slot stayed busy for the whole wait (retried later)."""


@dataclass(frozen=True)
class QuotaStatus:
    """A user's budget in seconds; ``limit`` None means unlimited."""

    user: str
    limit: float | None
    used: float
    reserved: float

    @property
    def remaining(self) -> float:
        if self.limit is None:
            return float("inf")
        return self.limit - self.used - self.reserved

    def as_dict(self) -> dict:
        return {
            "user": self.user,
            "limit_seconds": self.limit,
            "used_seconds": self.used,
            "reserved_seconds": self.reserved,
            "remaining_seconds": None if self.limit is None else self.remaining,
        }


@dataclass(frozen=True)
class Reservation:
    user: str
    job_id: str
    id: str
    seconds: float


@dataclass(frozen=True)
class JobUsage:
    job_id: str
    seconds: float
    problems: int


@dataclass
class UserUsage:
    status: QuotaStatus
    jobs: list[JobUsage] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {
            **self.status.as_dict(),
            "jobs": [
                {"id": job.job_id, "qpu_seconds": job.seconds, "problems": job.problems}
                for job in self.jobs
            ],
        }


# --- the ledger --------------------------------------------------------------------------------


class QuotaLedger:
    """Budgets, reservations and usage records of every user."""

    def __init__(self, client: redis.Redis, key_prefix: str):
        self.redis = client
        self.prefix = key_prefix
        self._reserve = client.register_script(_RESERVE)
        self._settle = client.register_script(_SETTLE)
        self._status = client.register_script(_STATUS)

    @classmethod
    def from_settings(cls, settings: Settings) -> QuotaLedger:
        from workers.app import redis_url

        return cls(redis.Redis.from_url(redis_url(settings)), settings.key_prefix)

    def key(self, *parts: object) -> str:
        return ":".join([self.prefix, *map(str, parts)])

    def _keys(self, user: str) -> list[str]:
        quota = self.key("quota", user)
        return [
            quota,
            quota + ":held",
            quota + ":deadline",
            quota + ":lapsed",
            self.key("usage", user, "seconds"),
        ]

    def set_limit(self, user: str, seconds: float | None) -> None:
        """Set (or with None: remove, i.e. unlimited) a user's total budget in seconds."""
        with self.redis.pipeline() as pipe:
            if seconds is None:
                pipe.hdel(self.key("quota", user), "limit")
            else:
                if seconds < 0:
                    raise ValueError("a QPU budget cannot be negative")
                pipe.hset(self.key("quota", user), "limit", repr(float(seconds)))
            pipe.sadd(self.key("quota", "users"), user)
            pipe.execute()

    def status(self, user: str) -> QuotaStatus:
        limit, used, reserved = (
            value.decode() if isinstance(value, bytes) else str(value)
            for value in self._status(keys=self._keys(user))
        )
        return QuotaStatus(
            user=user,
            limit=float(limit) if limit else None,
            used=float(used),
            reserved=float(reserved),
        )

    def check(self, user: str, needed: float, what: str = "this job") -> QuotaStatus:
        """Raise :class:`QuotaExceeded` unless ``needed`` seconds fit the remaining budget."""
        status = self.status(user)
        if needed > 0 and status.remaining < needed:
            raise QuotaExceeded(user, status.remaining, needed, what)
        return status

    def reserve(self, user: str, job_id: str, seconds: float, ttl: float) -> Reservation:
        """Hold ``seconds`` of the budget for one problem, or raise :class:`QuotaExceeded`."""
        rid = f"{job_id}#{uuid.uuid4().hex}"
        ok, remaining = self._reserve(
            keys=[*self._keys(user), self.key("quota", "users")],
            args=[rid, repr(float(seconds)), repr(float(ttl)), user],
        )
        if not int(ok):
            raise QuotaExceeded(user, float(remaining), seconds)
        return Reservation(user=user, job_id=job_id, id=rid, seconds=float(seconds))

    def settle(self, reservation: Reservation, actual: float, problems: int = 1) -> float:
        """Replace the reservation with the reported time; returns the seconds charged now."""
        keys = [*self._keys(reservation.user), self.key("usage", reservation.user, "problems")]
        charged = self._settle(
            keys=keys,
            args=[reservation.id, repr(max(0.0, float(actual))), reservation.job_id, problems],
        )
        return float(charged)

    def release(self, reservation: Reservation) -> None:
        """Drop a reservation without charging (the problem was never sent)."""
        self.settle(reservation, 0.0, problems=0)

    def users(self) -> list[str]:
        return sorted(member.decode() for member in self.redis.smembers(self.key("quota", "users")))

    def usage(self, user: str) -> UserUsage:
        seconds = self.redis.hgetall(self.key("usage", user, "seconds"))
        problems = self.redis.hgetall(self.key("usage", user, "problems"))
        jobs = [
            JobUsage(
                job_id=job.decode(),
                seconds=float(value),
                problems=int(problems.get(job, 0)),
            )
            for job, value in seconds.items()
        ]
        jobs += [
            JobUsage(job_id=job.decode(), seconds=0.0, problems=int(count))
            for job, count in problems.items()
            if job not in seconds
        ]
        return UserUsage(status=self.status(user), jobs=sorted(jobs, key=lambda j: j.job_id))

    def job_usage(self, user: str, job_id: str) -> JobUsage:
        seconds = self.redis.hget(self.key("usage", user, "seconds"), job_id)
        problems = self.redis.hget(self.key("usage", user, "problems"), job_id)
        return JobUsage(job_id, float(seconds or 0.0), int(problems or 0))


# --- the lab-wide semaphore --------------------------------------------------------------------


class QpuSemaphore:
    """At most ``limit`` QPU problems in flight lab-wide (and ``per_user`` per user).

    Slots are members of a sorted set scored by their expiry, so a killed worker's slot frees
    itself after ``ttl`` seconds. Waiting is polling with jittered backoff (QPU calls take
    tenths of a second to seconds, so this costs nothing noticeable).
    """

    def __init__(
        self, client: redis.Redis, key_prefix: str, limit: int, per_user: int | None = None
    ):
        self.redis = client
        self.prefix = key_prefix
        self.limit = limit
        self.per_user = per_user
        self._acquire = client.register_script(_ACQUIRE)
        self._count = client.register_script(_COUNT)

    @classmethod
    def from_settings(cls, settings: Settings, client: redis.Redis | None = None) -> QpuSemaphore:
        from workers.app import redis_url

        client = client or redis.Redis.from_url(redis_url(settings))
        return cls(
            client, settings.key_prefix, settings.qpu_max_in_flight,
            settings.qpu_max_in_flight_per_user,
        )  # fmt: skip

    def _keys(self, user: str) -> list[str]:
        slots = f"{self.prefix}:qpu:slots"
        return [slots, f"{slots}:{user}"]

    def try_acquire(self, user: str, ttl: float) -> str | None:
        """A slot token, or None when the lab (or this user's share) is full."""
        token = uuid.uuid4().hex
        taken = self._acquire(
            keys=self._keys(user), args=[token, self.limit, self.per_user or 0, repr(float(ttl))]
        )
        return token if int(taken) else None

    def acquire(self, user: str, ttl: float, wait: float) -> str:
        """Wait up to ``wait`` seconds for a slot; :class:`NoQpuSlot` when none frees up."""
        deadline = time.monotonic() + wait
        delay = 0.02
        while True:
            token = self.try_acquire(user, ttl)
            if token is not None:
                return token
            if time.monotonic() >= deadline:
                raise NoQpuSlot(
                    f"all {self.limit} lab-wide QPU slots stayed busy for {wait:g} s; "
                    "the bundle will be retried"
                )
            time.sleep(min(delay * random.uniform(0.5, 1.5), max(0.0, deadline - time.monotonic())))
            delay = min(delay * 2, 0.5)

    def release(self, user: str, token: str) -> None:
        with self.redis.pipeline() as pipe:
            for key in self._keys(user):
                pipe.zrem(key, token)
            pipe.execute()

    def in_flight(self) -> int:
        return int(self._count(keys=self._keys("")[:1]))

    @contextmanager
    def slot(self, user: str, ttl: float, wait: float) -> Iterator[str]:
        token = self.acquire(user, ttl, wait)
        try:
            yield token
        finally:
            self.release(user, token)


# --- one metered problem -----------------------------------------------------------------------


@dataclass
class Charge:
    """What the caller reports after the solve: the seconds the sample set says it used."""

    seconds: float = 0.0
    sent: bool = False

    def report(self, seconds: float) -> None:
        self.seconds = max(0.0, float(seconds))
        self.sent = True


class QpuMeter:
    """Slot + reservation + settlement around each metered problem (what a worker uses)."""

    def __init__(
        self, ledger: QuotaLedger, semaphore: QpuSemaphore, slot_ttl: float, slot_wait: float
    ):
        self.ledger = ledger
        self.semaphore = semaphore
        self.slot_ttl = slot_ttl
        self.slot_wait = slot_wait

    @classmethod
    def from_settings(cls, settings: Settings, client: redis.Redis | None = None) -> QpuMeter:
        from workers.app import redis_url

        client = client or redis.Redis.from_url(redis_url(settings))
        return cls(
            QuotaLedger(client, settings.key_prefix),
            QpuSemaphore.from_settings(settings, client),
            settings.qpu_slot_ttl,
            settings.qpu_slot_wait,
        )

    @contextmanager
    def problem(self, user: str, job_id: str, estimate: float) -> Iterator[Charge]:
        """Take a slot, reserve ``estimate`` (QuotaExceeded when it does not fit), yield a
        :class:`Charge` for the caller to fill in, then settle and free the slot.

        If the body raises before reporting, the reservation is released uncharged (failed
        problems are not billed by D-Wave either).
        """
        ttl = self.slot_ttl + estimate
        with self.semaphore.slot(user, ttl, self.slot_wait):
            reservation = self.ledger.reserve(user, job_id, estimate, ttl)
            charge = Charge()
            try:
                yield charge
            finally:
                if charge.sent:
                    self.ledger.settle(reservation, charge.seconds)
                else:
                    self.ledger.release(reservation)


# --- the worker's metered solve ----------------------------------------------------------------


_live_solvers: dict[str, object | None] = {}


def live_timing_solver(solver_name: str):
    """The cloud solver behind a QPU adapter (its own ``problem_timing_data`` and
    ``estimate_qpu_access_time``), or None offline. Looked up once per process."""
    if solver_name not in _live_solvers:
        cloud = None
        try:
            from shared.solvers import get_solver

            adapter = get_solver(solver_name)
            if not getattr(adapter, "simulated", True) and callable(
                getattr(adapter, "sampler", None)
            ):
                cloud = getattr(adapter.sampler(), "solver", None)
        except Exception:  # no token or no network: the offline model will do
            cloud = None
        if not callable(getattr(cloud, "estimate_qpu_access_time", None)):
            cloud = None
        _live_solvers[solver_name] = cloud
    return _live_solvers[solver_name]


def bundle_estimate(inputs, config, start: int, stop: int, columns: int | None = None) -> float:
    """Estimated charge of the bundle of rows [start, stop) (``columns`` wide: a row segment;
    None: whole rows) of a level (no BQM is built), with the actual embedding of its shape once
    any worker has embedded one."""
    from shared.encodings import get_codec
    from shared.solvers.embedding_cache import default_cache
    from shared.solvers.qpu_time import (
        QPU_SOLVERS,
        bundle_seconds,
        known_embedding,
        sampler_params,
    )

    width, labels = inputs.candidates.shape[1], inputs.candidates.shape[2]
    width = width if columns is None else columns
    variables = (stop - start) * width * get_codec(config.encoding).variables_per_pixel(labels)
    params = sampler_params(config.solver_params, warm=uses_warm_start(config))
    if config.solver not in QPU_SOLVERS:
        return bundle_seconds(config.solver, variables, params)
    embedding = known_embedding(
        default_cache(), config.solver, config.encoding, (stop - start, width), labels
    )
    live = live_timing_solver(config.solver)
    return bundle_seconds(config.solver, variables, params, embedding=embedding, solver=live)


def solve_metered(
    meter: QpuMeter,
    owner: str,
    job_id: str,
    inputs,
    config,
    bundles: list,
    still_running=lambda: True,
):
    """``solve_bundles`` for a metered solver: one bundle at a time, each inside a lab-wide
    slot and a reservation of its estimate, charged what its sample set reports.

    Returns the results, or None when ``still_running()`` turns false (the job was cancelled
    or failed): the remaining bundles are then not sent. Raises :class:`QuotaExceeded` when the
    owner's budget cannot cover the next bundle.
    """
    from shared.solve import solve_bundles
    from shared.solvers.qpu_time import charged_seconds

    results = []
    for spec in bundles:
        if not still_running():
            return None
        bundle = inputs.as_bundle(spec)
        start, stop, first, last = bundle.as_list()
        estimate = bundle_estimate(inputs, config, start, stop, last - first)
        with meter.problem(owner, job_id, estimate) as charge:
            [result] = solve_bundles(inputs, config, [bundle])
            charge.report(charged_seconds(result.timing))
        results.append(result)
    return results
