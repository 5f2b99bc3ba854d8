"""QPU budgets, reservations and the lab-wide semaphore against a real Redis."""

from __future__ import annotations

import threading
import time

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from shared.solvers import SolverError, TransientSolverError
from workers.quota import NoQpuSlotError, QpuMeter, QpuSemaphore, QuotaExceededError, QuotaLedger


@pytest.fixture
def ledger(redis_client, prefix) -> QuotaLedger:
    return QuotaLedger(redis_client, prefix)


def test_reserve_settle_release_keep_the_books(ledger):
    ledger.set_limit("ada", 10.0)
    first = ledger.reserve("ada", "job-a", 3.0, ttl=60)
    second = ledger.reserve("ada", "job-b", 2.0, ttl=60)
    status = ledger.status("ada")
    assert (status.used, status.reserved, status.remaining) == (0.0, 5.0, 5.0)

    assert ledger.settle(first, 1.25) == pytest.approx(1.25)
    ledger.release(second)  # never sent: not charged
    status = ledger.status("ada")
    assert status.used == pytest.approx(1.25)
    assert status.reserved == 0.0
    usage = {job.job_id: job for job in ledger.usage("ada").jobs}
    assert usage["job-a"].seconds == pytest.approx(1.25) and usage["job-a"].problems == 1
    assert "job-b" not in usage


def test_refuses_a_reservation_that_does_not_fit(ledger):
    ledger.set_limit("ada", 1.0)
    held = ledger.reserve("ada", "job", 0.75, ttl=60)
    with pytest.raises(QuotaExceededError) as refused:
        ledger.reserve("ada", "job", 0.5, ttl=60)
    assert isinstance(refused.value, SolverError)  # fails the job, is not retried
    assert not isinstance(refused.value, TransientSolverError)
    assert "0.250 s remaining" in str(refused.value) and "0.500 s" in str(refused.value)
    ledger.settle(held, 0.1)
    ledger.reserve("ada", "job", 0.5, ttl=60)  # fits once the actual time is known


def test_a_user_without_a_limit_is_unlimited_and_check_uses_the_remaining_budget(ledger):
    ledger.reserve("nolimit", "job", 1e6, ttl=60)
    assert ledger.status("nolimit").limit is None
    ledger.set_limit("ada", 2.0)
    ledger.check("ada", 2.0)
    with pytest.raises(QuotaExceededError, match="for this job"):
        ledger.check("ada", 2.5)
    assert ledger.users() == ["ada", "nolimit"]


def test_an_expired_reservation_is_charged_and_a_late_settlement_corrects_it(ledger):
    ledger.set_limit("ada", 10.0)
    lost = ledger.reserve("ada", "job", 2.0, ttl=0.05)  # its worker "dies"
    slow = ledger.reserve("ada", "job", 3.0, ttl=0.05)  # its worker is only slow
    time.sleep(0.1)
    status = ledger.status("ada")
    assert status.reserved == 0.0 and status.used == pytest.approx(5.0)
    assert ledger.settle(slow, 0.5) == pytest.approx(-2.5)
    assert ledger.status("ada").used == pytest.approx(2.5)  # lost: estimate; slow: actual
    assert ledger.job_usage("ada", "job").seconds == pytest.approx(2.5)
    del lost


@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    limit=st.floats(0.0, 5.0),
    problems=st.lists(st.tuples(st.floats(0.01, 2.0), st.floats(0.0, 2.0)), max_size=12),
)
def test_sequential_jobs_never_overspend_by_more_than_one_bundle(
    redis_client, prefix, limit, problems
):
    """Each bundle is reserved at its estimate and charged its actual time: the budget is only
    exceeded by the last bundle's excess over its estimate."""
    ledger = QuotaLedger(redis_client, f"{prefix}:{time.monotonic_ns()}")
    ledger.set_limit("ada", limit)
    charged = 0.0
    for estimate, actual in problems:
        remaining = ledger.status("ada").remaining
        try:
            reservation = ledger.reserve("ada", "job", estimate, ttl=60)
        except QuotaExceededError:
            assert remaining < estimate
            continue
        assert remaining >= estimate - 1e-9
        ledger.settle(reservation, actual)
        charged += actual
        assert ledger.status("ada").used <= limit + max(0.0, actual - estimate) + 1e-9
    assert ledger.status("ada").used == pytest.approx(charged)


