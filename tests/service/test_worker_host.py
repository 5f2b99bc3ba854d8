"""A worker host that shares nothing with the API but Redis (issue 22, item 3).

The test plays a second machine with a network namespace of its own (``ip netns``), joined to
this one by a veth pair on a link-local /30. A fresh redis-server (password, free port) listens
on this side of the link only; the API runs here with its own data directory; the control
worker and a CPU worker run in the namespace through ``qhsm worker``, each with an empty data
directory of its own and nothing but ``QHSM_REDIS_URL`` pointing back here (127.0.0.1 in the
namespace is its own loopback, where nothing answers). A job with a ground truth must succeed
there with exactly ``run_pipeline``'s disparity and metrics, and leave the workers' data
directories empty. Skipped where network namespaces cannot be made (not root, no ``ip``).
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import harness
import numpy as np
import pytest
import redis

from shared.config import MatchConfig, Settings
from shared.images import decode_image
from shared.metrics import evaluate
from shared.pipeline import run_pipeline
from shared.synthetic import make_scene
from workers.embedded_redis import free_port, redis_server_binary
from workers.process import die_with_parent

pytestmark = pytest.mark.service

ROOT = Path(__file__).parents[2]
SCENE = make_scene(24, 40, max_disparity=6, seed=11)
UPLOADS = harness.png(SCENE.left), harness.png(SCENE.right)
PARAMS = {"solver": "exact", "max_disparity": 6}


def run(*command: str) -> subprocess.CompletedProcess:
    return subprocess.run(command, capture_output=True, text=True, check=False)


class Link:
    """A network namespace joined to this one by a veth pair (``host`` <-> ``worker`` IPs)."""

    def __init__(self) -> None:
        tag = secrets.token_hex(3)
        self.namespace, self.outside, self.inside = f"qhsm-w-{tag}", f"qh{tag}", f"qw{tag}"
        block = secrets.randbelow(64) * 4  # a random link-local /30: runs in parallel differ
        third = 100 + secrets.randbelow(100)
        self.host, self.worker = f"169.254.{third}.{block + 1}", f"169.254.{third}.{block + 2}"

    def up(self) -> None:
        steps = [
            ["ip", "netns", "add", self.namespace],
            ["ip", "link", "add", self.outside, "type", "veth", "peer", "name", self.inside],
            ["ip", "link", "set", self.inside, "netns", self.namespace],
            ["ip", "addr", "add", f"{self.host}/30", "dev", self.outside],
            ["ip", "link", "set", self.outside, "up"],
            ["ip", "-n", self.namespace, "addr", "add", f"{self.worker}/30", "dev", self.inside],
            ["ip", "-n", self.namespace, "link", "set", self.inside, "up"],
            ["ip", "-n", self.namespace, "link", "set", "lo", "up"],
        ]
        for step in steps:
            done = run(*step)
            if done.returncode != 0:
                raise OSError(f"{' '.join(step)}: {done.stderr.strip()}")

    def down(self) -> None:
        run("ip", "link", "del", self.outside)  # also removes its peer
        run("ip", "netns", "del", self.namespace)

    def exists(self) -> bool:
        return self.namespace in run("ip", "netns", "list").stdout


@pytest.fixture
def link():
    if not hasattr(os, "geteuid") or os.geteuid() != 0:
        pytest.skip("needs root to make a network namespace (ip netns)")
    if shutil.which("ip") is None:
        pytest.skip("no `ip` command (iproute2) to make a network namespace")
    made = Link()
    try:
        made.up()
    except OSError as error:
        made.down()
        pytest.skip(f"cannot make a network namespace here: {error}")
    try:
        yield made
    finally:
        made.down()
        assert not made.exists()


def start(command: list[str], log: Path, env: dict[str, str] | None = None) -> subprocess.Popen:
    """A process group of its own (stopped whole), dying with this one."""
    with log.open("ab") as out:
        return subprocess.Popen(
            command,
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
            preexec_fn=die_with_parent,
            process_group=0,
        )


def stop(process: subprocess.Popen, timeout: float = 15.0) -> None:
    """SIGTERM to the process's group (a worker and its pool), SIGKILL after ``timeout``."""
    if process.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGTERM)
        try:
            process.wait(timeout)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)
            process.wait()


def wait_for_redis(url: str, timeout: float = 20.0) -> None:
    client = redis.Redis.from_url(url)
    deadline = time.monotonic() + timeout
    while True:
        try:
            client.ping()
            return
        except redis.ConnectionError:
            assert time.monotonic() < deadline, f"redis-server did not answer at {url}"
            time.sleep(0.1)


