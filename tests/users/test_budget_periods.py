"""Budget periods (issue 31): a monthly or weekly budget counts what was charged in the current
UTC month or ISO week, with the ledger's clock frozen; the lifetime total stays."""

from __future__ import annotations

import calendar
from datetime import UTC, datetime, timedelta

import pytest
from hypothesis import given
from hypothesis import strategies as st

from shared.settings import BudgetPeriod, Settings
from workers.quota import QuotaExceededError, QuotaLedger
from workers.quota.periods import epoch_day, window

NOVEMBER = datetime(2026, 11, 20, 15, 30, tzinfo=UTC)
DECEMBER = datetime(2026, 12, 2, 9, 0, tzinfo=UTC)


class Clock:
    """A frozen clock the test moves by hand."""

    def __init__(self, moment: datetime) -> None:
        self.moment = moment

    def __call__(self) -> datetime:
        return self.moment


@pytest.fixture
def clock() -> Clock:
    return Clock(NOVEMBER)


@pytest.fixture
def monthly(redis_client, prefix, clock) -> QuotaLedger:
    return QuotaLedger(redis_client, prefix, BudgetPeriod.MONTHLY, clock=clock)


def spend(ledger: QuotaLedger, user: str, job: str, seconds: float) -> None:
    ledger.settle(ledger.reserve(user, job, seconds, ttl=60), seconds)


def test_the_default_period_is_lifetime():
    assert Settings().budget_period is BudgetPeriod.LIFETIME


def test_spending_in_november_does_not_count_against_december(monthly, clock):
    monthly.set_limit("ada", 10.0)
    spend(monthly, "ada", "job-nov", 9.5)
    november = monthly.status("ada")
    assert november.used == pytest.approx(9.5) and november.remaining == pytest.approx(0.5)
    with pytest.raises(QuotaExceededError):
        monthly.reserve("ada", "job-nov-2", 1.0, ttl=60)

    clock.moment = DECEMBER
    december = monthly.status("ada")
    assert december.used == 0.0 and december.remaining == pytest.approx(10.0)
    assert december.total == pytest.approx(9.5)  # the history is kept
    assert december.period.start == datetime(2026, 12, 1, tzinfo=UTC)
    assert december.period.end == datetime(2027, 1, 1, tzinfo=UTC)
    spend(monthly, "ada", "job-dec", 2.0)
    assert monthly.status("ada").used == pytest.approx(2.0)
    shown = monthly.status("ada").as_dict()
    assert shown["period"] == "monthly" and shown["resets_at"] == "2027-01-01T00:00:00+00:00"
    assert shown["total_used_seconds"] == pytest.approx(11.5)
    jobs = {job.job_id: job for job in monthly.usage("ada").jobs}
    assert jobs["job-nov"].last_charged_at.month == 11  # dated entries stay
    assert jobs["job-dec"].last_charged_at.month == 12


def test_the_same_charges_counted_over_a_lifetime_budget(redis_client, prefix, clock):
    lifetime = QuotaLedger(redis_client, prefix, clock=clock)
    lifetime.set_limit("ada", 10.0)
    spend(lifetime, "ada", "job-nov", 9.5)
    clock.moment = DECEMBER
    status = lifetime.status("ada")
    assert status.used == pytest.approx(9.5) and status.period.end is None
    with pytest.raises(QuotaExceededError, match="lifetime budget, never resets"):
        lifetime.check("ada", 1.0)


def test_admission_refusal_names_the_period_and_its_reset(monthly):
    monthly.set_limit("ada", 1.0)
    spend(monthly, "ada", "job", 0.9)
    with pytest.raises(QuotaExceededError) as refused:
        monthly.check("ada", 0.5, "this job")
    message = str(refused.value)
    assert "0.100 s remaining this month" in message
    assert "monthly budget, resets at 2026-12-01T00:00:00+00:00" in message
    with pytest.raises(QuotaExceededError, match="resets at 2026-12-01"):
        monthly.reserve("ada", "job", 0.5, ttl=60)  # a worker's reservation says it too


def test_the_low_budget_warning_uses_the_periods_remainder(monthly, clock):
    monthly.set_limit("ada", 10.0)
    spend(monthly, "ada", "job", 9.5)
    warning = monthly.status("ada").warning
    assert warning and "0.500 s of 10 s left this month" in warning and "resets at" in warning
    clock.moment = DECEMBER
    assert monthly.status("ada").warning is None  # a new month, the whole budget again


def test_a_users_own_period_overrides_the_deployments(redis_client, prefix, clock):
    ledger = QuotaLedger(redis_client, prefix, BudgetPeriod.LIFETIME, clock=clock)
    ledger.set_limit("ada", 5.0)
    spend(ledger, "ada", "job", 4.0)
    ledger.set_period("ada", BudgetPeriod.WEEKLY)
    assert ledger.own_period("ada") is BudgetPeriod.WEEKLY
    clock.moment = NOVEMBER + timedelta(days=7)
    status = ledger.status("ada")
    assert status.period.period is BudgetPeriod.WEEKLY and status.used == 0.0
    ledger.set_period("ada", None)  # back to the deployment's lifetime: all of it counts
    assert ledger.own_period("ada") is None
    assert ledger.status("ada").used == pytest.approx(4.0)


def test_charges_made_before_dates_were_kept_count_in_their_month(monthly, redis_client, prefix):
    """A ledger written by the previous version (total, per-job seconds and last dates, no
    day buckets): its dated charges are booked on their day the first time it is read."""
    key = f"{prefix}:quota:ada"
    redis_client.hset(key, mapping={"limit": "10", "used": "7"})
    redis_client.hset(f"{prefix}:usage:ada:seconds", mapping={"old": "3", "this": "4"})
    redis_client.hset(f"{prefix}:usage:ada:last", mapping={
        "old": repr((NOVEMBER - timedelta(days=40)).timestamp()),
        "this": repr((NOVEMBER - timedelta(days=1)).timestamp()),
    })  # fmt: skip
    status = monthly.status("ada")
    assert status.used == pytest.approx(4.0) and status.total == pytest.approx(7.0)
    spend(monthly, "ada", "new", 1.0)
    assert monthly.status("ada").used == pytest.approx(5.0)  # booked once, not again


@given(
    st.datetimes(min_value=datetime(1971, 1, 1), max_value=datetime(2200, 1, 1)),
    st.sampled_from([BudgetPeriod.MONTHLY, BudgetPeriod.WEEKLY]),
)
def test_a_period_contains_its_moment_and_starts_where_the_calendar_says(moment, period):
    moment = moment.replace(tzinfo=UTC)
    current = window(period, moment)
    assert current.start is not None and current.end is not None
    assert current.start <= moment < current.end
    first, stop = current.days or (0, 0)
    assert first <= epoch_day(moment) < stop
    if period is BudgetPeriod.MONTHLY:
        assert current.start.day == 1
        assert stop - first == calendar.monthrange(moment.year, moment.month)[1]
    else:
        assert current.start.weekday() == 0 and stop - first == 7
    assert window(period, current.end).start == current.end  # the next one follows at once


def test_a_reservation_that_lapses_is_charged_in_the_period_it_lapsed_in(monthly, clock):
    monthly.set_limit("ada", 10.0)
    monthly.reserve("ada", "job", 3.0, ttl=60)  # its worker dies in November...
    assert monthly.status("ada").reserved == pytest.approx(3.0)
    clock.moment = DECEMBER  # ...and it is found lapsed in December: charged at its estimate
    status = monthly.status("ada")
    assert status.reserved == 0.0 and status.used == pytest.approx(3.0)
    assert status.total == pytest.approx(3.0)
