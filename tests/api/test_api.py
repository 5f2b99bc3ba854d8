"""HTTP behaviour that needs no worker: validation (4xx, never 5xx), job lifecycle while
queued, listing, solvers, health."""

from __future__ import annotations

import harness
import numpy as np
import pytest
import redis
from api_helpers import LEFT, SCENE, post
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st


def test_unsupported_format_is_415(api):
    response = post(api, left=b"GIF89a not really an image")
    assert response.status_code == 415
    assert "left: not a readable image" in response.json()["detail"]


def test_views_of_different_sizes_are_422(api):
    response = post(api, right=harness.png(SCENE.right[:, :20]))
    assert response.status_code == 422
    assert "left is 32x24 but right is 20x24" in response.json()["detail"]


def test_images_above_the_pixel_limit_are_413(make_client):
    response = post(make_client(max_image_pixels=500))
    assert response.status_code == 413
    assert "768 pixels is above the limit of 500" in response.json()["detail"]


def test_files_above_the_byte_limit_are_413(make_client):
    response = post(make_client(max_upload_bytes=100))
    assert response.status_code == 413 and "QHSM_MAX_UPLOAD_BYTES" in response.json()["detail"]


def test_unknown_solver_is_422_and_lists_the_known_ones(api):
    response = post(api, params={"solver": "quantum-magic"})
    assert response.status_code == 422
    detail = response.json()["detail"]
    assert "unknown solver 'quantum-magic'" in detail and "exact" in detail


def test_a_dimod_sampler_by_name_is_accepted_and_a_bad_name_is_422(api):
    good = {"solver": "dimod:dwave.samplers.SteepestDescentSolver", "encoding": "domain-wall"}
    assert post(api, params=good).status_code == 202
    response = post(api, params={"solver": "dimod:dimod.Structured"})
    assert response.status_code == 422
    detail = response.json()["detail"]
    assert "is not among the dimod samplers this service allows" in detail
    assert "dimod:PACKAGE.MODULE.CLASS" in detail and "QHSM_DIMOD_SAMPLERS" in detail


@pytest.mark.parametrize("name", ["dimod:this.X", "dimod:lib2to3.__main__.X", "dimod:os.X"])
def test_a_dimod_name_off_the_allowlist_is_422_and_never_imported(api, name, capfd):
    """A solver name used to be imported by the API: `this` printed the Zen of Python, 2to3
    ran and raised SystemExit (a plain-text 500)."""
    import sys

    module = name.removeprefix("dimod:").split(".")[0]
    already = module in sys.modules
    response = post(api, params={"solver": name})
    assert response.status_code == 422, response.text
    assert "not among the dimod samplers this service allows" in response.json()["detail"]
    assert already or module not in sys.modules
    assert "Beautiful is better than ugly" not in capfd.readouterr().out


def test_a_dimod_samplers_parameters_are_bounded_at_submit(api):
    params = {
        "solver": "dimod:dwave.samplers.SimulatedAnnealingSampler",
        "solver_params": {"num_reads": 10, "num_sweeps": 100_000_000},
    }
    response = post(api, params=params)
    assert response.status_code == 422, response.text
    assert "num_sweeps (int, 1..100000)" in response.json()["detail"]


def test_solver_without_worker_or_local_availability_is_422(api):
    response = post(api, params={"solver": "fake-unavailable"})
    assert response.status_code == 422
    detail = response.json()["detail"]
    assert "needs hardware this machine lacks" in detail
    assert "celery -A workers worker -Q fake-unavailable" in detail


def test_bad_params_are_4xx_with_the_field_named(api):
    assert post(api, params="{not json").status_code == 400
    assert post(api, params="[1, 2]").status_code == 422
    response = post(api, params={"max_disparity": 0, "median_size": 4, "colour": "red"})
    assert response.status_code == 422
    detail = response.json()["detail"]
    assert "max_disparity" in detail and "median_size must be odd" in detail and "colour" in detail


def test_missing_view_and_bad_ground_truth_are_4xx(api):
    assert api.post("/v1/jobs", files={"left": ("l.png", LEFT)}).status_code == 422
    wrong = harness.npy(np.ones((5, 5), np.float32))
    response = post(api, ground_truth=wrong, gt_scale=1)
    assert response.status_code == 422 and "ground_truth is 5x5" in response.json()["detail"]
    assert post(api, ground_truth=b"nonsense").status_code == 415
    good = harness.npy(SCENE.disparity)
    assert post(api, ground_truth=good, gt_scale=0).status_code == 422