def test_a_job_runs_on_workers_in_another_network_namespace_with_no_shared_files(link, tmp_path):
    from workers.app import make_celery
    from workers.supervisor import wait_for_workers

    password, port = secrets.token_hex(16), free_port()
    url = f"redis://:{password}@{link.host}:{port}/0"
    prefix = harness.unique_prefix()
    logs = tmp_path / "logs"
    logs.mkdir()
    processes: list[subprocess.Popen] = []
    homes = {role: tmp_path / f"worker-{role}" for role in ("control", "cpu")}
    try:
        redis_dir = tmp_path / "redis"
        redis_dir.mkdir()
        server = [
            str(redis_server_binary()), "--bind", link.host, "--port", str(port),
            "--requirepass", password, "--save", "", "--appendonly", "no",
            "--dir", str(redis_dir),
        ]  # fmt: skip
        processes.append(start(server, logs / "redis.log"))
        wait_for_redis(url)
        settings = Settings(
            redis_url=url,
            key_prefix=prefix,
            data_dir=tmp_path / "api-data",
            inspect_timeout=1.0,
            max_active_jobs_per_user=None,
        )
        names = {}
        for role, queues in {"control": "control", "cpu": "exact,sa"}.items():
            homes[role].mkdir()
            env = {
                "PATH": os.environ.get("PATH", "/usr/bin:/bin"),
                "HOME": str(homes[role]),
                "PYTHONPATH": str(ROOT),
                "QHSM_REDIS_URL": url,
                "QHSM_KEY_PREFIX": prefix,
                "QHSM_DATA_DIR": str(homes[role] / "data"),
                "QHSM_TASK_MEMORY_LIMIT_MB": str(harness.MEMORY_LIMIT_MB),
            }
            names[role] = f"{role}-{prefix}"
            command = [
                "ip", "netns", "exec", link.namespace,
                sys.executable, "-m", "shared.cli", "worker",
                "--queues", queues, "--concurrency", "1", "--name", names[role],
            ]  # fmt: skip
            processes.append(start(command, logs / f"{role}.log", env))
        celery = make_celery(settings, with_tasks=False)
        wait_for_workers(celery, [f"{name}@{socket.gethostname()}" for name in names.values()])

        truth = SCENE.disparity.astype(np.float32)
        with harness.api_client(settings) as client:
            job = harness.submit(
                client, *UPLOADS, PARAMS, ground_truth=harness.npy(truth), gt_scale=1
            )
            status = harness.wait_for(client, job, timeout=120)
            assert status["state"] == "succeeded", status
            disparity = harness.download(client, job)

        views = [decode_image(data, "view") for data in UPLOADS]
        config = MatchConfig.model_validate(PARAMS)
        expected = run_pipeline(*views, config).disparity
        assert np.array_equal(disparity, expected)
        scores = evaluate(expected, truth, scale=1.0, border=status["ground_truth"]["border"])
        assert status["metrics"] == pytest.approx(scores.as_dict())
        assert status["levels"] and len(status["levels"]) == status["progress"]["levels"]
        for role, home in homes.items():  # the workers wrote no file, of the job or otherwise
            assert [p for p in home.rglob("*") if p.is_file()] == [], role
        ran = {role: (logs / f"{role}.log").read_text() for role in names}
        assert "qhsm.start_job" in ran["control"] and "qhsm.level_done" in ran["control"]
        assert "qhsm.solve_rows" in ran["cpu"]
    finally:
        for process in reversed(processes):
            stop(process)
        for home in homes.values():
            shutil.rmtree(home, ignore_errors=True)


def test_qhsm_worker_needs_the_redis_url_and_gives_the_token_only_to_qpu_queues(
    monkeypatch, capsys
):
    """What ``qhsm worker`` runs (captured instead of exec'd): the queues asked for, the D-Wave
    token only for a queue that spends QPU time, the Redis password nowhere in its output."""
    from shared.cli import main

    ran = []
    monkeypatch.setattr(os, "execve", lambda path, command, env: ran.append((command, env)))
    for name in ("QHSM_REDIS_URL", "REDIS_URL"):
        monkeypatch.delenv(name, raising=False)
    assert main(["worker"]) == 1
    assert "set QHSM_REDIS_URL" in capsys.readouterr().err and not ran

    monkeypatch.setenv("QHSM_REDIS_URL", "redis://:pass-never-shown@worker-test:6379/0")
    monkeypatch.setenv("DWAVE_API_TOKEN", "token-sentinel")
    assert main(["worker", "--queues", "nope,sa"]) == 1
    assert "unknown queue(s) nope" in capsys.readouterr().err and not ran
    assert main(["worker", "--queues", "sa,exact", "--name", "solver"]) == 0
    assert main(["worker", "--queues", "qpu"]) == 0
    assert main(["worker", "--queues", "control"]) == 0
    output = capsys.readouterr().err
    assert "pass-never-shown" not in output and "Redis redis://:***@worker-test" in output
    (cpu, cpu_env), (qpu, qpu_env), (control, _) = ran
    assert cpu[cpu.index("-Q") + 1] == "sa,exact" and cpu[cpu.index("-n") + 1].startswith("solver@")
    assert "DWAVE_API_TOKEN" not in cpu_env and qpu_env["DWAVE_API_TOKEN"] == "token-sentinel"
    assert qpu[qpu.index("-c") + 1] == "1"
    assert control[control.index("-c") + 1] == str(Settings().control_concurrency)