def test_concurrent_workers_overspend_at_most_the_in_flight_excess(redis_client, prefix):
    """8 threads spend one budget through the meter; estimates are below the actual time, so
    only the bundles in flight when the budget runs out can overspend, by (actual - estimate)
    each; the semaphore caps how many are in flight."""
    limit, estimate, actual, slots = 6.0, 0.2, 0.3, 3
    ledger = QuotaLedger(redis_client, prefix)
    ledger.set_limit("ada", limit)
    semaphore = QpuSemaphore(redis_client, prefix, limit=slots)
    meter = QpuMeter(ledger, semaphore, slot_ttl=60, slot_wait=30)
    lock = threading.Lock()
    active, peak, sent = [0], [0], [0]

    def worker() -> None:
        while True:
            try:
                with meter.problem("ada", "job", estimate) as charge:
                    with lock:
                        active[0] += 1
                        peak[0] = max(peak[0], active[0])
                    time.sleep(0.002)
                    with lock:
                        active[0] -= 1
                        sent[0] += 1
                    charge.report(actual)
            except QuotaExceededError:
                return

    threads = [threading.Thread(target=worker) for _ in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    used = ledger.status("ada").used
    assert peak[0] <= slots
    assert used == pytest.approx(sent[0] * actual)
    assert limit - estimate < used <= limit + slots * (actual - estimate) + 1e-9
    assert ledger.status("ada").reserved == 0.0
    assert semaphore.in_flight() == 0


def test_semaphore_limits_lab_and_user_and_expires_dead_slots(redis_client, prefix):
    semaphore = QpuSemaphore(redis_client, prefix, limit=2, per_user=1)
    ada = semaphore.try_acquire("ada", ttl=0.05)
    assert ada is not None
    assert semaphore.try_acquire("ada", ttl=60) is None  # ada's share is 1
    bob = semaphore.try_acquire("bob", ttl=60)
    assert bob is not None
    assert semaphore.try_acquire("cy", ttl=60) is None  # lab-wide limit 2
    assert semaphore.in_flight() == 2
    time.sleep(0.1)  # ada's worker died without releasing: the slot expires
    cy = semaphore.try_acquire("cy", ttl=60)
    assert cy is not None
    with pytest.raises(NoQpuSlotError, match="2 lab-wide QPU slots"):
        semaphore.acquire("dee", ttl=60, wait=0.05)
    semaphore.release("bob", bob)
    with semaphore.slot("dee", ttl=60, wait=1):
        assert semaphore.in_flight() == 2
    assert semaphore.in_flight() == 1


def test_meter_releases_the_reservation_and_slot_when_the_solve_fails(redis_client, prefix):
    ledger = QuotaLedger(redis_client, prefix)
    ledger.set_limit("ada", 1.0)
    semaphore = QpuSemaphore(redis_client, prefix, limit=1)
    meter = QpuMeter(ledger, semaphore, slot_ttl=60, slot_wait=1)
    with pytest.raises(RuntimeError), meter.problem("ada", "job", 0.5):
        raise RuntimeError("solver blew up before any sample came back")
    assert ledger.status("ada").used == 0.0 and ledger.status("ada").reserved == 0.0
    assert semaphore.in_flight() == 0
    with pytest.raises(QuotaExceededError), meter.problem("ada", "job", 2.0):
        pass
    assert semaphore.in_flight() == 0  # a refused reservation gives its slot back
