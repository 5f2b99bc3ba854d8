"""Memory as an admitted resource (issue 29): a job's peak memory is estimated from its size,
range and solver and shown; a worker process's budget is its share of its host's memory; a job
above it is refused (413) at submit, or failed at its start by a worker whose host has less;
a task that grows past the budget at run time gets a MemoryError (its job then fails with a
message). Small sizes and low configured limits."""

from __future__ import annotations

import json

import harness
import numpy as np
import pytest
from hypothesis import given
from hypothesis import settings as settings_
from hypothesis import strategies as st

from shared.config import MatchConfig
from shared.memory import MemoryBudgetError, host_memory_mb, job_memory_mb, worker_budget_mb
from shared.synthetic import make_scene
from workers import orchestration
from workers.app import make_celery
from workers.process import memory_budget
from workers.records import JobRecord, JobState, new_job_id, now
from workers.store import JobStore

SCENE = make_scene(24, 32, max_disparity=6, seed=1)
FILES = {"left": ("l.png", harness.png(SCENE.left)), "right": ("r.png", harness.png(SCENE.right))}


@settings_(max_examples=50, deadline=None)
@given(
    side=st.integers(16, 3000),
    grow=st.integers(1, 1000),
    top=st.integers(2, 256),
    solver=st.sampled_from(["exact", "sa", "dimod:dwave.samplers.TreeDecompositionSolver"]),
)
def test_the_estimate_grows_with_the_size_and_the_solver(side, grow, top, solver):
    """(Not with every step of the range: the pyramid's coarsest level may hold fewer bins at
    a larger range.)"""
    config = MatchConfig(solver=solver)
    small = job_memory_mb(config, side, side, top)
    assert small <= job_memory_mb(config, side + grow, side, top)
    assert small <= job_memory_mb(config, side, side + grow, top)
    assert small >= job_memory_mb(MatchConfig(solver="exact"), side, side, top)


def test_the_calibration_points_are_estimated_within_a_third():
    """The peaks measured for docs/benchmarks.md ("Memory of a job: calibration")."""
    measured = {(256, 32): 348, (384, 16): 358, (512, 64): 614, (768, 64): 1065, (2000, 256): 1884}
    for (side, top), peak in measured.items():
        estimate = job_memory_mb(MatchConfig(), side, side, top)
        assert 0.75 * peak <= estimate <= 1.33 * peak, (side, top, estimate, peak)


def test_the_workers_of_a_host_share_80_percent_of_its_memory(settings):
    for processes in (1, 4, 13):
        share = worker_budget_mb(
            settings.model_copy(update={"task_memory_limit_mb": None}), processes
        )
        assert processes * share <= 0.8 * host_memory_mb()
    assert worker_budget_mb(settings.model_copy(update={"task_memory_limit_mb": 300})) == 300
    assert worker_budget_mb(settings.model_copy(update={"task_memory_limit_mb": 0})) is None


def test_a_job_above_the_budget_is_413_naming_it_and_the_estimate_is_shown(settings, workers):
    low = settings.model_copy(
        update={"task_memory_limit_mb": 200, "max_active_jobs_per_user": None}
    )
    params = {"params": json.dumps({"solver": "exact", "max_disparity": 6})}
    with harness.api_client(low) as client:
        refused = client.post("/v1/jobs", files=FILES, data=params)
        assert refused.status_code == 413, refused.text
        detail = refused.json()["detail"]
        assert "above the limit of 200 MiB per worker process" in detail
        assert "QHSM_TASK_MEMORY_LIMIT_MB" in detail
        asked = client.post("/v1/estimate", files=FILES, data=params).json()
        status = harness.wait_for(client, asked["id"], path="/v1/estimates/{}")
        priced = status["result"]  # the worker's estimate against the API's budget
        assert priced["memory_budget_mb"] == 200 and priced["memory_mb"] > 200
    roomy = low.model_copy(update={"task_memory_limit_mb": 4000})
    with harness.api_client(roomy) as client:
        accepted = client.post("/v1/jobs", files=FILES, data=params)
        assert accepted.status_code == 202, accepted.text
        status = client.get(f"/v1/jobs/{accepted.json()['id']}").json()
        assert status["memory_mb"] == job_memory_mb(MatchConfig(max_disparity=6), 24, 32, 6)


def test_a_worker_with_less_memory_fails_the_job_at_its_start(settings):
    """The API's host admitted it; the worker's host (its own settings) has less."""
    small = settings.model_copy(update={"task_memory_limit_mb": 100})
    store = JobStore.from_settings(small)
    config = MatchConfig(solver="exact", max_disparity=6)
    record = JobRecord(id=new_job_id(), config=config, width=32, height=24, created_at=now())
    store.create(record, {"left": SCENE.left, "right": SCENE.right})
    with pytest.raises(MemoryBudgetError, match="above the limit of 100 MiB"):
        orchestration.start_job(make_celery(small, with_tasks=False), store, record.id)
    assert store.get(record.id).memory_mb > 100
    store.transition(record.id, JobState.CANCELLED, {JobState.RUNNING})


def test_a_block_over_its_budget_gets_a_memory_error_and_the_limit_is_restored():
    with pytest.raises(MemoryError), memory_budget(100):
        np.ones(400 * 2**20, np.uint8)  # 400 MiB against a 100 MiB budget
    assert np.ones(400 * 2**20, np.uint8).sum() == 400 * 2**20  # the limit is gone after
    with memory_budget(100):
        assert np.ones(2**20, np.uint8).sum() == 2**20  # within it: fine
