"""Recovery from worker liveness (issue 20, item 3), with real workers of their own under a key
prefix of their own: a worker whose main process is SIGKILLed holding a job's start task or its
bundles has exactly those messages put back in their queues (not after the 6-hour visibility
timeout, nor after the 300 s stall), a live worker's long task is never sent again, and a queued
job whose start task was never sent is started. The watchdog's stall settings are the defaults;
only the heartbeat is faster (0.5 s) so that the tests are short."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import harness
import numpy as np
import pytest
import redis

from shared.config import MatchConfig, Settings
from shared.images import decode_image
from shared.pipeline import run_pipeline
from shared.synthetic import make_scene
from workers import liveness
from workers.app import make_celery
from workers.records import JobRecord, new_job_id, now
from workers.store import JobStore
from workers.supervisor import WorkerProcess, wait_for_workers, worker_env
from workers.telemetry import Telemetry
from workers.watchdog import resend_count

pytestmark = pytest.mark.service

HEARTBEAT = 0.5
SLOW_SECONDS = 0.5  # per bundle of fake-slow
SCENE = make_scene(16, 24, max_disparity=6, seed=8)
UPLOADS = harness.png(SCENE.left), harness.png(SCENE.right)


@pytest.fixture
def stack(tmp_path, redis_url):
    """Settings of a service of its own (its prefix, data directory) and a way to start its
    workers; everything is stopped and deleted afterwards."""
    settings = Settings(
        redis_url=redis_url,
        key_prefix=harness.unique_prefix(),
        data_dir=tmp_path / "data",
        rows_per_task=4,
        inspect_timeout=0.5,
        worker_heartbeat_seconds=HEARTBEAT,
        max_active_jobs_per_user=None,
    )
    env = worker_env(settings, redis_url, dwave=False)
    env["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).parent), env.get("PYTHONPATH", "")])
    env["QHSM_WORKER_HEARTBEAT_SECONDS"] = str(HEARTBEAT)
    env["QHSM_TEST_SLOW_SECONDS"] = str(SLOW_SECONDS)
    starter = Starter(settings, env, tmp_path)
    try:
        yield settings, starter
    finally:
        harness.stop_workers(starter.started)
        harness.drop_prefix(redis_url, settings.key_prefix)


class Starter:
    """Starts workers of the stack: one (``starter(name, queues, **env)``) or several at once
    (``together``: their start-ups overlap), each answering before it returns."""

    def __init__(self, settings: Settings, env: dict[str, str], folder: Path):
        self.settings, self.env, self.folder = settings, env, folder
        self.celery = make_celery(settings, with_tasks=False)
        self.started: list[WorkerProcess] = []

    def __call__(self, name: str, queues: list[str], **more: str) -> WorkerProcess:
        [worker] = self.together((name, queues, more))
        return worker

    def together(self, *specs: tuple[str, list[str], dict[str, str]]) -> list[WorkerProcess]:
        workers = [
            WorkerProcess(
                f"{name}-{self.settings.key_prefix}", queues, 1, {**self.env, **more},
                self.folder / f"{name}.log",
            ).start()
            for name, queues, more in specs
        ]  # fmt: skip
        self.started += workers
        wait_for_workers(self.celery, [worker.hostname for worker in workers])
        return workers


def reference(params: dict) -> np.ndarray:
    import qhsm_test_plugin  # noqa: F401 - fake-slow in this process

    views = [decode_image(data, name) for data, name in zip(UPLOADS, ("l", "r"), strict=True)]
    saved = os.environ.get("QHSM_TEST_SLOW_SECONDS")
    os.environ["QHSM_TEST_SLOW_SECONDS"] = "0"
    try:
        return run_pipeline(*views, MatchConfig.model_validate(params)).disparity
    finally:
        os.environ.pop("QHSM_TEST_SLOW_SECONDS")
        if saved is not None:
            os.environ["QHSM_TEST_SLOW_SECONDS"] = saved


def holding(settings: Settings, worker: WorkerProcess, timeout: float = 30.0) -> list[str]:
    """The delivery tags ``worker`` says it holds, once it holds one."""
    client = redis.Redis.from_url(settings.redis_url)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for instance, tags in liveness.live_holdings(client, settings.key_prefix).items():
            if instance.startswith(worker.hostname + "#") and tags:
                return sorted(tags)
        time.sleep(0.1)
    raise AssertionError(f"{worker.hostname} never held a message")


def kill(worker: WorkerProcess) -> None:
    """SIGKILL the worker's main process (its pool processes die with it)."""
    os.kill(worker.pid, signal.SIGKILL)
    worker.process.wait()


