"""Users, keys and QPU quotas through the real service: HTTP + Celery workers + Redis.

A dedicated worker consumes the ``qpu-sim`` and ``hybrid-sim`` queues with ``DWAVE_API_TOKEN``
set to a sentinel; the stand-ins are charged what the timing model says the real service would
take, through the same path as the real QPU's reported time. At the end, the sentinel
must appear in no response body, log line or Redis value.
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

import harness
import pytest
import redis

from api.users import UserStore
from shared.solvers.meters import qpu_time
from shared.solvers.registry import resolve
from shared.synthetic import make_scene

pytestmark = pytest.mark.service

SENTINEL = "sentinel-dwave-token-7f3a9c"
QPU_SLOTS = 2


class Recorder(logging.Handler):
    """Keeps every log line of this (API) process."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(self.format(record))


@pytest.fixture(scope="module")
def api_log():
    recorder = Recorder()
    root = logging.getLogger()
    root.addHandler(recorder)
    yield recorder
    root.removeHandler(recorder)


@pytest.fixture(scope="module")
def bodies():
    return []


@pytest.fixture(scope="module")
def users(settings) -> UserStore:
    return UserStore.from_settings(settings)


@pytest.fixture(scope="module")
def qpu_worker(settings, service_dir):
    """One worker for qpu-sim and hybrid-sim, two processes, the sentinel as its token."""
    from workers.app import make_celery
    from workers.supervisor import WorkerProcess, wait_for_workers, worker_env

    env = worker_env(settings, settings.redis_url, dwave=True)
    env["DWAVE_API_TOKEN"] = SENTINEL
    here = str(Path(__file__).parent)  # the test plugin (its entry points)
    env["PYTHONPATH"] = os.pathsep.join([here, env.get("PYTHONPATH", "")])
    env["QHSM_QPU_MAX_IN_FLIGHT"] = str(QPU_SLOTS)
    log = service_dir / "logs" / "qpu.log"
    queues = ["qpu-sim", "hybrid-sim"]
    worker = WorkerProcess(f"qpu-{settings.key_prefix}", queues, 2, env, log).start()
    try:
        wait_for_workers(make_celery(settings, with_tasks=False), [worker.hostname])
        yield worker
    finally:
        harness.stop_workers([worker])


@pytest.fixture(scope="module")
def http(settings, workers, qpu_worker, bodies, api_log):
    """An API client without a key of its own, recording every response body."""
    from fastapi.testclient import TestClient

    from api.app import create_app

    def record(response) -> None:
        response.read()
        bodies.append(response.text)

    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        client.event_hooks = {"request": [], "response": [record]}
        yield client