@settings(
    max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(left=st.binary(max_size=256), params=st.text(max_size=40))
def test_arbitrary_uploads_never_cause_a_server_error(api, left, params):
    response = post(api, left=left, params=params)
    assert 400 <= response.status_code < 500, response.text


def test_queued_job_lifecycle_and_listing(api):
    ids = []
    for _ in range(3):
        response = post(api, params={"max_disparity": 6})
        assert response.status_code == 202
        assert response.headers["location"] == f"/v1/jobs/{response.json()['id']}"
        assert response.json()["state"] == "queued"
        ids.append(response.json()["id"])

    status = api.get(f"/v1/jobs/{ids[0]}").json()
    # max 6 px: the bin pyramid has one level (7 bins of 1 px); the range's record (with the
    # views' check) is written by the job's first control task, which no worker runs here
    assert status["state"] == "queued" and status["progress"]["levels"] == 1
    assert status["disparity_range"] is None
    assert status["warnings"] == []
    assert (
        status["width"] == 32 and status["height"] == 24 and status["config"]["max_disparity"] == 6
    )
    not_ready = api.get(f"/v1/jobs/{ids[0]}/disparity")
    assert not_ready.status_code == 409 and "poll GET" in not_ready.json()["detail"]
    assert api.get(f"/v1/jobs/{ids[0]}/disparity", params={"format": "tiff"}).status_code == 422

    page = api.get("/v1/jobs", params={"limit": 2}).json()
    assert [item["id"] for item in page["items"]] == ids[::-1][:2]  # newest first
    assert page["next"] == "/v1/jobs?offset=2&limit=2"
    following = api.get(page["next"]).json()
    assert following["items"][0]["id"] == ids[0]

    cancelled = api.delete(f"/v1/jobs/{ids[1]}")
    assert cancelled.status_code == 200 and cancelled.json()["state"] == "cancelled"
    assert api.get(f"/v1/jobs/{ids[1]}/preview.png").status_code == 409


def test_unknown_jobs_are_404(api):
    assert api.get("/v1/jobs/0123456789abcdef0123456789abcdef").status_code == 404
    assert api.get("/v1/jobs/../../etc/passwd").status_code == 404
    assert api.delete("/v1/jobs/nope").status_code == 404


def test_solvers_report_availability_and_workers(api):
    solvers = {s["name"]: s for s in api.get("/v1/solvers").json()}
    assert solvers["exact"]["available"] and solvers["exact"]["workers"] == []
    assert not solvers["fake-unavailable"]["available"]
    assert (
        solvers["fake-unavailable"]["reason"]
        == "fake-unavailable needs hardware this machine lacks"
    )


def test_health_and_readiness(api, make_client):
    assert api.get("/healthz").json()["status"] == "ok"
    # no worker here: nothing would start a job
    ready = api.get("/readyz")
    assert ready.status_code == 503, ready.text
    assert ready.json()["redis"] == "ok" and "control" in ready.json()["queues_without_consumer"]
    from workers.embedded_redis import free_port

    down = make_client(redis_url=f"redis://127.0.0.1:{free_port()}/0")
    response = down.get("/readyz")
    assert response.status_code == 503 and response.json()["status"] == "unavailable"


def test_openapi_docs(api):
    assert api.get("/docs").status_code == 200
    assert "/v1/jobs/{job_id}/disparity" in api.get("/openapi.json").json()["paths"]


def test_a_metered_jobs_charge_is_listed_and_shown(api, api_settings):
    """What the ledger charged the job (here settled by hand, as a QPU worker would)."""
    import redis

    from workers.quota import QuotaLedger

    job = post(api, params={"solver": "qpu-sim", "max_disparity": 6}).json()["id"]
    owner = api.get("/v1/me").json()["name"]
    ledger = QuotaLedger(redis.Redis.from_url(api_settings.redis_url), api_settings.key_prefix)
    ledger.settle(ledger.reserve(owner, job, 2.0, ttl=60), 1.25, problems=3)
    listed = {item["id"]: item for item in api.get("/v1/jobs").json()["items"]}
    assert listed[job]["qpu_seconds"] == 1.25
    assert api.get(f"/v1/jobs/{job}").json()["qpu_seconds"] == 1.25
    exact = post(api, params={"max_disparity": 6}).json()["id"]
    assert api.get(f"/v1/jobs/{exact}").json()["qpu_seconds"] is None
    for cancelled in (job, exact):
        assert api.delete(f"/v1/jobs/{cancelled}").status_code == 200


def test_readyz_names_full_storage(api, monkeypatch):
    """Redis refusing writes on a full disk (it refuses PING too) is storage, not Redis being
    unreachable; a full data disk is named as well (issue 29)."""
    store = api.app.state.services.store

    def refuse():
        raise redis.ResponseError("MISCONF Errors writing to the AOF file: No space left")

    monkeypatch.setattr(store, "ping", refuse)
    body = api.get("/readyz")
    assert body.status_code == 503
    assert body.json()["storage"].startswith("full: Redis cannot persist writes (MISCONF")
    assert "unreachable" not in body.json()["redis"]
    monkeypatch.undo()

    from api.routes import health

    monkeypatch.setattr(health, "MIN_FREE_BYTES", 2**62)
    body = api.get("/readyz")
    assert body.status_code == 503 and body.json()["storage"].startswith("full: the disk of")
