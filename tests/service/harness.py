"""Test harness of the service tests: helpers to set up users and key prefixes in the tests'
Redis (the session's ``redis_url`` fixture, ``tests/conftest.py``) and to talk to the API."""

from __future__ import annotations

import io
import re
import shlex
import signal
import subprocess
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager

import cv2
import numpy as np
import redis

from shared.config import LevelConfig

TERMINAL = {"succeeded", "failed", "cancelled"}
#: Address space of a test worker's pool process, MiB: room for the solvers, not for fake-hog.
MEMORY_LIMIT_MB = 1536


#: A compose worker's ``sh -c`` command: its queues from the registry, then Celery.
_DERIVED = re.compile(r"queues=\$\(python -m workers\.queues (\S+)\) && exec (.*)")


def compose_command(command: list[str]) -> list[str]:
    """A docker-compose.yml service's command as the program it runs: the ``sh -c`` form of the
    worker services resolved, ``$(python -m workers.queues GROUP)`` replaced by the queues the
    registry gives that group (``KeyError`` for a group it has none of)."""
    from shared.solvers.registry import worker_groups

    if command[:2] != ["sh", "-c"]:
        return command
    script = command[2].replace("$$", "$")  # compose's escape of a literal $
    found = _DERIVED.fullmatch(script)
    assert found, f"not a derived worker command: {script}"
    group, rest = found.groups()
    queues = ",".join(worker_groups()[group])
    return shlex.split(rest.replace('"$queues"', queues))


def admin_key(settings) -> str:
    """A new admin's API key (a unique user per call) in the service's Redis."""
    from api.users import UserStore

    _, key = UserStore.from_settings(settings).create_user(
        f"test-admin-{uuid.uuid4().hex[:8]}", admin=True, qpu_seconds=None
    )
    return key


def api_client(settings, key: str | None = None):
    """The API in process (a ``TestClient``, to be entered) as ``key``'s user, default a new
    admin; a server error is answered as HTTP 500, not raised in the test."""
    from fastapi.testclient import TestClient

    from api.app import create_app

    return TestClient(
        create_app(settings),
        raise_server_exceptions=False,
        headers={"Authorization": f"Bearer {key or admin_key(settings)}"},
    )


@contextmanager
def killed_at_exit(process: subprocess.Popen) -> Iterator[None]:
    """SIGKILL ``process`` (a `qhsm serve`) when the block ends: its workers and Redis die with
    it (Linux's parent-death signal; test_serve.py checks that none is left). For fixtures
    that assert nothing on the stop: serve's orderly Ctrl-C stop took 10-12 s here, and is
    tested on its own (test_serve.py, test_dwave_service.py)."""
    try:
        yield
    finally:
        process.kill()
        process.wait()


@contextmanager
def interrupted_at_exit(process: subprocess.Popen, timeout: float = 30.0) -> Iterator[None]:
    """Stop ``process`` as a terminal's Ctrl-C does when the block ends (SIGINT), killing it if it
    has not stopped within ``timeout`` seconds."""
    try:
        yield
    finally:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def stop_workers(workers) -> None:
    """Stop a test's worker processes (``WorkerProcess``) once it is done with them: SIGKILL of
    each pool process and main process. No test asserts on these stops (warm shutdown is
    `qhsm serve`'s, tested in test_serve.py and test_cli.py), and a warm one took 1-2 s per
    worker; whatever a killed worker left in Redis is under the test's key prefix, dropped."""
    from workers.process import kill_now

    workers = [worker for worker in workers if worker.alive]
    for worker in workers:
        for child in worker.children():
            kill_now(child)
        worker.process.kill()
    for worker in workers:
        worker.process.wait()


def unique_prefix() -> str:
    return f"qhsm-test-{uuid.uuid4().hex[:10]}"


def drop_prefix(url: str, prefix: str) -> None:
    client = redis.Redis.from_url(url)
    keys = list(client.scan_iter(match=f"{prefix}:*", count=1000))
    for start in range(0, len(keys), 500):
        client.delete(*keys[start : start + 500])


def png(image: np.ndarray) -> bytes:
    return cv2.imencode(".png", np.rint(image * 255).astype(np.uint8))[1].tobytes()


def npy(array: np.ndarray) -> bytes:
    stream = io.BytesIO()
    np.save(stream, array)
    return stream.getvalue()


def one_level(candidates: int = 3, **extra) -> dict:
    """Job params of a single full-resolution level without filters: every bundle of the job is
    in one chord.

    Parameters
    ----------
    candidates : int
        Candidate disparities per pixel of the level.
    **extra
        More job params (solver, seed, solver_params ...).

    Returns
    -------
    dict
        The ``params`` form field of a job."""
    return {
        "preset": "paper",
        "levels": [LevelConfig(downsample=1, candidates=candidates).model_dump()],
        "max_disparity": 8,
        "median": False,
        "bilateral": False,
        **extra,
    }


def submit(client, left: bytes, right: bytes, params: dict | None = None, **files) -> str:
    import json

    data = {"params": json.dumps(params or {})}
    for key in ("gt_scale", "gt_border"):
        if key in files:
            data[key] = str(files.pop(key))
    parts = {"left": ("left.png", left), "right": ("right.png", right)}
    parts.update({name: (f"{name}.bin", content) for name, content in files.items()})
    response = client.post("/v1/jobs", files=parts, data=data)
    assert response.status_code == 202, response.text
    return response.json()["id"]


#: An estimate's final states (``workers.estimates.EstimateState``).
ESTIMATE_ENDS = ("done", "failed", "cancelled")


def wait_for(
    client, job_id: str, timeout: float = 60.0, states=TERMINAL, path: str = "/v1/jobs/{}"
) -> dict:
    """Poll a job (or with ``path="/v1/estimates/{}"`` an estimate) until it is in ``states``
    (an estimate: until it ends)."""
    if path.startswith("/v1/estimates") and states is TERMINAL:
        states = ESTIMATE_ENDS
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        status = client.get(path.format(job_id)).json()
        if status["state"] in states:
            return status
        time.sleep(0.05)
    raise AssertionError(f"job {job_id} still {status['state']} after {timeout} s: {status}")


def download(client, job_id: str) -> np.ndarray:
    response = client.get(f"/v1/jobs/{job_id}/disparity", params={"format": "npy"})
    assert response.status_code == 200, response.text
    return np.load(io.BytesIO(response.content))
