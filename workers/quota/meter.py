"""Metering of a job's bundles: each metered problem runs inside a lab-wide slot and a
reservation of its estimate (:mod:`shared.solvers.meters.qpu_time`), and is charged the time
its sample set reports (read by the solver's meter, :mod:`shared.solvers.meters`)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import redis

from shared.config import Settings
from shared.solvers.meters.qpu_time import batch_estimate, bundle_estimate
from shared.solvers.qpu.problems import current
from shared.solvers.resolved import ResolvedSolver
from workers.quota.ledger import QuotaLedger
from workers.quota.semaphore import QpuSemaphore


@dataclass
class Charge:
    """What the caller reports after the solve: the seconds the sample set says it used."""

    seconds: float = 0.0
    sent: bool = False

    def report(self, seconds: float) -> None:
        """Record the reported seconds (negative counts as zero) and that the problem was sent."""
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
        from workers.redis_client import client_for

        client = client or client_for(settings)
        return cls(
            QuotaLedger(client, settings.key_prefix, settings.budget_period),
            QpuSemaphore.from_settings(settings, client),
            settings.qpu_slot_ttl,
            settings.qpu_slot_wait,
        )

    @contextmanager
    def problem(self, user: str, job_id: str, estimate: float) -> Iterator[Charge]:
        """Take a slot, reserve ``estimate`` (QuotaExceededError when it does not fit), yield a
        :class:`Charge` for the caller to fill in, then settle and free the slot.

        If the body raises before reporting, the reservation is released uncharged (failed
        problems are not billed by D-Wave either). The ids of the D-Wave problems the body sent
        (in an open ``sent_problems`` log) are kept with the job's usage, and counted.

        Parameters
        ----------
        user, job_id : str
            Whose budget, and the job charged.
        estimate : float
            Seconds to reserve; the slot and the reservation lapse ``slot_ttl`` after it.

        Returns
        -------
        Iterator[Charge]
            One :class:`Charge`, for the ``with`` body to :meth:`Charge.report` on.
        """
        ttl = self.slot_ttl + estimate
        log = current()  # the task's D-Wave problems (shared.solvers.qpu.problems)
        before = len(log.ids) if log is not None else 0
        with self.semaphore.slot(user, ttl, self.slot_wait):
            reservation = self.ledger.reserve(user, job_id, estimate, ttl)
            charge = Charge()
            try:
                yield charge
            finally:
                if charge.sent:
                    ids = log.ids[before:] if log is not None else []
                    self.ledger.settle(reservation, charge.seconds, len(ids) or 1, ids)
                else:
                    self.ledger.release(reservation)


def solve_metered(
    meter: QpuMeter,
    owner: str,
    job_id: str,
    inputs,
    solver: ResolvedSolver,
    bundles: list,
    still_running=lambda: True,
    level_estimate: float | None = None,
):
    """The level inference's ``solve`` for a metered solver: one bundle at a time, each inside
    a lab-wide slot and a reservation of its estimate, charged what its sample set reports; a
    solver that joins bundles into one problem (``solve_batch``: the hybrid solvers) takes all
    of them in one slot and one reservation, charged what their results report together.

    Parameters
    ----------
    meter : QpuMeter
        Slots and the ledger.
    owner, job_id : str
        Whose budget, and the job charged.
    inputs : LevelInputs
        The level's inputs, as for ``shared.inference.solve_bundles``.
    solver : ResolvedSolver
        The job's solver, resolved with its ``MatchConfig`` (``solver.config``).
    bundles : list
        The bundle specs to solve, in order.
    still_running : callable
        Checked before each bundle; false stops the job (cancelled or failed).
    level_estimate : float, optional
        The job's accepted estimate of the level (seconds): a batch reserves its share of it
        (the bundles' share of the level's), so a level is reserved what its estimate said;
        None: estimated here from the bundles (``batch_estimate``).

    Returns
    -------
    list or None
        The results, or None when ``still_running()`` turned false: the remaining bundles are
        then not sent. Raises :class:`~workers.quota.ledger.QuotaExceededError` when the owner's
        budget cannot cover the next bundle.
    """
    from shared.inference import inference_for
    from shared.solvers.meters import meter_for

    config = solver.config
    assert config is not None, "solve_metered needs the solver resolved with the job's config"
    inference = inference_for(solver)  # the task's resolution, not a second one
    sent = inference.bundle_config(inputs, config)  # as the bundles are solved (tiles: 4 rows)
    kind = meter_for(solver.spec.name)
    charged_seconds = kind.charged_seconds if kind is not None else (lambda timing: 0.0)
    if solver.kind == "batch":  # one slot, one reservation
        if not still_running():
            return None
        given = [inputs.as_bundle(spec) for spec in bundles]
        if level_estimate is None:
            reserve = batch_estimate(inputs, sent, given, solver=solver)
        else:
            share = len(given) / max(len(inference.planned(inputs, config)), len(given), 1)
            reserve = level_estimate * share
        with meter.problem(owner, job_id, reserve) as charge:
            results = inference.solve(inputs, config, given)
            charge.report(sum(charged_seconds(result.timing) for result in results))
        return results
    results = []
    for spec in bundles:
        if not still_running():
            return None
        bundle = inputs.as_bundle(spec)
        start, stop, first, last = bundle.as_list()
        estimate = bundle_estimate(inputs, sent, start, stop, last - first, solver=solver)
        with meter.problem(owner, job_id, estimate) as charge:
            [result] = inference.solve(inputs, config, [bundle])
            charge.report(charged_seconds(result.timing))
        results.append(result)
    return results
