"""Limits checked at submit (issue 10, item 2): solver parameters outside the solver's schema
are a 422 that states the allowed range; a user with too many jobs in flight gets a 429."""

from __future__ import annotations

import json
import uuid

import harness
from fastapi.testclient import TestClient

from api.app import create_app
from api.users import UserStore
from shared.synthetic import make_scene

SCENE = make_scene(16, 24, max_disparity=4, seed=4)
FILES = {"left": ("l.png", harness.png(SCENE.left)), "right": ("r.png", harness.png(SCENE.right))}


def submit(client, params: dict, headers: dict | None = None):
    return client.post(
        "/v1/jobs", files=FILES, data={"params": json.dumps(params)}, headers=headers or {}
    )


def test_unbounded_solver_parameters_are_422_with_the_allowed_range(api):
    stall = {"solver": "sa", "solver_params": {"num_reads": 10, "num_sweeps": 100_000_000}}
    response = submit(api, stall)
    assert response.status_code == 422, response.text
    detail = response.json()["detail"]
    assert "num_sweeps" in detail and "less than or equal to 100000" in detail
    assert "num_sweeps (int, 1..100000)" in detail

    response = submit(api, {"solver": "sa", "solver_params": {"num_reads": 1e9}})
    assert response.status_code == 422 and "num_reads (int, 1..1000)" in response.json()["detail"]

    response = submit(api, {"solver": "tabu", "solver_params": {"no_such": 1}})
    assert response.status_code == 422 and "no_such: unknown parameter" in response.json()["detail"]


def test_parameters_are_stored_as_validated(api):
    response = submit(api, {"solver": "sa", "solver_params": {"num_reads": "12"}})
    assert response.status_code == 202, response.text
    job = api.get(f"/v1/jobs/{response.json()['id']}").json()
    assert job["config"]["solver_params"] == {"num_reads": 12}
    api.delete(f"/v1/jobs/{job['id']}")


def test_a_user_with_too_many_jobs_in_flight_gets_429(api_settings):
    users = UserStore.from_settings(api_settings)
    _, capped = users.create_user(f"capped-{uuid.uuid4().hex[:6]}")
    _, other = users.create_user(f"other-{uuid.uuid4().hex[:6]}")
    mine, theirs = {"Authorization": f"Bearer {capped}"}, {"Authorization": f"Bearer {other}"}
    settings = api_settings.model_copy(update={"max_active_jobs_per_user": 2})
    # no worker runs in these tests: accepted jobs stay queued, i.e. in flight
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        first = submit(client, {"solver": "exact"}, mine)
        assert first.status_code == 202
        assert submit(client, {"solver": "exact"}, mine).status_code == 202
        refused = submit(client, {"solver": "exact"}, mine)
        assert refused.status_code == 429, refused.text
        detail = refused.json()["detail"]
        assert "already has 2 jobs queued or running" in detail
        assert "QHSM_MAX_ACTIVE_JOBS_PER_USER=2" in detail and "cancel" in detail
        assert submit(client, {"solver": "exact"}, theirs).status_code == 202  # per user

        assert client.delete(f"/v1/jobs/{first.json()['id']}", headers=mine).status_code == 200
        assert submit(client, {"solver": "exact"}, mine).status_code == 202
    unlimited = api_settings.model_copy(update={"max_active_jobs_per_user": 0})
    with TestClient(create_app(unlimited), raise_server_exceptions=False) as client:
        assert submit(client, {"solver": "exact"}, mine).status_code == 202  # 0: no limit


def test_the_cap_counts_only_jobs_still_in_flight(api_settings):
    """A finished job leaves the count at once; a record that vanished is dropped from it."""
    from workers.records import JobState
    from workers.store import JobStore

    store = JobStore.from_settings(api_settings)
    users = UserStore.from_settings(api_settings)
    name = f"counted-{uuid.uuid4().hex[:6]}"
    _, key = users.create_user(name)
    headers = {"Authorization": f"Bearer {key}"}
    with TestClient(create_app(api_settings), raise_server_exceptions=False) as client:
        ids = [submit(client, {"solver": "exact"}, headers).json()["id"] for _ in range(3)]
    assert store.active_jobs(name) == 3
    store.transition(ids[0], JobState.FAILED, {JobState.QUEUED}, error="test")
    assert store.active_jobs(name) == 2
    store.redis.delete(store.key("job", ids[1]))
    assert store.active_jobs(name) == 1
    assert store.redis.hlen(store.key("jobs", "active")) >= 1


def test_simultaneous_submits_never_pass_the_cap(api_settings):
    """The cap is counted and taken in one Redis script: 30 submits at once with a cap of 8
    accept exactly 8 (the count used to be read, then written: 12 to 16 got through)."""
    import threading

    import httpx
    import redis
    import uvicorn

    from workers.embedded_redis import free_port

    users = UserStore.from_settings(api_settings)
    _, key = users.create_user(f"racer-{uuid.uuid4().hex[:6]}")
    settings = api_settings.model_copy(update={"max_active_jobs_per_user": 8})
    port = free_port()
    server = uvicorn.Server(
        uvicorn.Config(create_app(settings), host="127.0.0.1", port=port, log_config=None)
    )
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    while not server.started:
        assert thread.is_alive()
    client = redis.Redis.from_url(settings.redis_url)
    uploads = f"{settings.key_prefix}:job:*:upload"
    kept = len(list(client.scan_iter(match=uploads)))
    start = threading.Barrier(30)
    codes: list[int] = []

    def one() -> None:
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=60) as client:
            start.wait()
            response = client.post(
                "/v1/jobs",
                files=FILES,
                data={"params": json.dumps({"solver": "exact"})},
                headers={"Authorization": f"Bearer {key}"},
            )
            codes.append(response.status_code)

    racers = [threading.Thread(target=one) for _ in range(30)]
    try:
        for racer in racers:
            racer.start()
        for racer in racers:
            racer.join(120)
    finally:
        server.should_exit = True
        thread.join(10)
    assert sorted(set(codes)) == [202, 429]
    assert codes.count(202) == 8, codes
    assert len(list(client.scan_iter(match=uploads))) == kept + 8  # refused: no upload left
