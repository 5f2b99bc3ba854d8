"""Jobs through HTTP + Celery + Redis with real workers: results, cancel, failures, routing,
and a worker process killed mid-level."""

from __future__ import annotations

import io
import json
import os
import signal
import time

import harness
import numpy as np
import pytest

from shared.config import MatchConfig
from shared.images import decode_image
from shared.pipeline import run_pipeline
from shared.solvers.registry import get_solver, solver_names
from shared.synthetic import make_scene

pytestmark = pytest.mark.service

SMALL = {"height": 32, "width": 48, "max_disparity": 8}


@pytest.fixture(scope="module")
def pair():
    """A small synthetic pair as PNG bytes, its decoded views and its ground truth."""
    scene = make_scene(**SMALL, seed=3)
    left, right = harness.png(scene.left), harness.png(scene.right)
    return left, right, decode_image(left, "left"), decode_image(right, "right"), scene.disparity


def reference(pair, params: dict) -> np.ndarray:
    _, _, left, right, _ = pair
    return run_pipeline(left, right, MatchConfig.model_validate(params)).disparity


def test_a_coarse_grid_job_gives_the_in_process_map(client, pair):
    """The accurate preset's coarse level at half size (40 px: widths 8, 4, 2, 1): the workers pool
    its costs from the views block by block, the process from its cached volumes; one map."""
    left, right, left_view, right_view, _ = pair
    params = {"solver": "exact", "max_disparity": 40, "seed": 5}
    job_id = harness.submit(client, left, right, params)
    status = harness.wait_for(client, job_id)
    assert status["state"] == "succeeded", status["error"]
    local = run_pipeline(left_view, right_view, MatchConfig.model_validate(params))
    assert np.array_equal(harness.download(client, job_id), local.disparity)
    levels = [(level["downsample"], level["height"]) for level in status["levels"]]
    assert levels == [(2, 16), (1, 32), (1, 32), (1, 32)]
    assert [level["energy"] for level in status["levels"]] == [
        level.energy for level in local.levels
    ]


@pytest.mark.parametrize(
    "params",
    [
        {"solver": "exact", "max_disparity": 8, "seed": 5},
        {
            "solver": "sa",
            "max_disparity": 8,
            "seed": 7,
            "encoding": "domain-wall",
            "solver_params": {"num_reads": 4, "num_sweeps": 100},
        },
        {
            "solver": "dimod:dwave.samplers.SteepestDescentSolver",
            "max_disparity": 8,
            "seed": 3,
            "encoding": "domain-wall",
        },
    ],
    ids=["exact", "sa", "dimod"],
)
def test_result_identical_to_in_process_pipeline(client, pair, settings, params):
    left, right, _, _, truth = pair
    job_id = harness.submit(
        client, left, right, params, ground_truth=harness.npy(truth), gt_scale=1.0, gt_border=2
    )
    status = harness.wait_for(client, job_id)
    assert status["state"] == "succeeded", status["error"]
    _, _, left_view, right_view, _ = pair
    local = run_pipeline(left_view, right_view, MatchConfig.model_validate(params))
    assert np.array_equal(harness.download(client, job_id), local.disparity)
    # the provenance map: the bundles' codes travel through the store (a whole view's too)
    stages = client.get(status["links"]["provenance"].replace("png", "npy"))
    assert np.array_equal(np.load(io.BytesIO(stages.content)), local.provenance_map)
    assert status["provenance_counts"] == local.summary()["provenance_counts"]

    # max 8 px: bins of 2 then 1 px; both views are bundles of each level's chord: exact takes
    # each view's whole grid (with a lower bound); a QUBO solver gets the 4x4 tiles around the
    # pixels the host's dual decomposition left unsettled (shared.settle), with its bound too
    last = status["levels"][-1]
    bundles = 2 if params["solver"] == "exact" else last["residual"]["tiles"]
    assert status["progress"] == {
        "level": 2,
        "levels": 2,
        "bundles_done": bundles,
        "bundles_total": bundles,
        "phase": None,  # said only while a level is prepared
        "stage": None,  # only a pricing job has one
        "fraction": None,
    }
    bounds = [level["lower_bound"] for level in status["levels"]]
    assert all(b <= level["energy"] for b, level in zip(bounds, status["levels"], strict=True))
    if params["solver"] != "exact":
        for level in status["levels"]:
            residual = level["residual"]
            assert residual["certified"] + residual["unsettled"] == residual["pixels"]
            assert residual["pixels_sent"] == 16 * residual["tiles"] < residual["pixels"]
    assert [(level["bin_width"], level["views"]) for level in status["levels"]] == [(2, 2), (1, 2)]
    assert [level["height"] for level in status["levels"]] == [32, 32]
    assert status["disparity_range"]["max_disparity"] == 8
    assert status["usage"]["solver_seconds"] > 0
    assert 0 <= status["metrics"]["bpp"] <= 100 and status["metrics"]["pixels"] > 0
    # the finest level was really fanned out: several tasks (exact: one per view)
    from workers.store import JobStore

    chunks = [c for c in JobStore.from_settings(settings).chunks(job_id) if c.level == 1]
    assert sum(c.bundles for c in chunks) == bundles and len(chunks) >= min(bundles, 2)
    for fmt, magic in [("pfm", b"Pf"), ("png", b"\x89PNG")]:
        response = client.get(f"/v1/jobs/{job_id}/disparity", params={"format": fmt})
        assert response.status_code == 200 and response.content.startswith(magic)
    preview = client.get(f"/v1/jobs/{job_id}/preview.png")
    assert preview.status_code == 200 and preview.headers["content-type"] == "image/png"
    if params["solver"] == "exact":  # the maps beside the result, as `qhsm match` writes them
        links = status["links"]
        valid = decode_image(client.get(links["validity"]).content, "validity")
        assert np.array_equal(valid > 0.5, local.validity)
        confidence = client.get(links["confidence"].replace("pfm", "npy"))
        assert np.allclose(np.load(io.BytesIO(confidence.content)), local.confidence, atol=1e-6)


