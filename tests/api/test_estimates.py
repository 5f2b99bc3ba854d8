"""Pricing off the API (issue 29): ``POST /v1/estimate`` answers at once (202) and is polled,
a metered job waits in ``pricing``; no worker runs here, so what a pricing worker does is done
in this process by calling :mod:`workers.pricing` as its task does (the real workers:
tests/service/test_users.py)."""

from __future__ import annotations

import json
import time
import uuid

import pytest
import redis
from api_helpers import LEFT, RIGHT, post

from api.users import UserStore
from shared.config import MatchConfig
from shared.solvers.meters import qpu_time
from shared.solvers.registry import resolve
from workers import pricing
from workers.app import make_celery
from workers.estimates import EstimateStore, sweep_abandoned
from workers.quota import QuotaExceededError, QuotaLedger
from workers.store import JobStore

METERED = {"solver": "qpu-sim", "max_disparity": 6}


def ask(client, params=None, headers=None, left=LEFT):
    files = {"left": ("left.png", left), "right": ("right.png", RIGHT)}
    data = {} if params is None else {"params": json.dumps(params)}
    return client.post("/v1/estimate", files=files, data=data, headers=headers or {})


def member(api_settings, name=None) -> dict[str, str]:
    _, key = UserStore.from_settings(api_settings).create_user(
        name or f"member-{uuid.uuid4().hex[:8]}", qpu_seconds=100
    )
    return {"Authorization": f"Bearer {key}"}


def compute(api_settings, estimate_id: str):
    """What the pricing worker's ``qhsm.price_estimate`` does, here."""
    store = JobStore.from_settings(api_settings)
    return pricing.price_estimate(EstimateStore(store.redis, api_settings), store, estimate_id)


@pytest.fixture
def no_matcher(monkeypatch):
    """The matcher raises in this (the API's) process."""

    def refuse(*args, **kwargs):
        raise AssertionError("the API process ran the matcher")

    for module, name in (
        ("shared.residual", "job_residual"),
        ("shared.residual", "survey"),
        ("shared.pipeline", "match_views"),
        ("shared.pipeline", "run_pipeline"),
        ("shared.solvers.meters.qpu_time", "job_seconds"),
        ("workers.pricing", "price"),
    ):
        monkeypatch.setattr(f"{module}.{name}", refuse)


def test_an_estimate_is_accepted_at_once_and_left_to_a_worker(api, no_matcher):
    before = api.get("/v1/jobs", params={"limit": 100}).json()["total"]
    response = ask(api, METERED)
    assert response.status_code == 202, response.text
    body = response.json()
    assert body["state"] == "pending" and body["result"] is None
    assert response.headers["Location"] == body["links"]["self"] == f"/v1/estimates/{body['id']}"
    polled = api.get(response.headers["Location"]).json()
    assert polled["state"] == "pending" and polled["id"] == body["id"]
    assert api.get("/v1/jobs", params={"limit": 100}).json()["total"] == before  # not a job
    assert api.delete(response.headers["Location"]).json()["state"] == "cancelled"


def test_a_polled_estimate_gives_the_workers_result_then_a_repeat_is_cached(api, api_settings):
    params = {**METERED, "encoding": "domain-wall", "solver_params": {"num_reads": 50}}
    created = ask(api, params).json()
    finished = compute(api_settings, created["id"])
    assert finished is not None and finished.state == "done"
    body = api.get(created["links"]["self"]).json()
    assert body["state"] == "done" and not body["cached"] and body["error"] is None
    result = body["result"]
    expected = qpu_time.job_seconds(resolve(MatchConfig.model_validate(params)), (24, 32), 6)
    assert result["max_disparity"] == 6 and result["bundles"] == expected.bundles
    # roof duality surveyed on the pair: what it solves on the host is not charged
    assert 0 < result["seconds"] <= expected.seconds * (1 + 1e-9)
    assert result["fits"] is True and result["memory_mb"] > 0  # the local admin: unlimited
    again = ask(api, params)
    assert again.status_code == 202
    repeat = again.json()
    assert repeat["state"] == "done" and repeat["cached"] and repeat["id"] != created["id"]
    assert repeat["result"] == result
    other = ask(api, {**params, "solver_params": {"num_reads": 60}}).json()
    assert other["state"] == "pending"  # another config: not the cached one
    api.delete(other["links"]["self"])


