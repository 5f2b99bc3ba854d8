"""Session fixtures: a real Redis, three real Celery workers (prefork) and an in-process API.

As under ``qhsm serve``, worker ``control`` consumes only the control queue; worker ``main``
consumes the CPU queues + the fakes; worker ``routed`` consumes only ``gurobi`` and
``fake-routed``, so routing is observable. ``fake-sleepy`` and ``fake-hung`` get a time limit of
``TIME_LIMIT`` seconds per task (hard limit one second later). Everything lives under a unique key
prefix in a dedicated Redis database and is deleted afterwards.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))  # the harness and the test plugin (entry points)

import harness

from shared.config import Settings
from workers.app import make_celery
from workers.supervisor import WorkerProcess, wait_for_workers

ROWS_PER_TASK = 4
SLOW_SECONDS = 0.25
TIME_LIMIT = 1.0
MAIN_QUEUES = [
    "exact",
    "sa",
    "fake-slow",
    "fake-flaky",
    "fake-broken",
    "fake-sleepy",
    "fake-hung",
    "fake-split",
    "fake-hog",
    "dimod",
]
ROUTED_QUEUES = ["gurobi", "fake-routed"]
#: Seconds the session's workers get to answer (serve's own deadline is 60 s).
WORKERS_START_TIMEOUT = 180.0


@pytest.fixture(scope="session")
def service_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("service")


@pytest.fixture(scope="session")
def settings(redis_url, service_dir) -> Settings:
    prefix = harness.unique_prefix()
    yield Settings(
        redis_url=redis_url,
        key_prefix=prefix,
        data_dir=service_dir / "data",
        rows_per_task=ROWS_PER_TASK,
        solver_rows_per_task={},
        retry_backoff=0.1,
        inspect_timeout=0.5,
        solver_time_limits={"fake-sleepy": TIME_LIMIT, "fake-hung": TIME_LIMIT},
        task_time_limit_grace=1.0,
        max_active_jobs_per_user=None,
    )
    harness.drop_prefix(redis_url, prefix)


@pytest.fixture(scope="session")
def markers(service_dir) -> Path:
    folder = service_dir / "markers"
    folder.mkdir()
    return folder


@pytest.fixture(scope="session")
def workers(settings, markers, service_dir):
    """The two workers, started once per session (about 5 s)."""
    from workers.supervisor import worker_env

    env = worker_env(settings, settings.redis_url, dwave=False)
    env["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).parent), env.get("PYTHONPATH", "")])
    env["QHSM_RETRY_BACKOFF"] = str(settings.retry_backoff)
    env["QHSM_TEST_SLOW_SECONDS"] = str(SLOW_SECONDS)
    env["QHSM_TEST_MARKERS"] = str(markers)
    env["QHSM_SOLVER_TIME_LIMITS"] = json.dumps(settings.solver_time_limits)
    env["QHSM_TASK_TIME_LIMIT_GRACE"] = str(settings.task_time_limit_grace)
    env["QHSM_TASK_MEMORY_LIMIT_MB"] = str(harness.MEMORY_LIMIT_MB)
    logs = service_dir / "logs"
    suffix = settings.key_prefix
    started = {
        "control": WorkerProcess(
            f"control-{suffix}", [settings.control_queue], 1, env, logs / "control.log"
        ).start(),
        "main": WorkerProcess(
            f"main-{suffix}", [*MAIN_QUEUES, settings.pricing_queue], 2, env, logs / "main.log"
        ).start(),
        "routed": WorkerProcess(
            f"routed-{suffix}", ROUTED_QUEUES, 1, env, logs / "routed.log"
        ).start(),
    }
    try:
        # pytest-xdist's workers start their own at once: allow for a busy machine
        wait_for_workers(
            make_celery(settings, with_tasks=False),
            [w.hostname for w in started.values()],
            timeout=WORKERS_START_TIMEOUT,
        )
        yield started
    finally:
        harness.stop_workers(started.values())


@pytest.fixture(scope="session")
def admin_key(settings) -> str:
    return harness.admin_key(settings)


@pytest.fixture(scope="session")
def client(settings, workers, admin_key):
    """The API in process, authenticated as an admin (tests/service/test_users.py covers auth)."""
    with harness.api_client(settings, admin_key) as test_client:
        yield test_client


@pytest.fixture(scope="session")
def pair_arrays():
    """A small synthetic pair as float32 arrays."""
    from shared.synthetic import make_scene

    scene = make_scene(32, 48, max_disparity=8, seed=2)
    return scene.left, scene.right
