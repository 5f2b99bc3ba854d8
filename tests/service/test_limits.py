"""No user can stall the service (issue 10, item 2), with real workers: solver tasks have time
limits, a cancel terminates the job's running tasks, and orchestration has a worker of its own,
so a new job starts while every solver process is busy (that `qhsm serve` starts it so:
tests/service/test_serve.py)."""

from __future__ import annotations

import time

import harness
import pytest

from shared.synthetic import make_scene
from workers.store import JobStore

pytestmark = pytest.mark.service


@pytest.fixture(scope="module")
def pair():
    scene = make_scene(32, 48, max_disparity=8, seed=6)
    return harness.png(scene.left), harness.png(scene.right)


def one_level(solver: str, **extra) -> dict:
    """One level with eight candidates for ``solver`` (see ``harness.one_level``)."""
    return harness.one_level(candidates=8, solver=solver, **extra)


#: The most a user may ask of sa (native code, no fixing): about 20 s per bundle here, so a task
#: of 4 bundles keeps its process busy for over a minute.
HEAVY_SA = one_level(
    "sa", solver_params={"num_reads": 20, "num_sweeps": 100_000, "preprocess": "none"}
)


def wait_until(condition, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"not within {timeout} s: {what}")


def occupy_every_solver_process(client, pair, store: JobStore) -> str:
    """Submit the heavy sa job and wait until both processes of worker ``main`` run it."""
    job_id = harness.submit(client, *pair, HEAVY_SA)
    wait_until(lambda: len(store.running_tasks(job_id)) >= 2, 30, "two sa tasks running")
    return job_id


@pytest.fixture
def store(settings) -> JobStore:
    return JobStore.from_settings(settings)


def test_soft_time_limit_fails_the_job_with_a_message(client, pair, settings):
    limit = settings.solver_time_limits["fake-sleepy"]
    started = time.monotonic()
    job_id = harness.submit(client, *pair, one_level("fake-sleepy"))
    status = harness.wait_for(client, job_id, timeout=30)
    assert status["state"] == "failed"
    assert f"ran out of time after the time limit of {limit:g} s per task" in status["error"]
    assert "QHSM_SOLVER_TIME_LIMITS" in status["error"]
    assert time.monotonic() - started < 15  # the fake would sleep 600 s


def test_hard_time_limit_kills_a_task_that_ignores_the_soft_one(
    client, pair, workers, store, settings
):
    hard = settings.solver_time_limits["fake-hung"] + settings.task_time_limit_grace
    before = set(workers["main"].children())
    job_id = harness.submit(client, *pair, one_level("fake-hung"))
    status = harness.wait_for(client, job_id, timeout=30)
    assert status["state"] == "failed"
    assert f"was stopped after the time limit of {hard:g} s" in status["error"]
    # the stuck pool process was killed and replaced
    wait_until(lambda: before - set(workers["main"].children()), 10, "a pool process replaced")


def test_cancel_terminates_the_running_tasks_of_the_job(client, pair, workers, store):
    before = set(workers["main"].children())
    heavy = occupy_every_solver_process(client, pair, store)

    cancelled = client.delete(f"/v1/jobs/{heavy}")
    assert cancelled.status_code == 200 and cancelled.json()["state"] == "cancelled"
    # both processes running the heavy job were killed (each sa bundle takes minutes)...
    wait_until(lambda: not before & set(workers["main"].children()), 15, "pool processes killed")
    # ...so another job's small solve runs at once instead of waiting for them
    started = time.monotonic()
    small = harness.submit(client, *pair, one_level("exact"))
    assert harness.wait_for(client, small, timeout=30)["state"] == "succeeded"
    assert time.monotonic() - started < 30
    assert client.get(f"/v1/jobs/{heavy}").json()["state"] == "cancelled"


def test_a_failing_task_stops_the_other_running_tasks_of_its_job(client, pair, workers, markers):
    job_id = harness.submit(client, *pair, one_level("fake-split"))
    status = harness.wait_for(client, job_id, timeout=30)
    assert status["state"] == "failed" and "fake-split: this bundle fails" in status["error"]
    [busy] = markers.glob("split-busy-*")  # the task that sleeps 600 s ...
    pid = int(busy.name.removeprefix("split-busy-"))
    # ... is killed with its process instead of holding a worker for 10 minutes
    wait_until(lambda: pid not in workers["main"].children(), 10, "sleeping task killed")


def test_orchestration_runs_while_every_solver_process_is_busy(client, pair, store):
    heavy = occupy_every_solver_process(client, pair, store)
    try:
        small = harness.submit(client, *pair, one_level("exact"))
        # start_job ran and launched the first level although no solver process is free
        status = wait_until(
            lambda: (
                (job := client.get(f"/v1/jobs/{small}").json())["progress"]["bundles_total"] and job
            ),
            10,
            "the small job's first level launched",
        )
        assert status["state"] == "running" and status["progress"]["level"] == 1
        assert status["progress"]["bundles_total"] == 32
    finally:
        client.delete(f"/v1/jobs/{heavy}")
    assert harness.wait_for(client, small, timeout=30)["state"] == "succeeded"


def test_a_task_that_needs_more_memory_than_a_process_has_fails_its_job(client, pair):
    """Pool processes have an address-space ceiling (QHSM_TASK_MEMORY_LIMIT_MB): a bundle
    that allocates past it fails its job with a reason instead of taking the machine."""
    job_id = harness.submit(client, *pair, one_level("fake-hog"))
    status = harness.wait_for(client, job_id, timeout=60)
    assert status["state"] == "failed", status
    assert f"limit of {harness.MEMORY_LIMIT_MB} MiB" in status["error"]
    assert "QHSM_TASK_MEMORY_LIMIT_MB" in status["error"]
    # the worker is fine afterwards
    done = harness.wait_for(client, harness.submit(client, *pair, one_level("exact")))
    assert done["state"] == "succeeded", done


def test_an_exact_enumeration_is_refused_above_its_size_before_it_allocates(client, pair):
    """dimod.ExactSolver holds 2^n states: the allowlist gives it a largest bundle."""
    params = one_level("dimod:dimod.ExactSolver", encoding="one-hot")
    job_id = harness.submit(client, *pair, params)
    status = harness.wait_for(client, job_id, timeout=60)
    assert status["state"] == "failed", status
    assert "enumerates every state" in status["error"]
