"""GET /metrics (issue 10, item 20) after real jobs on real workers: Prometheus text with jobs by
state, bundles and task times per solver, queue depths, QPU seconds per user, watchdog re-sends."""

from __future__ import annotations

import time
import uuid

import harness
import pytest
from prometheus_client.parser import text_string_to_metric_families

from shared.config import LevelConfig
from shared.synthetic import make_scene
from workers.app import make_celery
from workers.quota import QuotaLedger
from workers.telemetry import Telemetry

pytestmark = pytest.mark.service


def scrape(client) -> dict[tuple[str, tuple], float]:
    response = client.get("/metrics")
    assert response.status_code == 200, response.text
    assert response.headers["content-type"].startswith("text/plain; version=")
    return {
        (sample.name, tuple(sorted(sample.labels.items()))): sample.value
        for family in text_string_to_metric_families(response.text)
        for sample in family.samples
    }


def value(samples, name: str, **labels) -> float:
    return samples.get((name, tuple(sorted(labels.items()))), 0.0)


def quiet_scrape(client, settings, workers, seconds: float = 3.0, limit: float = 60.0) -> dict:
    """A scrape once the session's workers run no task and no ``exact`` bundle has been solved
    for ``seconds``: they may still be finishing an earlier test's (e.g. cancelled) job, whose
    bundles would count (on a loaded machine one chunk can outlast any fixed quiet period)."""
    inspect = make_celery(settings, with_tasks=False).control.inspect(
        destination=[worker.hostname for worker in workers.values()], timeout=1.0
    )
    deadline = time.monotonic() + limit
    samples = scrape(client)
    while time.monotonic() < deadline:
        time.sleep(seconds)
        again = scrape(client)
        key = ("qhsm_bundles_solved_total", (("solver", "exact"),))
        idle = not any((inspect.active() or {}).values())
        if idle and again.get(key) == samples.get(key):
            return again
        samples = again
    return samples


def test_metrics_follow_jobs_queues_usage_and_resends(client, settings, workers):
    scene = make_scene(16, 24, max_disparity=4, seed=8)
    left, right = harness.png(scene.left), harness.png(scene.right)
    level = {
        "preset": "paper",
        "levels": [LevelConfig(downsample=1, candidates=4).model_dump()],
        "max_disparity": 4,
    }
    before = quiet_scrape(client, settings, workers)

    done = harness.submit(client, left, right, {**level, "solver": "exact"})
    assert harness.wait_for(client, done)["state"] == "succeeded"
    # no worker of the session consumes tabu: its tasks wait in the queue
    waiting = harness.submit(client, left, right, {**level, "solver": "tabu"})
    harness.wait_for(client, waiting, states={"running"})
    user = f"metered-{uuid.uuid4().hex[:6]}"
    ledger = QuotaLedger.from_settings(settings)
    ledger.set_limit(user, 10.0)
    ledger.settle(ledger.reserve(user, "job", 1.0, ttl=60), 0.25)
    Telemetry.from_settings(settings).resent(3)

    chunks = 16 // settings.rows_per_task
    deadline = time.monotonic() + 10  # the chord is sent just after the job turns running
    while (after := scrape(client)) and value(after, "qhsm_queue_depth", queue="tabu") < chunks:
        assert time.monotonic() < deadline, "the tabu tasks never reached their queue"
        time.sleep(0.1)
    assert value(after, "qhsm_jobs", state="succeeded") >= 1 + value(
        before, "qhsm_jobs", state="succeeded"
    )
    assert value(after, "qhsm_jobs", state="running") >= 1
    solved = value(after, "qhsm_bundles_solved_total", solver="exact") - value(
        before, "qhsm_bundles_solved_total", solver="exact"
    )
    assert solved == 16  # one level, 16 single-row bundles
    tasks = value(after, "qhsm_task_seconds_count", solver="exact") - value(
        before, "qhsm_task_seconds_count", solver="exact"
    )
    assert tasks == 16 // settings.rows_per_task
    assert value(after, "qhsm_task_seconds_sum", solver="exact") > 0
    assert value(after, "qhsm_queue_depth", queue="tabu") == chunks
    assert (("qhsm_queue_depth", (("queue", settings.control_queue),))) in after
    assert value(after, "qhsm_qpu_seconds_used_total", user=user) == pytest.approx(0.25)
    resends = value(after, "qhsm_watchdog_resends_total") - value(
        before, "qhsm_watchdog_resends_total"
    )
    assert resends == 3
    # the succeeded job's pixels by the stage that decided them: the paper preset's exact rows
    decided = {
        stage: value(after, "qhsm_pixels_decided_total", solver="exact", stage=stage)
        - value(before, "qhsm_pixels_decided_total", solver="exact", stage=stage)
        for stage in ("certified", "host", "solver", "filtered")
    }
    assert decided["certified"] > 0 and decided["host"] == decided["solver"] == 0
    assert decided["certified"] + decided["filtered"] == 16 * 24
    client.delete(f"/v1/jobs/{waiting}")


def test_metrics_need_an_admin_key(client, settings):
    from api.users import UserStore

    _, key = UserStore.from_settings(settings).create_user(f"plain-{uuid.uuid4().hex[:6]}")
    assert client.get("/metrics", headers={"Authorization": f"Bearer {key}"}).status_code == 403
    assert client.get("/metrics", headers={"Authorization": ""}).status_code == 401
