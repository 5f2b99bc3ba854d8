"""Per-user QPU-time accounting: budgets, reservations and what each job was charged.

A reservation is refused when ``limit - used - reserved < estimate``; settling replaces it with
the time the sample set reports. The steps run as Lua scripts (``reserve.lua``, ``settle.lua``,
``status.lua``, sharing ``now.lua``, ``period.lua`` and ``expire.lua``), so concurrent
workers see consistent budgets. A budget covers a period (``Settings.budget_period`` or the
user's own): lifetime, the UTC calendar month or the ISO week; what is charged is booked on its
day, and the total is kept too, so no history is lost when the period changes. An expired
reservation (its worker died) is charged at its estimate, because the problem may well have
run; a late settlement corrects the charge to the reported time.

Keys (under ``{key_prefix}:``):

    quota:{user}             hash  limit (absent: unlimited), used, expired (seconds, in
                                   total), period (absent: Settings.budget_period), dated
    quota:{user}:held        hash  reservation id -> reserved seconds
    quota:{user}:deadline    zset  reservation id -> expiry (Redis server time)
    quota:{user}:lapsed      hash  reservation id -> seconds charged when it expired
    quota:users              set   users with a budget or usage
    usage:{user}:seconds     hash  job id -> charged seconds
    usage:{user}:problems    hash  job id -> problems sent
    usage:{user}:first       hash  job id -> first charge (Redis server time, epoch seconds)
    usage:{user}:last        hash  job id -> last charge
    usage:{user}:days        hash  epoch day (UTC) -> seconds charged that day: what a monthly
                                   or weekly budget counts (:mod:`workers.quota.periods`)
    usage:{user}:ids:{job}   list  the ids SAPI gave the job's problems (to find them on Leap)
"""

from __future__ import annotations

import csv
import io
import math
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime

import redis

from shared.config import Settings
from shared.settings import BudgetPeriod
from shared.solvers import SolverError
from workers.quota.periods import PeriodWindow, window
from workers.quota.scripts import load_script
from workers.redis_client import text

_RESERVE = load_script("now", "period", "expire", "reserve")
_SETTLE = load_script("now", "period", "settle")
_STATUS = load_script("now", "period", "expire", "status")

#: Share of a budget below which what is left is warned about (``QuotaStatus.warning``).
LOW_BUDGET_SHARE = 0.10
#: Columns of the usage ledger as CSV (:func:`usage_csv`).
CSV_COLUMNS = ("user", "job", "qpu_seconds", "problems", "first_charged_at", "last_charged_at")

#: The user every request acts as (and owns jobs) while ``Settings.auth_enabled`` is off.
LOCAL_USER = "local"


class QuotaExceededError(SolverError):
    """The owner's remaining QPU budget is below what the next problem needs (not retried)."""

    def __init__(
        self,
        user: str,
        remaining: float,
        needed: float,
        what: str = "the next bundle",
        period: PeriodWindow | None = None,
    ):
        self.user, self.remaining, self.needed = user, remaining, needed
        self.period = period or PeriodWindow(BudgetPeriod.LIFETIME)
        wait = "" if self.period.end is None else "wait for the reset, "
        super().__init__(
            f"not enough QPU budget left for user {user!r}: {max(remaining, 0.0):.3f} s remaining "
            f"{self.period.this} ({self.period.describe()}), {needed:.3f} s estimated for "
            f"{what}; {wait}ask an admin to raise it (qhsm admin set-quota) or use an "
            "unmetered solver"
        )


