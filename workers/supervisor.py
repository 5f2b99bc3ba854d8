"""Process supervision for ``qhsm serve`` / ``qhsm demo`` (and the service tests and benchmark):
Redis (embedded unless configured, see ``workers.embedded_redis``) plus a Celery worker
subprocess per kind of queue, restarted with backoff when one dies.

Everything started here gets a parent-death signal (Linux ``PR_SET_PDEATHSIG``), so it dies with
the process that started it even when that one is SIGKILLed. :class:`Supervisor` restarts a dead
worker or Redis with backoff. The HTTP side (the API's socket and uvicorn) is ``api.server``'s.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from shared.config import Settings
from shared.threads import thread_budget, thread_environment
from workers.embedded_redis import (
    EMBEDDED_URL_FILE,
    DataDirLock,
    EmbeddedRedis,
    safe_url,
    write_private,
)
from workers.process import die_with_parent, kill_now
from workers.redis_client import redis_url

log = logging.getLogger(__name__)

#: Environment variables only QPU / hybrid workers may see.
DWAVE_SECRETS = ("DWAVE_API_TOKEN", "DWAVE_API_REGION", "DWAVE_API_ENDPOINT", "DWAVE_SOLVER")


def worker_command(
    hostname: str, queues: list[str], concurrency: int, extra_args: list[str] | None = None
) -> list[str]:
    """``celery -A workers worker`` as serve, the tests and ``qhsm worker`` run it (prefork
    pool; liveness comes from workers/liveness.py, not Celery's gossip)."""
    return [
        sys.executable, "-m", "celery", "-A", "workers", "worker",
        "-Q", ",".join(queues),
        "-c", str(concurrency),
        "--pool", "prefork",
        "-n", hostname,
        "--loglevel", "INFO",
        "--without-gossip", "--without-mingle", "--without-heartbeat",
        *(extra_args or []),
    ]  # fmt: skip


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
    #: Threads per pool process for OpenCV, OpenMP/BLAS and numba (``shared.threads``); default:
    #: the cores shared among the ``concurrency`` processes.
    threads: int | None = None

    @property
    def hostname(self) -> str:
        return f"{self.name}@{socket.gethostname()}"

    def start(self) -> WorkerProcess:
        self.log_file.parent.mkdir(parents=True, exist_ok=True)
        command = worker_command(self.hostname, self.queues, self.concurrency, self.extra_args)
        threads = self.threads or thread_budget(self.concurrency, self.env)
        env = {**self.env, **thread_environment(threads, self.env)}
        with self.log_file.open("ab") as out:
            self.process = subprocess.Popen(
                command,
                env=env,
                stdout=out,
                stderr=subprocess.STDOUT,
                preexec_fn=die_with_parent,  # dies with serve, even on SIGKILL
                # a group of its own: a terminal's Ctrl-C is serve's, which stops the workers
                # then Redis (instead of each stopping itself and being restarted meanwhile)
                process_group=0,
            )
        return self

    @property
    def alive(self) -> bool:
        return self.process is not None and self.process.poll() is None

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
        stop_all([self], timeout)

    def terminate(self) -> bool:
        """Ask for a warm shutdown (SIGTERM: running tasks finish and are acked, messages it
        holds unstarted go back to their queues); False if the worker is not running."""
        if not self.alive:
            return False
        assert self.process is not None
        self.process.send_signal(signal.SIGTERM)
        return True

    def wait_until(self, deadline: float) -> bool:
        """Wait for the worker to exit until ``deadline`` (``time.monotonic``); whether it
        did."""
        assert self.process is not None
        try:
            self.process.wait(max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            return False
        return True

    def kill(self) -> None:
        """SIGKILL the pool processes (their tasks' messages stay unacked: the watchdog puts
        them back), then the main process; returns once it is gone."""
        assert self.process is not None
        for child in self.children():
            kill_now(child)
        self.process.kill()
        self.process.wait()


def stop_all(workers: list[WorkerProcess], timeout: float = 15.0) -> None:
    """Warm shutdown of every worker at once: all get SIGTERM first, then all are waited for
    with one deadline ``timeout`` s away, then whichever is still there is killed. Each worker
    finishes its own running tasks (no task waits for another: ``workers/orchestration.py``),
    so stopping them together loses nothing, and a stop takes the slowest worker's time
    instead of the sum."""
    stopping = [worker for worker in workers if worker.terminate()]
    deadline = time.monotonic() + timeout
    stuck = [worker for worker in stopping if not worker.wait_until(deadline)]
    for worker in stuck:
        worker.kill()


def stop_on_sigterm() -> None:
    """Turn SIGTERM into SystemExit so ``finally`` blocks stop the children we started."""
    if threading.current_thread() is threading.main_thread():

        def leave(signum: int, frame: object) -> None:
            raise SystemExit(128 + signum)

        signal.signal(signal.SIGTERM, leave)


def worker_env(settings: Settings, redis_url: str, *, dwave: bool) -> dict[str, str]:
    """The environment of a worker subprocess; the D-Wave token only where ``dwave``."""
    env = dict(os.environ)
    env["QHSM_REDIS_URL"] = redis_url
    env["QHSM_KEY_PREFIX"] = settings.key_prefix
    env["QHSM_DATA_DIR"] = str(settings.data_dir.resolve())
    env["QHSM_ROWS_PER_TASK"] = str(settings.rows_per_task)
    env["QHSM_SOLVER_ROWS_PER_TASK"] = json.dumps(settings.solver_rows_per_task)
    env["QHSM_CONTROL_QUEUE"] = settings.control_queue
    env["QHSM_PRICING_QUEUE"] = settings.pricing_queue
    if not dwave:
        for name in DWAVE_SECRETS:
            env.pop(name, None)
    return env


def wait_for_workers(
    celery, hostnames: list[str], timeout: float = 60.0, started: Sequence[WorkerProcess] = ()
) -> None:
    """Block until every named worker answers ``inspect active_queues`` (all of them booting
    at once, one deadline for all). A worker of ``started`` that exits meanwhile fails the
    wait at once, with the end of its log, instead of at the deadline."""
    deadline = time.monotonic() + timeout
    missing = set(hostnames)
    while time.monotonic() < deadline:
        replies = celery.control.inspect(timeout=0.5, destination=sorted(missing)).active_queues()
        missing -= set(replies or {})
        if not missing:
            return
        for worker in started:
            if worker.hostname in missing and not worker.alive:
                raise WorkerStartError(worker)
        time.sleep(0.2)
    raise RuntimeError(f"workers did not come up in {timeout:.0f} s: {sorted(missing)}")


class WorkerStartError(RuntimeError):
    """A worker exited before it was ready (an import error, a bad queue name, ...)."""

    def __init__(self, worker: WorkerProcess, lines: int = 20) -> None:
        assert worker.process is not None
        try:
            tail = worker.log_file.read_text(errors="replace").splitlines()[-lines:]
        except OSError:
            tail = []
        super().__init__(
            f"worker {worker.hostname} exited at start-up (exit code "
            f"{worker.process.returncode}); the end of {worker.log_file}:\n" + "\n".join(tail)
        )


@dataclass
class Supervisor:
    """Restarts a dead worker or embedded Redis, with exponential backoff, and logs it.

    Runs as a thread of the process that started them (it must outlive them: the parent-death
    signal follows the thread that forked). A process that stayed up ``STABLE_SECONDS`` gets
    its backoff reset."""

    stack: Stack
    poll: float = 0.5
    backoff: float = 1.0
    backoff_max: float = 60.0
    restarts: dict[str, int] = field(default_factory=dict)
    _stop: threading.Event = field(default_factory=threading.Event)
    _released: threading.Event = field(default_factory=threading.Event)
    _busy: threading.Lock = field(default_factory=threading.Lock)
    _thread: threading.Thread | None = None

    STABLE_SECONDS = 60.0

    def start(self) -> Supervisor:
        self._thread = threading.Thread(target=self._run, name="qhsm-supervisor", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop restarting (the thread stays: the processes it restarted die with it)."""
        self._stop.set()
        with self._busy:  # a restart under way finishes first
            pass

    def release(self) -> None:
        """End the thread, once what it restarted has been stopped."""
        self._stop.set()
        self._released.set()
        if self._thread is not None:
            self._thread.join(30)
            self._thread = None

    def _run(self) -> None:
        self._watch()
        self._released.wait()

    def _watch(self) -> None:
        due: dict[str, float] = {}  # name -> when to restart
        started: dict[str, float] = {}
        while not self._stop.wait(self.poll):
            with self._busy:
                if not self._stop.is_set():
                    self._check(due, started)

    def _check(self, due: dict[str, float], started: dict[str, float]) -> None:
        for name, alive, code, restart in self.stack.children():
            now = time.monotonic()
            if alive:
                if now - started.get(name, now) > self.STABLE_SECONDS:
                    self.restarts.pop(name, None)
                continue
            if name not in due:
                count = self.restarts.get(name, 0)
                delay = min(self.backoff * 2**count, self.backoff_max)
                log.warning(
                    "%s exited unexpectedly (exit code %s); restarting it in %.1f s",
                    name, code, delay,
                )  # fmt: skip
                due[name] = now + delay
            if now < due[name] or self._stop.is_set():
                continue
            del due[name]
            self.restarts[name] = self.restarts.get(name, 0) + 1
            try:
                restart()
            except Exception as error:
                log.error("could not restart %s: %s; trying again", name, error)
                continue
            started[name] = time.monotonic()
            log.warning("restarted %s (restart #%d)", name, self.restarts[name])


@dataclass
class Stack:
    """Redis (embedded unless configured) plus workers for every solver that runs here.

    A control worker consumes only the control queue (orchestration never waits behind solver
    work); a pricing worker (``max_concurrent_pricing`` processes) the pricing queue (estimates
    and metered jobs' pricing: the API never runs the matcher); one CPU worker consumes every
    locally available solver that does not spend QPU time; QPU/hybrid solvers get their own
    single-process worker, the only process that keeps the D-Wave token in its environment.
    With ``supervise`` a :class:`Supervisor` restarts any of them (or the embedded Redis) that
    dies.
    """

    settings: Settings
    concurrency: int | None = None
    redis: EmbeddedRedis | None = None
    workers: list[WorkerProcess] = field(default_factory=list)
    supervise: bool = True
    lock: DataDirLock | None = None
    supervisor: Supervisor | None = None

    def start(self, wait: bool = True) -> Stack:
        """Redis and every worker; with ``wait``, once all workers answer (else the supervisor
        restarts whichever dies while they boot)."""
        self.launch()
        if wait:
            self.wait_ready()
        elif self.supervise:
            self.supervisor = Supervisor(self).start()
        return self

    def launch(self) -> Stack:
        """Start Redis (when embedded) and every worker without waiting for the workers to
        boot (a few seconds of imports each, all at once): the caller builds what it needs
        meanwhile (``qhsm serve`` its API) and then calls :meth:`wait_ready`."""
        stop_on_sigterm()
        settings = self.settings
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        if settings.redis_url is None:
            self.lock = DataDirLock(settings.data_dir).acquire()
            self.redis = EmbeddedRedis(settings.data_dir / "redis").start()
            settings = self.settings = settings.model_copy(update={"redis_url": self.redis.url})
            # where `qhsm admin` finds the embedded Redis while it runs (with its password)
            write_private(settings.data_dir / EMBEDDED_URL_FILE, self.redis.url + "\n")
        from workers.queues import local_queues  # the registry: on start, not on import

        cpu, dwave = local_queues()
        logs = settings.data_dir / "logs"
        count = self.concurrency or settings.worker_concurrency or os.cpu_count() or 1
        url = redis_url(settings)  # the embedded one's when none is configured (set above)
        tag = os.getpid()
        cpu_env = worker_env(settings, url, dwave=False)
        # the processes that share this host's memory (shared.memory.worker_budget_mb)
        pricing = settings.max_concurrent_pricing
        processes = settings.control_concurrency + pricing + count + (1 if dwave else 0)
        cpu_env["QHSM_HOST_WORKER_PROCESSES"] = str(processes)
        self.workers.append(  # orchestration never waits behind solver work
            WorkerProcess(
                f"control-{tag}",
                [settings.control_queue],
                settings.control_concurrency,
                cpu_env,
                logs / "worker-control.log",
                # between the levels it runs alone (the solvers wait for it): every core
                threads=thread_budget(1, cpu_env),
            ).start()
        )
        self.workers.append(  # estimates and metered jobs' pricing: never in the API process
            WorkerProcess(
                f"pricing-{tag}",
                [settings.pricing_queue],
                pricing,
                cpu_env,
                logs / "worker-pricing.log",
            ).start()
        )
        self.workers.append(
            WorkerProcess(f"cpu-{tag}", cpu, count, cpu_env, logs / "worker-cpu.log").start()
        )
        if dwave:
            dwave_env = worker_env(settings, url, dwave=True)
            dwave_env["QHSM_HOST_WORKER_PROCESSES"] = str(processes)
            self.workers.append(
                WorkerProcess(
                    f"dwave-{tag}", dwave, 1, dwave_env, logs / "worker-dwave.log"
                ).start()
            )
        for name in DWAVE_SECRETS:  # the API process never needs the token
            os.environ.pop(name, None)
        self.settings = settings.model_copy(update={"dwave_api_token": None})
        return self

    def wait_ready(self, timeout: float = 60.0) -> Stack:
        """Wait for every launched worker with one shared deadline (``WorkerStartError`` at
        once if one exits meanwhile), then start the supervisor."""
        from workers.app import make_celery

        celery = make_celery(self.settings, with_tasks=False)
        hostnames = [worker.hostname for worker in self.workers]
        wait_for_workers(celery, hostnames, timeout, started=self.workers)
        if self.supervise:
            self.supervisor = Supervisor(self).start()
        return self

    def children(self) -> list[tuple[str, bool, int | None, Callable[[], object]]]:
        """(name, alive, exit code, restart) of every process this stack started."""
        rows: list[tuple[str, bool, int | None, Callable[[], object]]] = []
        if self.redis is not None:
            server = self.redis
            code = server.process.poll() if server.process else None
            rows.append(("embedded redis-server", server.alive, code, server.start))
        for worker in self.workers:
            code = worker.process.poll() if worker.process else None
            rows.append((f"worker {worker.hostname}", worker.alive, code, worker.start))
        return rows

    def describe(self) -> str:
        url = self.settings.redis_url or ""
        where = f"embedded, files in {self.redis.folder}" if self.redis else "configured"
        lines = [f"redis: {safe_url(url)} ({where})"]
        for worker in self.workers:
            lines.append(
                f"worker {worker.hostname}: queues {','.join(worker.queues)}, "
                f"{worker.concurrency} process(es), log {worker.log_file}"
            )
        return "\n".join(lines)

    def stop(self) -> None:
        if self.supervisor is not None:
            self.supervisor.stop()
        # every worker at once; Redis only after the last (a warm shutdown acks finished tasks'
        # messages and puts prefetched ones back in their queues, both in Redis)
        stop_all(self.workers)
        self.workers.clear()
        if self.redis:
            self.redis.stop()
            self.redis = None
            (self.settings.data_dir / EMBEDDED_URL_FILE).unlink(missing_ok=True)
        if self.supervisor is not None:
            self.supervisor.release()
            self.supervisor = None
        if self.lock is not None:
            self.lock.release()
            self.lock = None

    def __enter__(self) -> Stack:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
