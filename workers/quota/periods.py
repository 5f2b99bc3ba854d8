"""Budget periods: the window of time a QPU budget covers (``Settings.budget_period``, or a
user's own), as epoch days (UTC), the unit the ledger's dated charges are kept in
(``usage:{user}:days``: epoch day -> seconds charged that day)."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime, timedelta

from shared.settings import BudgetPeriod

DAY_SECONDS = 86_400
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)

#: How a period is named in messages ("... left this month").
_THIS = {BudgetPeriod.MONTHLY: "this month", BudgetPeriod.WEEKLY: "this week"}


def epoch_day(moment: datetime) -> int:
    """Days since 1970-01-01 UTC of ``moment`` (the ledger's day buckets)."""
    return int((moment - _EPOCH).total_seconds() // DAY_SECONDS)


@dataclass(frozen=True)
class PeriodWindow:
    """The period a budget is counted over at one moment: ``start`` (inclusive) to ``end``
    (exclusive: when the budget resets), both None for ``lifetime``."""

    period: BudgetPeriod
    start: datetime | None = None
    end: datetime | None = None

    @property
    def days(self) -> tuple[int, int] | None:
        """The window as epoch days ``[first, stop)``; None: lifetime (the total is counted)."""
        if self.start is None or self.end is None:
            return None
        return epoch_day(self.start), epoch_day(self.end)

    @property
    def this(self) -> str:
        """The period in words: ``this month``, ``this week``, ``in total``."""
        return _THIS.get(self.period, "in total")

    def describe(self) -> str:
        """The period and when it resets, for messages."""
        if self.end is None:
            return "lifetime budget, never resets"
        return f"{self.period.value} budget, resets at {self.end.isoformat()}"


def window(period: BudgetPeriod | str, moment: datetime) -> PeriodWindow:
    """The period containing ``moment`` (an aware datetime; read in UTC).

    Parameters
    ----------
    period : BudgetPeriod or str
        ``lifetime``, ``monthly`` (the UTC calendar month) or ``weekly`` (Monday 00:00 UTC on).
    moment : datetime
        The time the budget is looked at.

    Returns
    -------
    PeriodWindow
    """
    period = BudgetPeriod(period)
    day = moment.astimezone(UTC).replace(hour=0, minute=0, second=0, microsecond=0)
    if period is BudgetPeriod.MONTHLY:
        start = day.replace(day=1)
        end = (
            start.replace(year=start.year + 1, month=1)
            if start.month == 12
            else (start.replace(month=start.month + 1))
        )
        return PeriodWindow(period, start, end)
    if period is BudgetPeriod.WEEKLY:
        start = day - timedelta(days=day.weekday())
        return PeriodWindow(period, start, start + timedelta(days=7))
    return PeriodWindow(period)
