"""Fair share between users (issue 20, item 7) with the session's real workers: each user's
bundles wait in a queue of their own and the workers take from the users' queues in turn, so a
small job of one user is not stuck behind a large job another user queued first."""

from __future__ import annotations

import time
import uuid

import harness
import pytest
from fastapi.testclient import TestClient

from api.users import UserStore
from shared.synthetic import make_scene

pytestmark = pytest.mark.service


def user_client(settings, name: str) -> TestClient:
    _, key = UserStore.from_settings(settings).create_user(
        f"{name}-{uuid.uuid4().hex[:6]}", qpu_seconds=None
    )
    return harness.api_client(settings, key)


def test_a_small_job_is_served_between_another_users_large_jobs_tasks(settings, workers):
    big, small = make_scene(64, 24, max_disparity=6, seed=1), make_scene(8, 24, 6, seed=2)
    params = harness.one_level(solver="fake-slow")
    with user_client(settings, "alice") as alice, user_client(settings, "bob") as bob:
        first = harness.submit(alice, harness.png(big.left), harness.png(big.right), params)
        harness.wait_for(alice, first, states={"running"})
        deadline = time.monotonic() + 30
        while alice.get(f"/v1/jobs/{first}").json()["progress"]["bundles_done"] < 4:
            assert time.monotonic() < deadline
            time.sleep(0.05)
        # alice has 15 tasks of 4 bundles queued (15 x 4 x 0.25 s on two processes: 7.5 s)
        second = harness.submit(bob, harness.png(small.left), harness.png(small.right), params)
        done = harness.wait_for(bob, second, timeout=60)
        assert done["state"] == "succeeded", done
        theirs = alice.get(f"/v1/jobs/{first}").json()
        # bob's two tasks were taken between alice's, not after all of them
        assert theirs["state"] == "running", theirs["state"]
        assert theirs["progress"]["bundles_done"] < 0.7 * theirs["progress"]["bundles_total"]
        assert harness.wait_for(alice, first, timeout=120)["state"] == "succeeded"


def test_a_free_worker_takes_from_the_user_with_fewest_tasks_running(settings, monkeypatch):
    """kombu's queue order: the users with fewer solver tasks running lab-wide come first,
    the solvers' own queues before them; kombu's rotation decides among equals."""
    import redis

    from workers import fair

    # what the worker's context hands the strategy at start (kombu builds it without arguments)
    monkeypatch.setattr(fair.FewestRunningFirst, "settings", settings)
    client = redis.Redis.from_url(settings.redis_url)
    prefix = settings.key_prefix
    for task in ("t1", "t2", "t3"):
        fair.task_started(client, prefix, "sa~busy", task, limit=60)
    fair.task_started(client, prefix, "exact~some", "t4", limit=60)
    fair.task_started(client, prefix, "sa~lapsed", "t5", limit=-1)  # its worker was killed
    cycle = fair.FewestRunningFirst(["sa~busy", "exact~some", "sa", "sa~idle", "sa~lapsed"])
    assert cycle.consume(5) == ["sa", "sa~idle", "sa~lapsed", "exact~some", "sa~busy"]
    for task in ("t1", "t2", "t3"):
        fair.task_ended(client, prefix, "sa~busy", task)
    cycle._counts = (0.0, {})
    cycle.rotate("sa~idle")  # it just gave a message: after its equals
    assert cycle.consume(5)[:4] == ["sa", "sa~busy", "sa~lapsed", "sa~idle"]
