"""Recovery with the session's real Redis and workers: the watchdog re-sends a stalled job's lost
bundles (or fails it with a reason), the API answers 503 while Redis is down, and /readyz names
the queues no worker consumes."""

from __future__ import annotations

import itertools

import harness
import numpy as np
import pytest
from fastapi.testclient import TestClient

from api.app import create_app
from shared.config import LevelConfig, MatchConfig
from shared.disparity_range import RangeEstimate
from shared.pipeline import run_pipeline
from shared.pyramid import plan
from shared.synthetic import make_scene
from workers import orchestration
from workers.app import make_celery
from workers.embedded_redis import free_port
from workers.records import JobRecord, JobState, new_job_id, now
from workers.store import JobStore
from workers.watchdog import Watchdog, resend_count

pytestmark = pytest.mark.service


@pytest.fixture
def lose_chords(monkeypatch):
    """Chords sent in this process vanish, as when the worker holding their tasks is SIGKILLed."""
    monkeypatch.setattr(orchestration, "chord", lambda header: lambda callback: None)


PAPER_TWO_LEVELS = {
    "preset": "paper",
    "levels": [LevelConfig(downsample=2, candidates=3), LevelConfig(downsample=1, candidates=3)],
    "median": False,
    "bilateral": False,
}


def started_job(
    store: JobStore, solver: str, seed: int = 4, options: dict | None = None
) -> tuple[str, MatchConfig, tuple]:
    """A job started in process whose first level's tasks were lost (never reached a worker)."""
    scene = make_scene(32, 48, max_disparity=8, seed=seed)
    options = PAPER_TWO_LEVELS if options is None else options
    config = MatchConfig(solver=solver, max_disparity=8, seed=seed, **options)
    record = JobRecord(
        id=new_job_id(),
        config=config,
        width=48,
        height=32,
        created_at=now(),
        disparity_range=RangeEstimate(8, "given").as_dict(),
        levels_total=len(plan(config, 8)),
    )
    store.create(record, {"left": scene.left, "right": scene.right})
    orchestration.start_job(make_celery(store.settings, with_tasks=False), store, record.id)
    return record.id, config, (scene.left, scene.right)


def fast_watchdog(store: JobStore) -> tuple[Watchdog, itertools.count]:
    """A watchdog whose clock passes the stall time at each reading (``next(clock)`` too).

    Parameters
    ----------
    store : JobStore
        The store the watchdog watches.

    Returns
    -------
    tuple of (Watchdog, itertools.count)
        The watchdog and its clock."""
    clock = itertools.count(step=store.settings.watchdog_stall_seconds + 1)
    celery = make_celery(store.settings, with_tasks=False)
    return Watchdog(celery, store, "test", clock=lambda: next(clock)), clock


def tick_until(watchdog: Watchdog, clock: itertools.count, job_id: str, action: str) -> None:
    """Advance the fake clock past the stall time until the watchdog does ``action``."""
    for _ in range(4):
        for job, done in watchdog.tick():
            if job == job_id and done == action:
                return
        next(clock)
    raise AssertionError(f"the watchdog did not {action} job {job_id}")


@pytest.mark.parametrize(
    ("solver", "options"),
    [("fake-slow", PAPER_TWO_LEVELS), ("fake-routed", {"preset": "accurate"})],
    ids=["paper", "accurate"],
)
def test_watchdog_resends_lost_bundles_and_the_job_finishes_identically(
    settings, workers, lose_chords, monkeypatch, solver, options
):
    store = JobStore.from_settings(settings)
    job_id, config, (left, right) = started_job(store, solver, options=options)
    assert store.get(job_id).state is JobState.RUNNING
    assert store.solved_count(job_id, 0) == 0  # nothing was sent

    monkeypatch.undo()  # from now on chords reach the workers
    watchdog, clock = fast_watchdog(store)
    before = resend_count(store)
    tick_until(watchdog, clock, job_id, "resent")
    assert resend_count(store) > before  # counted for /metrics

    record = harness_wait(store, job_id)
    assert record.state is JobState.SUCCEEDED, record.error
    assert len(record.levels) == record.levels_total >= 2
    expected = run_pipeline(left, right, config).disparity
    assert np.array_equal(store.load_result(job_id), expected)