def succeeds_past_a_kill(
    stack,
    victim: WorkerProcess,
    params: dict,
    replacements: list[tuple[str, list[str]]],
    timeout: float,
    within: float,
    held_state: str | None = None,
) -> None:
    """Submit a job, SIGKILL ``victim`` once it holds one of the job's messages (the job then in
    ``held_state``, if given) and start the ``replacements`` (name, queues): the job succeeds
    within ``within`` seconds, with the disparity of an in-process run."""
    settings, start = stack
    with harness.api_client(settings) as client:
        job_id = harness.submit(client, *UPLOADS, params)
        holding(settings, victim)
        if held_state is not None:
            assert client.get(f"/v1/jobs/{job_id}").json()["state"] == held_state
        kill(victim)
        start.together(*[(name, queues, {}) for name, queues in replacements])
        began = time.monotonic()
        status = harness.wait_for(client, job_id, timeout=timeout)
    assert status["state"] == "succeeded", status
    assert time.monotonic() - began < within
    assert np.array_equal(harness_download(settings, job_id), reference(params))


def test_a_job_whose_control_worker_died_holding_its_start_is_started_within_seconds(stack):
    """The control worker takes the start task, then dies before its pool process runs it:
    the job used to stay queued for the 6-hour visibility timeout."""
    settings, start = stack
    first = start("control-a", [settings.control_queue])
    [pool] = first.children()
    os.kill(pool, signal.SIGSTOP)  # holds the start message, never runs it
    # control-b: the new control worker serve's supervisor starts
    replacements = [("control-b", [settings.control_queue]), ("cpu", ["exact"])]
    params = harness.one_level(solver="exact", seed=2)
    succeeds_past_a_kill(stack, first, params, replacements, 60, within=30, held_state="queued")
    live = liveness.live_holdings(redis.Redis.from_url(settings.redis_url), settings.key_prefix)
    assert live and not any(name.startswith(first.hostname + "#") for name in live)  # forgotten


def test_a_job_whose_solver_worker_died_mid_task_finishes_identically(stack):
    """A CPU worker's main process is SIGKILLed while its task runs: the message it held goes
    back to the queue at once, not after the 300 s stall."""
    settings, start = stack
    _, victim = start.together(
        ("control", [settings.control_queue], {}), ("cpu-a", ["fake-slow"], {})
    )
    params = harness.one_level(solver="fake-slow", seed=4)
    succeeds_past_a_kill(stack, victim, params, [("cpu-b", ["fake-slow"])], 90, within=60)
    assert resend_count(JobStore.from_settings(settings)) >= 1


def test_a_live_workers_long_task_is_never_sent_again(stack):
    """Tasks that outlast every threshold but the stall (8 s: more than the heartbeat's expiry
    and watchdog_lost_seconds, 3 s here) on a live worker are left alone: each bundle is solved
    once."""
    settings, start = stack
    start.together(
        (
            "control",
            [settings.control_queue],
            {"QHSM_ROWS_PER_TASK": "16", "QHSM_WATCHDOG_LOST_SECONDS": "3"},  # one task: 8 s
        ),
        ("cpu", ["fake-slow"], {}),
    )
    params = harness.one_level(solver="fake-slow", seed=6)
    with harness.api_client(settings) as client:
        job_id = harness.submit(client, *UPLOADS, params)
        status = harness.wait_for(client, job_id, timeout=120)
    assert status["state"] == "succeeded", status
    store = JobStore.from_settings(settings)
    assert resend_count(store) == 0
    counted = Telemetry(store.redis, settings.key_prefix).key("bundles")
    solved = store.redis.hget(counted, "fake-slow")
    assert int(solved) == SCENE.left.shape[0]  # every row once, none twice


def test_a_queued_job_whose_start_was_never_sent_is_started(stack):
    """The API died between writing the job and sending its start: the watchdog sends it."""
    settings, start = stack
    store = JobStore.from_settings(settings)
    config = MatchConfig.model_validate(harness.one_level(solver="exact", seed=1))
    record = JobRecord(
        id=new_job_id(), config=config, width=24, height=16, created_at=now(),
        disparity_range={"max_disparity": 8, "source": "given", "confirmed": 0.0, "note": ""},
        levels_total=1,
    )  # fmt: skip
    views = [decode_image(data, name) for data, name in zip(UPLOADS, ("l", "r"), strict=True)]
    store.create(record, {"left": views[0], "right": views[1]})
    start.together(
        ("control", [settings.control_queue], {"QHSM_WATCHDOG_LOST_SECONDS": "2"}),
        ("cpu", ["exact"], {}),
    )
    with harness.api_client(settings) as client:
        status = harness.wait_for(client, record.id, timeout=60)
    assert status["state"] == "succeeded", status


def harness_download(settings: Settings, job_id: str) -> np.ndarray:
    disparity = JobStore.from_settings(settings).load_result(job_id)
    assert disparity is not None
    return disparity