def test_an_auto_range_is_resolved_by_the_job_as_in_process(client, pair):
    """The range estimate and the views' check run in the job's first control task (not in
    the HTTP request); the job reports the same range and levels, and the same map, as the
    in-process pipeline."""
    left, right, left_view, right_view, _ = pair
    params = {"solver": "exact", "max_disparity": "auto"}
    status = harness.wait_for(client, harness.submit(client, left, right, params))
    assert status["state"] == "succeeded", status["error"]
    expected = run_pipeline(left_view, right_view, MatchConfig.model_validate(params))
    assert status["disparity_range"] == expected.disparity_range.as_dict()
    assert status["progress"]["levels"] == len(status["levels"]) == len(expected.levels)
    assert np.array_equal(harness.download(client, status["id"]), expected.disparity)


def test_cancel_stops_unsolved_bundles(client, pair):
    left, right, *_ = pair
    job_id = harness.submit(client, left, right, harness.one_level(solver="fake-slow"))
    running = wait_for_progress(client, job_id, at_least=1)
    assert running["state"] == "running"

    cancelled = client.delete(f"/v1/jobs/{job_id}")
    assert cancelled.status_code == 200 and cancelled.json()["state"] == "cancelled"
    solved_at_cancel = cancelled.json()["progress"]["bundles_done"]
    time.sleep(2 * 4 * 0.25 + 0.5)  # anything in flight (2 tasks x 4 bundles) has finished

    final = client.get(f"/v1/jobs/{job_id}").json()
    assert final["state"] == "cancelled"
    in_flight = 2 * 4
    assert final["progress"]["bundles_done"] <= solved_at_cancel + in_flight
    assert final["progress"]["bundles_done"] < final["progress"]["bundles_total"] == 32
    assert client.get(f"/v1/jobs/{job_id}/disparity").status_code == 409
    assert client.delete(f"/v1/jobs/{job_id}").status_code == 200  # idempotent


def test_permanent_solver_error_fails_the_job_with_its_message(client, pair):
    left, right, *_ = pair
    # a bundle shape the solver cannot take is refused before any work
    params = {"solver": "exact", "inference": "rows", "bundle_height": 2}
    response = client.post(
        "/v1/jobs",
        files={"left": ("left.png", left), "right": ("right.png", right)},
        data={"params": json.dumps(params)},
    )
    assert response.status_code == 422
    assert "single-row bundles" in response.text and "bundle_height 2" in response.text

    job_id = harness.submit(client, left, right, harness.one_level(solver="fake-broken"))
    status = harness.wait_for(client, job_id)
    assert status["state"] == "failed"
    assert "the device is on fire; use another solver" in status["error"]
    assert client.get(f"/v1/jobs/{job_id}/disparity").status_code == 409


