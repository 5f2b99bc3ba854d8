"""A monthly budget at admission and in /v1/usage (issue 31), with the API's ledger clock
frozen: November's spending does not count in December; the refusal names the period."""

from __future__ import annotations

import uuid
from datetime import UTC, datetime

import pytest
from api_helpers import LEFT, RIGHT

from api.users import UserStore
from workers.quota import QuotaExceededError


def price_job(api_settings, ledger, job_id: str):
    """What the pricing worker's ``qhsm.price_job`` does, here, with this ledger."""
    from workers import pricing
    from workers.app import make_celery
    from workers.store import JobStore

    store = JobStore.from_settings(api_settings)
    celery = make_celery(api_settings, with_tasks=False)
    return pricing.price_job(celery, store, ledger, job_id, None)


def test_admission_counts_the_current_month_and_says_when_it_resets(api, api_settings):
    ledger = api.app.state.users.ledger
    moment = {"now": datetime(2026, 11, 20, tzinfo=UTC)}
    ledger.clock = lambda: moment["now"]
    try:
        name = f"monthly-{uuid.uuid4().hex[:6]}"
        _, key = UserStore.from_settings(api_settings).create_user(name, qpu_seconds=1.0)
        headers = {"Authorization": f"Bearer {key}"}
        quota = api.put(f"/v1/users/{name}/quota", json={"qpu_seconds": 1.0, "period": "monthly"})
        assert quota.status_code == 200 and quota.json()["own_period"] == "monthly"
        ledger.settle(ledger.reserve(name, "old-job", 0.999, ttl=60), 0.999)
        form = {"params": '{"solver": "qpu-sim", "max_disparity": 6}'}
        files = {"left": ("l.png", LEFT), "right": ("r.png", RIGHT)}
        # priced on a worker (issue 29): accepted `pricing`, refused by its pricing task
        pricing_job = api.post("/v1/jobs", files=files, data=form, headers=headers)
        assert pricing_job.status_code == 202 and pricing_job.json()["state"] == "pricing"
        with pytest.raises(QuotaExceededError) as refused:
            price_job(api_settings, ledger, pricing_job.json()["id"])
        detail = str(refused.value)
        assert "remaining this month" in detail
        assert "monthly budget, resets at 2026-12-01T00:00:00+00:00" in detail
        api.delete(f"/v1/jobs/{pricing_job.json()['id']}")

        moment["now"] = datetime(2026, 12, 2, tzinfo=UTC)
        [usage] = api.get("/v1/usage", params={"user": name}).json()["users"]
        assert usage["used_seconds"] == 0 and usage["total_used_seconds"] == 0.999
        assert usage["period"] == "monthly" and usage["resets_at"].startswith("2027-01-01")
        accepted = api.post("/v1/jobs", files=files, data=form, headers=headers)
        assert accepted.status_code == 202, accepted.text
        api.delete(f"/v1/jobs/{accepted.json()['id']}")
    finally:
        ledger.clock = None


def test_qhsm_usage_prints_the_period_and_its_reset(live_api, api, api_settings, capsys):
    import json

    from shared.cli import main

    name = f"weekly-{uuid.uuid4().hex[:6]}"
    _, key = UserStore.from_settings(api_settings).create_user(name, qpu_seconds=2.0)
    api.put(f"/v1/users/{name}/quota", json={"qpu_seconds": 2.0, "period": "weekly"})
    assert main(["usage", "--url", live_api.url, "--key", key]) == 0
    line = capsys.readouterr().out
    assert f"{name}: used 0.000 s of 2 s" in line and "2.000 s left; weekly since" in line
    assert main(["usage", "--url", live_api.url, "--key", key, "--json"]) == 0
    [entry] = json.loads(capsys.readouterr().out)["users"]
    assert entry["period"] == "weekly" and entry["resets_at"]