def test_the_result_is_read_against_the_owners_budget_when_polled(api, api_settings):
    users = UserStore.from_settings(api_settings)
    name = f"poor-{uuid.uuid4().hex[:6]}"
    _, key = users.create_user(name, qpu_seconds=0.01)
    headers = {"Authorization": f"Bearer {key}"}
    created = ask(api, {"solver": "qpu-sim"}, headers).json()
    compute(api_settings, created["id"])
    result = api.get(created["links"]["self"], headers=headers).json()["result"]
    assert result["fits"] is False and result["remaining_seconds"] == 0.01
    assert result["seconds"] > 0.01 and result["max_disparity"] > 0  # the range was resolved


def test_an_unmetered_estimate_is_zero(api, api_settings):
    created = ask(api, {"solver": "exact", "max_disparity": 6}).json()
    compute(api_settings, created["id"])
    result = api.get(created["links"]["self"]).json()["result"]
    assert result["metered"] is False and result["seconds"] == 0 and result["fits"] is True
    assert result["remaining_seconds"] is None


def test_bad_requests_are_refused_before_anything_is_queued(api):
    assert ask(api, {"solver": "quantum-magic"}).status_code == 422
    assert ask(api, left=b"GIF89a no").status_code == 415
    assert api.post("/v1/estimate", data={"params": "{"}).status_code == 422  # no images
    # parameters the estimate cannot use fail the estimate (on its worker), with the reason
    config = MatchConfig.model_validate(
        {"solver": "qpu", "max_disparity": 6, "solver_params": {"num_reads": "many"}}
    )
    from shared.synthetic import make_scene

    scene = make_scene(24, 32, max_disparity=6, seed=1)
    with pytest.raises(pricing.PricingError, match="cannot estimate"):
        pricing.price(config, scene.left, scene.right, pricing.EmbeddingCache())


def test_unknown_and_other_users_estimates_are_404(api, api_settings):
    mine = member(api_settings)
    created = ask(api, METERED, mine).json()
    other = member(api_settings)
    for path in (created["links"]["self"], f"/v1/estimates/{uuid.uuid4().hex}", "/v1/estimates/x"):
        for method in ("GET", "DELETE"):
            response = api.request(method, path, headers=other)
            assert response.status_code == 404, (method, path, response.text)
            assert "POST /v1/estimate" in response.json()["detail"]
    assert api.get(created["links"]["self"], headers=mine).json()["state"] == "pending"
    assert api.get(created["links"]["self"]).status_code == 200  # an admin sees it
    api.delete(created["links"]["self"], headers=mine)


def test_a_cancelled_estimate_is_never_computed(api, api_settings, no_matcher):
    created = ask(api, METERED).json()
    cancelled = api.delete(created["links"]["self"])
    assert cancelled.status_code == 200
    assert cancelled.json()["state"] == "cancelled" and "DELETE" in cancelled.json()["error"]
    assert compute(api_settings, created["id"]) is None  # its worker finds nobody waiting
    assert api.get(created["links"]["self"]).json()["state"] == "cancelled"
    assert api.delete(created["links"]["self"]).json()["state"] == "cancelled"  # idempotent


def test_an_estimate_nobody_polls_is_revoked(make_client, api_settings):
    # 1 s: "just asked" must hold between the POST and the first sweep on a loaded machine
    quick = api_settings.model_copy(update={"estimate_abandon_seconds": 1.0})
    client = make_client(estimate_abandon_seconds=1.0)
    created = ask(client, METERED).json()
    store = EstimateStore(redis.Redis.from_url(quick.redis_url), quick)
    celery = make_celery(quick, with_tasks=False)
    assert created["id"] not in sweep_abandoned(celery, store)  # just asked
    time.sleep(1.1)
    assert created["id"] in sweep_abandoned(celery, store)
    body = client.get(created["links"]["self"]).json()
    assert body["state"] == "cancelled" and "abandoned" in body["error"]
    assert "QHSM_ESTIMATE_ABANDON_SECONDS" in body["error"]
    assert store.load_views(created["id"]) is None  # its views are gone with it