def test_transient_solver_error_is_retried(client, pair):
    left, right, *_ = pair
    params = harness.one_level(solver="fake-flaky", seed=11)
    job_id = harness.submit(client, left, right, params)
    status = harness.wait_for(client, job_id)
    assert status["state"] == "succeeded", status["error"]
    # the same answer as the fake that never fails (both return the all-zero sample)
    steady = {**params, "solver": "fake-routed"}
    assert np.array_equal(harness.download(client, job_id), reference(pair, steady))


@pytest.mark.parametrize("solver", ["gurobi", "fake-routed"])
def test_jobs_run_only_on_workers_consuming_their_queue(client, pair, settings, workers, solver):
    if solver not in solver_names() or not get_solver(solver).available().ok:
        pytest.skip(f"{solver} is not available here")
    left, right, *_ = pair
    params = {"solver": solver, "max_disparity": 8, "preset": "paper"}  # fits gurobi's licence
    job_id = harness.submit(client, left, right, params)
    status = harness.wait_for(client, job_id, timeout=120)
    assert status["state"] == "succeeded", status["error"]
    from workers.store import JobStore

    solved_by = {chunk.worker for chunk in JobStore.from_settings(settings).chunks(job_id)}
    assert solved_by == {workers["routed"].hostname}


def test_job_survives_a_worker_process_killed_mid_level(client, pair, workers, markers):
    left, right, *_ = pair
    params = harness.one_level(solver="fake-slow", seed=3)
    job_id = harness.submit(client, left, right, params)
    victim = busy_pool_process(markers, workers["main"].children())
    os.kill(victim, signal.SIGKILL)

    status = harness.wait_for(client, job_id, timeout=60)
    assert status["state"] == "succeeded", status["error"]
    assert status["progress"]["bundles_done"] == status["progress"]["bundles_total"] == 32
    os.environ["QHSM_TEST_SLOW_SECONDS"] = "0"
    assert np.array_equal(harness.download(client, job_id), reference(pair, params))
    assert victim not in workers["main"].children()  # the pool replaced the dead process


def wait_for_progress(client, job_id: str, at_least: int, timeout: float = 30.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        status = client.get(f"/v1/jobs/{job_id}").json()
        if status["progress"]["bundles_done"] >= at_least or status["state"] in harness.TERMINAL:
            return status
        time.sleep(0.05)
    raise AssertionError(f"job {job_id} made no progress in {timeout} s")


def busy_pool_process(markers, children: list[int], timeout: float = 30.0) -> int:
    """A pool process of the worker that is solving a bundle right now."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for marker in markers.glob("busy-*"):
            pid = int(marker.name.removeprefix("busy-"))
            if pid in children:
                return pid
        time.sleep(0.02)
    raise AssertionError("no pool process started solving")


def test_row_segments_through_the_service_equal_the_in_process_result(client, pair, settings):
    """Segment bundles fan out, travel back with their columns and are stitched in the fan-in
    exactly as in process; each row's segments share a task."""
    from shared.bundles import segment_columns

    left, right, *_ = pair
    params = {
        "solver": "sa",
        "max_disparity": 8,
        "seed": 3,
        "encoding": "domain-wall",
        "bundle_width": 20,
        "bundle_margin": 4,
        "certify_tiles": False,  # every tile sent: the segments of the 3-row tiles
        "solver_params": {"num_reads": 4, "num_sweeps": 100},
    }
    job_id = harness.submit(client, left, right, params)
    status = harness.wait_for(client, job_id)
    assert status["state"] == "succeeded", status["error"]
    assert np.array_equal(harness.download(client, job_id), reference(pair, params))
    per_row = len(segment_columns(SMALL["width"], 20, 4))
    assert per_row == 3
    total = 2 * -(-SMALL["height"] // 3) * per_row  # tiles of 3 rows (grid inference)
    assert status["progress"]["bundles_total"] == status["progress"]["bundles_done"] == total
    assert [level["bundles"] for level in status["levels"]] == [total, total]


def test_a_width_the_solver_cannot_use_is_a_422(client, pair):
    left, right, *_ = pair
    response = client.post(
        "/v1/jobs",
        files={"left": ("l.png", left), "right": ("r.png", right)},
        data={"params": '{"solver": "exact", "bundle_width": 32}'},
    )
    assert response.status_code == 422
    assert "solves whole rows" in response.json()["detail"]