def bearer(key: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {key}"}


@pytest.fixture(scope="module")
def pair():
    scene = make_scene(16, 24, max_disparity=6, seed=1)
    return harness.png(scene.left), harness.png(scene.right)


QPU_PARAMS = {
    "preset": "paper",  # small coarse levels keep the QPU stand-in quick
    "solver": "qpu-sim",
    "encoding": "domain-wall",
    "max_disparity": 6,
    "median": False,
    "bilateral": False,
    "solver_params": {"num_reads": 5},
}


def job_estimate(shape=(16, 24)) -> qpu_time.JobEstimate:
    from shared.config import MatchConfig

    return qpu_time.job_seconds(resolve(MatchConfig.model_validate(QPU_PARAMS)), shape, 6)


def submit(http, key, pair, params, expect=202):
    import json

    response = http.post(
        "/v1/jobs",
        files={"left": ("l.png", pair[0]), "right": ("r.png", pair[1])},
        data={"params": json.dumps(params)},
        headers=bearer(key),
    )
    if expect is not None:
        assert response.status_code == expect, response.text
    return response


def wait(http, key, job_id, timeout=90.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        status = http.get(f"/v1/jobs/{job_id}", headers=bearer(key)).json()
        if status["state"] in harness.TERMINAL:
            return status
        time.sleep(0.05)
    raise AssertionError(f"job {job_id} did not finish: {status}")


def test_every_v1_route_needs_a_key_but_health_and_docs_do_not(http, users):
    for method, path in [
        ("GET", "/v1/jobs"),
        ("POST", "/v1/jobs"),
        ("POST", "/v1/estimate"),
        ("GET", "/v1/jobs/0123456789abcdef0123456789abcdef"),
        ("DELETE", "/v1/jobs/0123456789abcdef0123456789abcdef"),
        ("GET", "/v1/solvers"),
        ("GET", "/v1/usage"),
    ]:
        response = http.request(method, path)
        assert response.status_code == 401, (method, path, response.text)
        assert response.headers["WWW-Authenticate"].startswith("Bearer")
        wrong = http.request(method, path, headers=bearer("qhsm_00000000_" + "x" * 43))
        assert wrong.status_code == 401
    for path in ("/healthz", "/readyz", "/docs", "/openapi.json"):
        assert http.get(path).status_code == 200, path


def test_another_users_job_is_404_and_admins_see_every_job(http, users, pair):
    _, ada = users.create_user("ada-own")
    _, bob = users.create_user("bob-own")
    _, root = users.create_user("root-own", admin=True)
    params = {"solver": "exact", "max_disparity": 6, "median": False, "bilateral": False}
    job_id = submit(http, ada, pair, params).json()["id"]
    assert wait(http, ada, job_id)["state"] == "succeeded"

    for method, path in [
        ("GET", f"/v1/jobs/{job_id}"),
        ("GET", f"/v1/jobs/{job_id}/disparity"),
        ("GET", f"/v1/jobs/{job_id}/preview.png"),
        ("DELETE", f"/v1/jobs/{job_id}"),
    ]:
        assert http.request(method, path, headers=bearer(bob)).status_code == 404, path
    assert job_id not in [
        j["id"] for j in http.get("/v1/jobs", headers=bearer(bob)).json()["items"]
    ]
    assert job_id in [j["id"] for j in http.get("/v1/jobs", headers=bearer(ada)).json()["items"]]
    everyone = http.get("/v1/jobs", params={"limit": 100}, headers=bearer(root)).json()
    assert job_id in [j["id"] for j in everyone["items"]]
    seen = http.get(f"/v1/jobs/{job_id}", headers=bearer(root))
    assert seen.status_code == 200 and seen.json()["owner"] == "ada-own"
    users.revoke("ada-own")
    assert http.get(f"/v1/jobs/{job_id}", headers=bearer(ada)).status_code == 401


def test_a_job_over_budget_fails_at_pricing_with_the_numbers(http, users, pair):
    """Priced on the pricing worker (issue 29): accepted in state pricing, then failed with
    the refusal a submit used to answer 403 with, before anything is queued or charged."""
    _, key = users.create_user("poor", qpu_seconds=0)
    seconds = service_estimate(http, key, pair, QPU_PARAMS)["seconds"]
    users.ledger.set_limit("poor", seconds / 2)
    accepted = submit(http, key, pair, QPU_PARAMS)
    assert accepted.json()["state"] == "pricing"
    status = wait(http, key, accepted.json()["id"])
    assert status["state"] == "failed" and status["levels"] == []
    detail = status["error"]
    assert detail.startswith("refused: not enough QPU budget left for user 'poor'"), detail
    assert f"{seconds / 2:.3f} s remaining" in detail and f"{seconds:.3f} s" in detail
    assert http.get("/v1/usage", headers=bearer(key)).json()["users"][0]["used_seconds"] == 0
    # unmetered solvers need no budget
    submit(http, key, pair, {"solver": "exact", "max_disparity": 6})


def test_usage_charged_equals_the_sample_sets_qpu_access_time(http, users, pair):
    _, key = users.create_user("meter", qpu_seconds=100)
    accepted = submit(http, key, pair, QPU_PARAMS).json()
    assert accepted["state"] == "pricing"  # then queued, running, succeeded
    job_id = accepted["id"]
    status = wait(http, key, job_id)
    assert status["state"] == "succeeded", status["error"]
    levels = [level["seconds"] for level in service_estimate(http, key, pair, QPU_PARAMS)["levels"]]
    assert len(levels) == len(status["levels"])  # priced at the same levels it ran
    reported = status["usage"]["qpu_access_time"]  # summed from the bundles' sample sets
    assert reported > 0
    usage = http.get("/v1/usage", headers=bearer(key)).json()
    [mine] = usage["users"]
    [job] = mine["jobs"]
    assert job["id"] == job_id
    assert job["qpu_seconds"] == pytest.approx(reported, rel=1e-9)
    # roof duality solves some bundles on the host; the others share QPU calls
    assert 1 <= job["problems"] <= job_estimate().bundles
    assert mine["used_seconds"] == pytest.approx(reported) and mine["reserved_seconds"] == 0
    assert mine["remaining_seconds"] == pytest.approx(100 - reported)


def service_estimate(http, key, pair, params) -> dict:
    """POST /v1/estimate, polled until its worker is done: the number the pricing of a job
    checks against the budget (known embeddings included)."""
    import json

    response = http.post(
        "/v1/estimate",
        files={"left": ("l.png", pair[0]), "right": ("r.png", pair[1])},
        data={"params": json.dumps(params)},
        headers=bearer(key),
    )
    assert response.status_code == 202, response.text
    status = response.json()
    deadline = time.monotonic() + 60
    while status["state"] in ("pending", "running") and time.monotonic() < deadline:
        time.sleep(0.05)
        status = http.get(response.headers["Location"], headers=bearer(key)).json()
    assert status["state"] == "done", status
    return status["result"]


def test_estimate_and_charge_agree_and_later_estimates_use_the_embedding(http, users):
    """qpu-sim is charged the model for its actual embedding; the estimate before any
    embedding assumes 2 qubits per variable, after one it uses the embedding's qubits."""
    scene = make_scene(12, 30, max_disparity=6, seed=2)  # a shape no other test embeds
    pair = harness.png(scene.left), harness.png(scene.right)
    _, key = users.create_user("estimator", qpu_seconds=100)
    before = service_estimate(http, key, pair, QPU_PARAMS)
    assert before["metered"] and before["fits"] and before["remaining_seconds"] == 100
    assert not any(level["embedding_known"] for level in before["levels"])
    assert http.get("/v1/jobs", headers=bearer(key)).json()["items"] == []  # nothing queued
    job_id = submit(http, key, pair, QPU_PARAMS).json()["id"]
    status = wait(http, key, job_id)
    assert status["state"] == "succeeded", status["error"]
    charged = http.get("/v1/usage", headers=bearer(key)).json()["users"][0]["used_seconds"]
    # before: one bundle per call assumed (the run packed them): an upper bound
    assert charged <= before["seconds"]
    after = service_estimate(http, key, pair, QPU_PARAMS)
    assert all(level["embedding_known"] for level in after["levels"])
    assert after["seconds"] == pytest.approx(charged, rel=0.1)
    assert after["remaining_seconds"] == pytest.approx(100 - charged)


def test_hybrid_sim_is_charged_what_leap_would_bill(http, users, pair):
    params = dict(QPU_PARAMS, solver="hybrid-sim", solver_params={"max_iter": 1})
    _, key = users.create_user("hybrid-user", qpu_seconds=1000)
    expected = service_estimate(http, key, pair, params)
    assert expected["metered"] and expected["seconds"] > 0
    job_id = submit(http, key, pair, params).json()["id"]
    status = wait(http, key, job_id, timeout=180)
    assert status["state"] == "succeeded", status["error"]
    [mine] = http.get("/v1/usage", headers=bearer(key)).json()["users"]
    assert mine["used_seconds"] == pytest.approx(expected["seconds"], rel=0.1)
    assert mine["jobs"][0]["problems"] == len(expected["levels"])  # one BQM a level


def test_twenty_concurrent_jobs_cannot_overspend_beyond_the_bundles_in_flight(
    http, users, pair, settings
):
    _, key = users.create_user("greedy", qpu_seconds=0)
    # the API's own estimate: by now it knows this shape's embeddings from the tests above
    estimate = service_estimate(http, key, pair, QPU_PARAMS)
    budget = 1.5 * estimate["seconds"]
    users.ledger.set_limit("greedy", budget)
    responses = [submit(http, key, pair, QPU_PARAMS) for _ in range(20)]
    # once the first jobs have spent the budget down, a late one is refused at its pricing
    # (failed before it is queued); every refusal says so, and enough jobs ran concurrently
    ids = [r.json()["id"] for r in responses]
    finals = [wait(http, key, job_id, timeout=120) for job_id in ids]
    # a failed job's bundles already sent still finish (and are charged): wait for them
    slots = redis.Redis.from_url(settings.redis_url)
    deadline = time.monotonic() + 30
    while True:
        usage = http.get("/v1/usage", headers=bearer(key)).json()["users"][0]
        idle = slots.zcard(f"{settings.key_prefix}:qpu:slots") == 0
        if (idle and usage["reserved_seconds"] == 0) or time.monotonic() > deadline:
            break
        time.sleep(0.1)

    # every bundle was reserved at its estimate before it was sent; only bundles in flight
    # when the budget ran out can exceed it, each by at most (actual - estimate)
    per_bundle = [level["seconds"] / level["bundles"] for level in estimate["levels"]]
    actuals = [
        f["usage"]["qpu_access_time"] / max(1, sum(level["bundles"] for level in f["levels"]))
        for f in finals
        if f["state"] == "succeeded"
    ]
    excess = max([0.0, *(a - min(per_bundle) for a in actuals)])
    assert usage["used_seconds"] <= budget + QPU_SLOTS * excess + 1e-9
    assert usage["used_seconds"] > budget / 2  # the budget really was spent down
    assert usage["reserved_seconds"] == 0

    states = [f["state"] for f in finals]
    assert "failed" in states
    admitted = [f for f in finals if not (f["error"] or "").startswith("refused:")]
    assert len(admitted) >= 2  # enough jobs passed their pricing and ran concurrently
    for final in finals:
        if final["state"] == "failed":
            assert final["error"].startswith(
                ("stopped: not enough QPU budget left for user 'greedy'",
                 "refused: not enough QPU budget left for user 'greedy'")
            ), final["error"]  # fmt: skip
    problems = sum(job["problems"] for job in usage["jobs"])
    assert (
        problems < len(ids) * estimate["bundles"]
    )  # the failed jobs' remaining bundles were not sent
    assert slots.zcard(f"{settings.key_prefix}:qpu:slots") == 0  # no slot leaked


def test_the_token_never_leaves_the_qpu_worker(
    http, users, pair, bodies, api_log, settings, qpu_worker
):
    _, key = users.create_user("leaky", qpu_seconds=100)
    failing = dict(QPU_PARAMS, solver_params={"num_reads": 5, "no_such_parameter": 1})
    job_id = submit(http, key, pair, failing).json()["id"]
    status = wait(http, key, job_id)
    assert status["state"] == "failed"
    http.get("/v1/usage", headers=bearer(key))
    http.get("/v1/solvers", headers=bearer(key))

    assert bodies and not any(SENTINEL in body for body in bodies)
    assert not any(SENTINEL in line for line in api_log.lines)
    logs = Path(qpu_worker.log_file).parent
    for log_file in logs.glob("*.log"):
        assert SENTINEL not in log_file.read_text(errors="replace"), log_file
    client = redis.Redis.from_url(settings.redis_url)
    for key_name in client.scan_iter(count=1000):
        assert SENTINEL.encode() not in key_name
        kind = client.type(key_name).decode()
        values = {
            "string": lambda k: [client.get(k) or b""],
            "hash": lambda k: [b"%s=%s" % kv for kv in client.hgetall(k).items()],
            "set": lambda k: list(client.smembers(k)),
            "zset": lambda k: [m for m, _ in client.zrange(k, 0, -1, withscores=True)],
            "list": lambda k: client.lrange(k, 0, -1),
        }.get(kind, lambda k: [])(key_name)
        assert not any(SENTINEL.encode() in value for value in values), key_name
