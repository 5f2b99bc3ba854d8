"""Estimates computed by a real pricing worker (issue 29): the API process answers at once and
never runs the matcher, the client polls transparently, a repeat comes from the cache and a
failed estimate says why. Metered jobs' pricing through workers: tests/service/test_users.py."""

from __future__ import annotations

import json

import harness
import pytest

from shared.synthetic import make_scene

pytestmark = pytest.mark.service

SCENE = make_scene(20, 28, max_disparity=6, seed=5)
FILES = {"left": ("l.png", harness.png(SCENE.left)), "right": ("r.png", harness.png(SCENE.right))}


@pytest.fixture
def no_matcher_here(monkeypatch):
    """The matcher raises in this process, the API's: only a worker can compute."""

    def refuse(*args, **kwargs):
        raise AssertionError("the API process ran the matcher")

    for target in (
        "shared.residual.job_residual",
        "shared.pipeline.match_views",
        "shared.pipeline.run_pipeline",
        "shared.solvers.meters.qpu_time.job_seconds",
        "workers.pricing.price",
    ):
        monkeypatch.setattr(target, refuse)


def test_a_worker_computes_the_estimate_and_a_repeat_is_cached(client, no_matcher_here):
    # every row bundle sent (no certified tiles): QPU time to meter, whatever the host settles
    job = {"solver": "qpu-sim", "max_disparity": "auto", "seed": 5, "certify_tiles": False}
    params = {"params": json.dumps(job)}
    asked = client.post("/v1/estimate", files=FILES, data=params)
    assert asked.status_code == 202, asked.text
    assert asked.json()["state"] in ("pending", "running", "done")
    status = harness.wait_for(client, asked.json()["id"], path="/v1/estimates/{}")
    assert status["state"] == "done", status
    result = status["result"]
    assert result["metered"] and result["seconds"] > 0 and result["max_disparity"] > 0
    repeat = client.post("/v1/estimate", files=FILES, data=params)
    assert repeat.json()["state"] == "done" and repeat.json()["cached"]
    assert repeat.json()["result"] == result


def test_an_estimate_the_worker_cannot_compute_fails_with_the_reason(client):
    bad = {"solver": "qpu", "max_disparity": 6, "solver_params": {"num_reads": "many"}}
    asked = client.post("/v1/estimate", files=FILES, data={"params": json.dumps(bad)})
    assert asked.status_code == 202, asked.text
    status = harness.wait_for(client, asked.json()["id"], path="/v1/estimates/{}")
    assert status["state"] == "failed" and "cannot estimate" in status["error"]
    assert status["result"] is None


def test_the_client_polls_transparently(settings, workers, admin_key, no_matcher_here):
    """``Client.estimate`` (``qhsm estimate``'s) returns the result as before the worker."""
    from api.client import Client, ClientError

    with harness.api_client(settings, admin_key) as test_client:
        client = Client("http://testserver", key=admin_key)
        client.http = test_client  # the in-process app (a TestClient is an httpx client)
        result = client.estimate(
            FILES["left"][1], FILES["right"][1], {"solver": "exact", "max_disparity": 6}
        )
        assert result["metered"] is False and result["seconds"] == 0 and result["memory_mb"]
        with pytest.raises(ClientError, match="failed: params: cannot estimate"):
            client.estimate(
                FILES["left"][1],
                FILES["right"][1],
                {"solver": "qpu", "max_disparity": 6, "solver_params": {"num_reads": "lots"}},
            )