def test_a_users_open_estimates_are_bounded_429(make_client, api_settings):
    client = make_client(max_estimates_per_user=1)
    headers = member(api_settings)
    first = ask(client, METERED, headers)
    assert first.status_code == 202
    busy = ask(client, {**METERED, "max_disparity": 5}, headers)
    assert busy.status_code == 429, busy.text
    assert "QHSM_MAX_ESTIMATES_PER_USER" in busy.json()["detail"]
    client.delete(first.json()["links"]["self"], headers=headers)
    assert ask(client, {**METERED, "max_disparity": 5}, headers).status_code == 202


def price_job(api_settings, job_id: str):
    """What the pricing worker's ``qhsm.price_job`` does, here."""
    store = JobStore.from_settings(api_settings)
    ledger = QuotaLedger(store.redis, api_settings.key_prefix)
    celery = make_celery(api_settings, with_tasks=False)
    return pricing.price_job(celery, store, ledger, job_id, None)


def test_a_metered_job_waits_in_pricing_then_is_queued_with_its_estimate(api, api_settings):
    """The range, the estimate and the budget check are the pricing worker's; the job is
    accepted at once (no range resolved in the request)."""
    created = post(api, params={"solver": "qpu-sim", "max_disparity": "auto"})
    assert created.status_code == 202 and created.json()["state"] == "pricing"
    job = created.json()["id"]
    status = api.get(f"/v1/jobs/{job}").json()
    assert status["state"] == "pricing" and status["disparity_range"] is None
    assert status["progress"]["stage"] is None  # no worker has taken it yet
    queued = price_job(api_settings, job)
    assert queued is not None and queued.state == "queued" and queued.dispatched
    status = api.get(f"/v1/jobs/{job}").json()
    assert status["state"] == "queued" and status["progress"]["stage"] is None
    assert status["disparity_range"]["source"] in ("auto", "auto-fallback")
    assert status["progress"]["levels"] >= 1 and status["memory_mb"] > 0
    created = ask(
        api, {"solver": "qpu-sim", "max_disparity": status["disparity_range"]["max_disparity"]}
    ).json()
    compute(api_settings, created["id"])
    levels = api.get(created["links"]["self"]).json()["result"]["levels"]
    assert queued.estimate_seconds == [level["seconds"] for level in levels]
    assert price_job(api_settings, job) is None  # priced once
    assert api.delete(f"/v1/jobs/{job}").status_code == 200


def test_a_metered_job_over_budget_fails_at_pricing_and_a_cancelled_one_is_not_priced(
    api, api_settings
):
    users = UserStore.from_settings(api_settings)
    name = f"broke-{uuid.uuid4().hex[:6]}"
    _, key = users.create_user(name, qpu_seconds=0.001)
    headers = {"Authorization": f"Bearer {key}"}
    files = {"left": ("l.png", LEFT), "right": ("r.png", RIGHT)}
    job = api.post("/v1/jobs", files=files, data={"params": json.dumps(METERED)}, headers=headers)
    assert job.status_code == 202 and job.json()["state"] == "pricing"
    with pytest.raises(QuotaExceededError, match="not enough QPU budget left"):
        price_job(api_settings, job.json()["id"])  # the task fails the job with this message
    cancelled = post(api, params=METERED).json()["id"]
    assert api.delete(f"/v1/jobs/{cancelled}").json()["state"] == "cancelled"
    assert price_job(api_settings, cancelled) is None
    assert api.get(f"/v1/jobs/{cancelled}").json()["state"] == "cancelled"