@dataclass(frozen=True)
class QuotaStatus:
    """A user's budget in seconds over its period; ``limit`` None means unlimited. ``used`` is
    what was charged in the period (lifetime: in total), ``total`` everything ever charged."""

    user: str
    limit: float | None
    used: float
    reserved: float
    period: PeriodWindow = field(default_factory=lambda: PeriodWindow(BudgetPeriod.LIFETIME))
    total: float | None = None

    @property
    def remaining(self) -> float:
        if self.limit is None:
            return float("inf")
        return self.limit - self.used - self.reserved

    @property
    def total_used(self) -> float:
        """Seconds ever charged, in any period (a lifetime budget's ``used``)."""
        return self.used if self.total is None else self.total

    @property
    def warning(self) -> str | None:
        """What to say when less than :data:`LOW_BUDGET_SHARE` of a (non-zero) budget is left."""
        if not self.limit or self.remaining >= LOW_BUDGET_SHARE * self.limit:
            return None
        left = max(self.remaining, 0.0)
        share = f"{100 * left / self.limit:.1f} %"
        if self.period.end is not None:
            share = f"{self.period.this} ({share}; {self.period.describe()})"
        else:
            share = f"({share})"
        return (
            f"QPU budget of user {self.user!r} runs low: {left:.3f} s of {self.limit:g} s left "
            f"{share}; ask an admin to raise it (qhsm admin set-quota)"
        )

    def as_dict(self) -> dict:
        """The budget as the API and the admin CLI show it: ``{what}_seconds``, None unlimited."""
        remaining = None if self.limit is None else self.remaining
        seconds = {"limit": self.limit, "used": self.used, "reserved": self.reserved}
        return {
            "user": self.user,
            **{f"{what}_seconds": value for what, value in seconds.items()},
            "remaining_seconds": remaining,
            "total_used_seconds": self.total_used,
            "period": self.period.period.value,
            "period_start": iso(self.period.start),
            "resets_at": iso(self.period.end),
            "warning": self.warning,
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
    #: SAPI's ids of the problems sent (none for the offline stand-ins).
    problem_ids: tuple[str, ...] = ()
    #: When the job was first and last charged (UTC; None: charged before dates were kept)
    first_charged_at: datetime | None = None
    last_charged_at: datetime | None = None


@dataclass
class UserUsage:
    status: QuotaStatus
    jobs: list[JobUsage] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {
            **self.status.as_dict(),
            "jobs": [
                {
                    "id": job.job_id,
                    "qpu_seconds": job.seconds,
                    "problems": job.problems,
                    "problem_ids": list(job.problem_ids),
                    "first_charged_at": iso(job.first_charged_at),
                    "last_charged_at": iso(job.last_charged_at),
                }
                for job in self.jobs
            ],
        }


def iso(moment: datetime | None) -> str | None:
    return None if moment is None else moment.isoformat()


def usage_csv(usages: list[UserUsage]) -> str:
    """The ledger as CSV, one row per user and job (:data:`CSV_COLUMNS`), for spreadsheets."""
    stream = io.StringIO()
    writer = csv.writer(stream, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for usage in usages:
        for job in usage.jobs:
            writer.writerow(
                [usage.status.user, job.job_id, repr(job.seconds), job.problems,
                 iso(job.first_charged_at) or "", iso(job.last_charged_at) or ""]
            )  # fmt: skip
    return stream.getvalue()


def _moment(raw: bytes | str | None) -> datetime | None:
    return None if raw is None else datetime.fromtimestamp(float(raw), UTC)


class QuotaLedger:
    """Budgets, reservations and usage records of every user."""

    def __init__(
        self,
        client: redis.Redis,
        key_prefix: str,
        period: BudgetPeriod | str = BudgetPeriod.LIFETIME,
        clock: Callable[[], datetime] | None = None,
    ):
        """``period``: the deployment's budget period (a user's own overrides it); ``clock``:
        what time it is (default: the Redis server's ``TIME``, the clock every worker shares;
        tests freeze it)."""
        self.redis = client
        self.prefix = key_prefix
        self.period = BudgetPeriod(period)
        self.clock = clock
        self._reserve = client.register_script(_RESERVE)
        self._settle = client.register_script(_SETTLE)
        self._status = client.register_script(_STATUS)

    @classmethod
    def from_settings(cls, settings: Settings) -> QuotaLedger:
        from workers.redis_client import client_for

        return cls(client_for(settings), settings.key_prefix, settings.budget_period)

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
            self.key("usage", user, "days"),
            self.key("usage", user, "last"),
        ]

    def window(self, user: str) -> tuple[PeriodWindow, list[str]]:
        """The user's budget period now, and the scripts' arguments that say it (the window's
        first and stop epoch days, ``''`` for lifetime; the time as ``@seconds``)."""
        with self.redis.pipeline(transaction=False) as pipe:  # one round trip
            pipe.time()
            pipe.hget(self.key("quota", user), "period")
            (seconds, micros), own = pipe.execute()
        moment = self.clock() if self.clock else datetime.fromtimestamp(seconds + micros / 1e6, UTC)
        current = window(text(own) if own else self.period, moment)
        days = current.days
        first, stop = ("", "") if days is None else (str(days[0]), str(days[1]))
        return current, [first, stop, f"@{moment.timestamp()!r}"]

    def set_period(self, user: str, period: BudgetPeriod | str | None) -> None:
        """Give a user their own budget period (None: the deployment's, ``Settings.budget_period``).
        The charges keep their dates, so any period can be counted afterwards."""
        if period is None:
            self.redis.hdel(self.key("quota", user), "period")
        else:
            self.redis.hset(self.key("quota", user), "period", BudgetPeriod(period).value)
        self.redis.sadd(self.key("quota", "users"), user)

    def own_period(self, user: str) -> BudgetPeriod | None:
        """The user's own budget period, None when it is the deployment's."""
        own = self.redis.hget(self.key("quota", user), "period")
        return BudgetPeriod(text(own)) if own else None

    def set_limit(self, user: str, seconds: float | None) -> None:
        """Set (or with None: remove, i.e. unlimited) a user's budget per period in seconds
        (ValueError unless finite and >= 0: unlimited is None, never infinity)."""
        with self.redis.pipeline() as pipe:
            if seconds is None:
                pipe.hdel(self.key("quota", user), "limit")
            else:
                if not math.isfinite(seconds) or seconds < 0:
                    raise ValueError(
                        f"a QPU budget is a finite number of seconds >= 0 (or unlimited), "
                        f"not {seconds!r}"
                    )
                pipe.hset(self.key("quota", user), "limit", repr(float(seconds)))
            pipe.sadd(self.key("quota", "users"), user)
            pipe.execute()

    def status(self, user: str) -> QuotaStatus:
        """The user's budget in its current period, after charging any lapsed reservations."""
        period, args = self.window(user)
        limit, used, reserved, total = (
            text(value) for value in self._status(keys=self._keys(user), args=args)
        )
        return QuotaStatus(
            user=user,
            limit=float(limit) if limit else None,
            used=float(used),
            reserved=float(reserved),
            period=period,
            total=float(total),
        )

    def check(self, user: str, needed: float, what: str = "this job") -> QuotaStatus:
        """Raise :class:`QuotaExceededError` unless ``needed`` seconds fit the remaining budget.

        Parameters
        ----------
        user : str
            Whose budget.
        needed : float
            Estimated seconds (zero or less always fits) of ``what`` (for the error message).

        Returns
        -------
        QuotaStatus
            The budget as checked.
        """
        status = self.status(user)
        if needed > 0 and status.remaining < needed:
            raise QuotaExceededError(user, status.remaining, needed, what, status.period)
        return status

    def reserve(self, user: str, job_id: str, seconds: float, ttl: float) -> Reservation:
        """Hold ``seconds`` of the budget for one problem, or raise :class:`QuotaExceededError`.

        Parameters
        ----------
        user, job_id : str
            Whose budget, and the job charged.
        seconds : float
            The problem's estimate.
        ttl : float
            Seconds after which the reservation lapses and is charged at its estimate.

        Returns
        -------
        Reservation
            To hand to :meth:`settle` or :meth:`release`.
        """
        rid = f"{job_id}#{uuid.uuid4().hex}"
        period, args = self.window(user)
        ok, remaining = self._reserve(
            keys=[*self._keys(user), self.key("quota", "users")],
            args=[rid, repr(float(seconds)), repr(float(ttl)), user, *args],
        )
        if not int(ok):
            raise QuotaExceededError(user, float(remaining), seconds, period=period)
        return Reservation(user=user, job_id=job_id, id=rid, seconds=float(seconds))

    def settle(
        self,
        reservation: Reservation,
        actual: float,
        problems: int = 1,
        problem_ids: list[str] | None = None,
    ) -> float:
        """Replace the reservation with the reported time.

        Parameters
        ----------
        reservation : Reservation
            From :meth:`reserve` (it may have lapsed meanwhile).
        actual : float
            Seconds the sample set reports (negative counts as zero).
        problems : int
            Problems to record as sent for the job.
        problem_ids : list of str, optional
            SAPI's ids of those problems, kept with the job's usage.

        Returns
        -------
        float
            The seconds charged now (negative when a lapsed estimate was too high).
        """
        keys = [
            *self._keys(reservation.user),
            *(self.key("usage", reservation.user, what) for what in ("problems", "first")),
        ]
        moment = "" if self.clock is None else f"@{self.clock().timestamp()!r}"
        charged = self._settle(
            keys=keys,
            args=[
                reservation.id,
                repr(max(0.0, float(actual))),
                reservation.job_id,
                problems,
                *([moment] if moment else []),
            ],
        )
        if problem_ids:
            self.redis.rpush(self.ids_key(reservation.user, reservation.job_id), *problem_ids)
        return float(charged)

    def ids_key(self, user: str, job_id: str) -> str:
        """Key of the list of SAPI's ids of the job's problems."""
        return self.key("usage", user, "ids", job_id)

    def _problem_ids(self, user: str, jobs: list[str]) -> list[tuple[str, ...]]:
        """SAPI's ids of each job's problems, in the order of ``jobs``."""
        with self.redis.pipeline() as pipe:
            for job in jobs:
                pipe.lrange(self.ids_key(user, job), 0, -1)
            found = pipe.execute()
        return [tuple(i.decode() if isinstance(i, bytes) else str(i) for i in ids) for ids in found]

    def release(self, reservation: Reservation) -> None:
        """Drop a reservation without charging (the problem was never sent)."""
        self.settle(reservation, 0.0, problems=0)

    def users(self) -> list[str]:
        """Every user with a budget or usage, sorted."""
        return sorted(text(member) for member in self.redis.smembers(self.key("quota", "users")))

    def usage(self, user: str) -> UserUsage:
        """The user's budget and what each of their jobs was charged, by job id."""
        seconds = self.redis.hgetall(self.key("usage", user, "seconds"))
        problems = self.redis.hgetall(self.key("usage", user, "problems"))
        jobs = [
            JobUsage(job_id=text(job), seconds=float(value), problems=int(problems.get(job, 0)))
            for job, value in seconds.items()
        ]
        jobs += [
            JobUsage(job_id=text(job), seconds=0.0, problems=int(count))
            for job, count in problems.items()
            if job not in seconds
        ]
        ids = self._problem_ids(user, [job.job_id for job in jobs])
        first, last = (
            {text(job): at for job, at in self.redis.hgetall(self.key("usage", user, w)).items()}
            for w in ("first", "last")
        )
        jobs = [
            replace(
                job,
                problem_ids=found,
                first_charged_at=_moment(first.get(job.job_id)),
                last_charged_at=_moment(last.get(job.job_id)),
            )
            for job, found in zip(jobs, ids, strict=True)
        ]
        return UserUsage(status=self.status(user), jobs=sorted(jobs, key=lambda j: j.job_id))

    def job_usage(self, user: str, job_id: str) -> JobUsage:
        """Seconds charged to and problems sent for one job (zero when it used none)."""
        seconds = self.redis.hget(self.key("usage", user, "seconds"), job_id)
        problems = self.redis.hget(self.key("usage", user, "problems"), job_id)
        [ids] = self._problem_ids(user, [job_id])
        first = self.redis.hget(self.key("usage", user, "first"), job_id)
        last = self.redis.hget(self.key("usage", user, "last"), job_id)
        return JobUsage(
            job_id, float(seconds or 0.0), int(problems or 0), ids, _moment(first), _moment(last)
        )