def test_watchdog_fails_a_job_no_worker_can_run_with_a_reason(settings, workers, lose_chords):
    # the watchdog asks the workers 11 times here (per re-send what they consume, run and
    # hold), each ask waiting the whole inspect timeout: 0.5 s made it 5.5 s or more; a late
    # reply changes nothing here (no worker consumes the queue, nothing of the job is in flight)
    store = JobStore.from_settings(settings.model_copy(update={"inspect_timeout": 0.1}))
    job_id, *_ = started_job(store, "fake-unavailable")
    watchdog, _ = fast_watchdog(store)
    actions = []
    for _ in range(settings.watchdog_max_resends + 2):
        actions += [action for job, action in watchdog.tick() if job == job_id]
    assert actions == ["resent"] * settings.watchdog_max_resends + ["failed"]
    record = store.get(job_id)
    assert record.state is JobState.FAILED
    assert "no progress" in record.error and "'fake-unavailable'" in record.error


def test_api_answers_503_with_a_message_while_redis_is_down(settings, admin_key):
    down = settings.model_copy(update={"redis_url": f"redis://127.0.0.1:{free_port()}/0"})
    with harness.api_client(down, admin_key) as client:
        for method, path in [("GET", "/v1/jobs"), ("GET", f"/v1/jobs/{'a' * 32}")]:
            response = client.request(method, path)
            assert response.status_code == 503, response.text
            assert "Redis" in response.json()["detail"] and "Try again" in response.json()["detail"]
            assert response.headers["retry-after"]
        ready = client.get("/readyz")
        assert ready.status_code == 503 and ready.json()["redis"].startswith("unreachable")


def test_readyz_names_queues_without_a_consumer(settings, workers, client):
    ready = client.get("/readyz")
    assert ready.status_code == 200, ready.text
    idle = ready.json()["queues_without_consumer"]
    assert "fake-unavailable" in idle and "exact" not in idle and "control" not in idle

    orphaned = settings.model_copy(update={"control_queue": "nobody-consumes-this"})
    with TestClient(create_app(orphaned), raise_server_exceptions=False) as other:
        ready = other.get("/readyz")
    assert ready.status_code == 503
    assert ready.json()["status"] == "unavailable"
    assert "nobody-consumes-this" in ready.json()["queues_without_consumer"]


def harness_wait(store: JobStore, job_id: str, timeout: float = 60.0) -> JobRecord:
    import time

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        record = store.get(job_id)
        if record.state.terminal:
            return record
        time.sleep(0.1)
    raise AssertionError(f"job {job_id} still {record.state} after {timeout} s")


def test_watchdog_leaves_a_job_waiting_in_a_busy_queue_alone(settings, workers, lose_chords):
    store = JobStore.from_settings(settings)
    job_id, *_ = started_job(store, "fake-unavailable")
    watchdog, _ = fast_watchdog(store)
    before = watchdog.queue_length("fake-unavailable")
    watchdog.celery.send_task(
        "qhsm.solve_rows", args=("other-job", 0, [[0, 1]]), queue="fake-unavailable"
    )
    assert watchdog.queue_length("fake-unavailable") == before + 1  # kombu's list, by its key
    # as if a worker consumed the queue but were busy with other jobs' tasks
    watchdog.consumed_queues = lambda: {"fake-unavailable", settings.control_queue}
    actions = []
    for _ in range(settings.watchdog_max_resends + 3):
        actions += [action for job, action in watchdog.tick() if job == job_id]
    assert set(actions) == {"waiting"}
    assert store.get(job_id).state is JobState.RUNNING
    store.fail(job_id, "test over")