def test_a_pricing_job_whose_pricing_task_was_lost_is_priced_again(api, api_settings):
    """Redis lost the pricing task's message (no queue holds it, no worker has it): the
    watchdog sends it again, once, to the pricing queue under the id a cancel revokes."""
    from workers.app import pricing_task_id
    from workers.watchdog import Watchdog

    job = post(api, params=METERED).json()["id"]
    store = JobStore.from_settings(api_settings)
    watchdog = Watchdog(make_celery(api_settings, with_tasks=False), store, "test")
    assert job.encode() in watchdog.messages()  # sent at submit
    for key in watchdog.queue_keys(api_settings.pricing_queue):
        store.redis.delete(key)  # lost with a Redis restart
    assert job.encode() not in watchdog.messages()
    clock = iter(range(0, 10_000, int(api_settings.watchdog_lost_seconds) + 1))
    watchdog.clock = lambda: next(clock)
    actions = [action for _ in range(3) for found, action in watchdog.tick() if found == job]
    assert actions == ["priced again"]
    queued = store.redis.lrange(store.key(api_settings.pricing_queue), 0, -1)
    [message] = [message for message in queued if job.encode() in message]
    assert pricing_task_id(job).encode() in message
    assert price_job(api_settings, job).state == "queued"  # the resent task prices it
    assert api.delete(f"/v1/jobs/{job}").status_code == 200


def test_pricing_reports_the_share_of_levels_priced_while_it_runs(api, api_settings, monkeypatch):
    """Issue 29: an estimate's poll and a pricing job's progress give the levels surveyed /
    the levels as the pricing worker goes (not a stage name only); nothing once it ended."""
    params = {"solver": "qpu-sim", "max_disparity": 16}  # three levels
    seen: list[tuple[str | None, float | None]] = []
    read = {"now": lambda: (None, None)}
    real = pricing.job_residual

    def watched(config, left, right, top, cache, progress):
        def told(done: int, total: int) -> None:
            progress(done, total)  # what the worker writes, then what a poll reads
            seen.append(read["now"]())

        return real(config, left, right, top, cache, told)

    monkeypatch.setattr(pricing, "job_residual", watched)
    created = ask(api, params).json()

    def estimate_now():
        body = api.get(created["links"]["self"]).json()
        assert body["state"] == "running"
        return body["stage"], body["fraction"]

    read["now"] = estimate_now
    compute(api_settings, created["id"])
    assert seen == [(pricing.SURVEY, 1 / 3), (pricing.SURVEY, 2 / 3), (pricing.SURVEY, 1.0)]
    done = api.get(created["links"]["self"]).json()
    assert done["state"] == "done" and done["stage"] is None and done["fraction"] is None

    job = post(api, params=params).json()["id"]
    assert api.get(f"/v1/jobs/{job}").json()["progress"]["fraction"] is None  # not taken yet

    def job_now():
        progress = api.get(f"/v1/jobs/{job}").json()["progress"]
        return progress["stage"], progress["fraction"]

    read["now"], seen[:] = job_now, []
    assert price_job(api_settings, job) is not None
    assert seen == [(pricing.SURVEY, 1 / 3), (pricing.SURVEY, 2 / 3), (pricing.SURVEY, 1.0)]
    assert job_now() == (None, None)  # queued
    api.delete(f"/v1/jobs/{job}")


def test_the_estimates_text_names_qubits_only_for_levels_that_send_bundles():
    """``qhsm estimate``'s lines: a level whose every bundle the host solved embeds nothing,
    so its line names no qubits; a level that sends bundles names them and their source."""
    from api.cli import format_estimate

    def level(index: int, sent: int) -> dict:
        return {
            "index": index, "height": 4, "width": 8, "bundles": 10, "variables_per_bundle": 6,
            "bundles_sent": sent, "variables_share": 0.5, "qubits_per_bundle": 12,
            "embedding_known": False, "seconds": 0.01 * sent,
        }  # fmt: skip

    result = {
        "solver": "qpu", "metered": True, "seconds": 0.02, "bundles": 20, "bundles_sent": 2,
        "max_disparity": 8,
        "levels": [level(0, 0), level(1, 2)],
    }  # fmt: skip
    first, second = format_estimate(result).splitlines()[1:3]
    assert "qubits" not in first and "0 sent" in first
    assert "12 qubits (assumed)" in second and "2 sent" in second
