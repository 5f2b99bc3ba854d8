"""Fixtures shared by every test package: synthetic scenes, the optional Middlebury data, the
Redis the user, API and service tests share (one per session, each test under its own key
prefix), a temporary data directory, and Ctrl-C as a terminal sends it."""

from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import redis

from shared.datasets import default_middlebury_dir, load_scene
from shared.energy import Costs
from shared.synthetic import SyntheticScene, make_scene

_TEMPORARY_DATA_DIR: str | None = None
#: Set by pytest-xdist in each of its worker processes (gw0, gw1, ...); absent in a plain run.
XDIST_WORKER_ENV = "PYTEST_XDIST_WORKER"


def pytest_configure(config) -> None:
    """Nothing a test runs writes to the user's own data folder (the default QHSM_DATA_DIR):
    unless QHSM_DATA_DIR is set, it is a temporary folder (subprocesses inherit it), removed at
    the end. Under pytest-xdist the controller makes it and each worker takes a folder of its
    own inside it (``gw0``, ...): two workers' ``qhsm serve`` or embedding store never share
    a data directory, its lock or its embedded Redis."""
    global _TEMPORARY_DATA_DIR
    # nor does a `qhsm match` run in a terminal (`pytest -s`) build kernels in the user's cache
    os.environ.setdefault("QHSM_BUILD_KERNELS", "never")
    worker = os.environ.get(XDIST_WORKER_ENV)
    if worker:
        own = Path(os.environ["QHSM_DATA_DIR"]) / worker
        own.mkdir(parents=True, exist_ok=True)
        os.environ["QHSM_DATA_DIR"] = str(own)
    elif "QHSM_DATA_DIR" not in os.environ:
        import tempfile

        _TEMPORARY_DATA_DIR = tempfile.mkdtemp(prefix="qhsm-test-data-")
        os.environ["QHSM_DATA_DIR"] = _TEMPORARY_DATA_DIR


def pytest_unconfigure(config) -> None:
    if _TEMPORARY_DATA_DIR is not None:
        import shutil

        shutil.rmtree(_TEMPORARY_DATA_DIR, ignore_errors=True)


@pytest.fixture(scope="session")
def scene() -> SyntheticScene:
    """A 96x128 scene with a slanted background and two layers (disparities up to 16)."""
    return make_scene(96, 128, max_disparity=16, seed=0)


@pytest.fixture(scope="session")
def middlebury_dir():
    folder = default_middlebury_dir()
    if not folder.is_dir():
        pytest.skip(f"Middlebury data not found at {folder} (set QHSM_MIDDLEBURY_DIR to use it)")
    return folder


@pytest.fixture(scope="session")
def tsukuba(middlebury_dir):
    return load_scene(middlebury_dir / "tsukuba")


def _random_costs(rng: np.random.Generator, height: int, width: int, labels: int) -> Costs:
    return Costs(
        candidates=np.broadcast_to(np.arange(labels, dtype=np.int32), (height, width, labels)),
        unary=rng.random((height, width, labels)),
        pair_h=rng.random((height, max(width - 1, 0), labels, labels)),
        pair_v=rng.random((max(height - 1, 0), width, labels, labels)),
    )


@pytest.fixture(scope="session")
def random_costs():
    """Factory: non-negative random MRF costs (the regime the rectifier proofs cover)."""
    return _random_costs


#: Environment variable choosing the tests' Redis: a URL, or ``embedded``.
TEST_REDIS_ENV = "QHSM_TEST_REDIS_URL"
#: The value of :data:`TEST_REDIS_ENV` that asks for the embedded redis-server.
EMBEDDED = "embedded"
#: The local Redis of a development machine or CI, in a database of the tests' own.
LOCAL_REDIS = "redis://127.0.0.1:6379/13"


@dataclass(frozen=True)
class RedisChoice:
    """Which Redis the tests use: ``url`` (None: start the embedded one), or ``error``."""

    url: str | None
    reason: str
    error: str | None = None


_REDIS_CHOICE = pytest.StashKey[RedisChoice]()


def _why_not(url: str) -> str | None:
    """None when a Redis answers at ``url``, else why not."""
    try:
        redis.Redis.from_url(url, socket_connect_timeout=0.5, socket_timeout=2).ping()
    except redis.RedisError as error:
        return f"{type(error).__name__}: {error}"
    return None


#: Key of :class:`RedisChoice` in pytest-xdist's ``workerinput``: the controller's choice.
_WORKER_INPUT_KEY = "qhsm_test_redis"


def _redis_choice(config: pytest.Config) -> RedisChoice:
    """Decided once per session: ``QHSM_TEST_REDIS_URL`` when set (a URL that must answer, or
    ``embedded``), else the local Redis when it answers, else the embedded redis-server (a
    laptop without Redis). Under pytest-xdist the controller decides and its workers take its
    choice (:func:`pytest_configure_node`), so the header it prints names what they use."""
    if _REDIS_CHOICE not in config.stash:
        given = getattr(config, "workerinput", {}).get(_WORKER_INPUT_KEY)
        config.stash[_REDIS_CHOICE] = (
            RedisChoice(**given)
            if given is not None
            else _choose_redis(os.environ.get(TEST_REDIS_ENV, "").strip())
        )
    return config.stash[_REDIS_CHOICE]


@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node) -> None:
    """pytest-xdist, in the controller, for each worker it starts: pass the Redis choice on.
    An embedded choice (``url`` None) means a redis-server per worker (:func:`redis_url`)."""
    choice = _redis_choice(node.config)
    node.workerinput[_WORKER_INPUT_KEY] = dataclasses.asdict(choice)


def _choose_redis(wanted: str) -> RedisChoice:
    from workers.embedded_redis import safe_url

    if wanted.lower() == EMBEDDED:
        return RedisChoice(None, f"embedded redis-server ({TEST_REDIS_ENV}={EMBEDDED})")
    if wanted:
        shown = f"{safe_url(wanted)} (from {TEST_REDIS_ENV})"
        error = _why_not(wanted)
        if error is None:
            return RedisChoice(wanted, shown)
        return RedisChoice(
            None,
            shown,
            f"{TEST_REDIS_ENV}={safe_url(wanted)} does not answer ({error}): start that Redis, "
            f"set {TEST_REDIS_ENV}={EMBEDDED}, or unset it (the local Redis if it answers, else "
            "the embedded one)",
        )
    if _why_not(LOCAL_REDIS) is None:
        return RedisChoice(LOCAL_REDIS, f"{LOCAL_REDIS} (the local Redis answered)")
    return RedisChoice(None, f"embedded redis-server (nothing answers at {LOCAL_REDIS})")


def pytest_report_header(config: pytest.Config) -> str:
    choice = _redis_choice(config)
    return f"tests' Redis: {choice.error or choice.reason}"


@pytest.fixture(scope="session")
def redis_url(request, tmp_path_factory) -> Iterator[str]:
    """The URL of the tests' Redis (:func:`_redis_choice`). When that is the embedded
    redis-server, one is started for the session, as ``qhsm serve`` starts its own (a free
    127.0.0.1 port, a password)."""
    choice = _redis_choice(request.config)
    if choice.error is not None:
        if os.environ.get(XDIST_WORKER_ENV):  # pytest.exit in a worker: xdist's INTERNALERROR
            pytest.fail(choice.error, pytrace=False)
        pytest.exit(choice.error, returncode=pytest.ExitCode.USAGE_ERROR)
    if choice.url is not None:
        yield choice.url
        return
    from workers.embedded_redis import EmbeddedRedis

    server = EmbeddedRedis(tmp_path_factory.mktemp("redis")).start()
    try:
        yield server.url
    finally:
        server.stop()


@dataclass
class Interrupted:
    """A command that got Ctrl-C: its exit status and what it wrote."""

    returncode: int
    stdout: str
    stderr: str
    #: Whether any process of its group was still there 5 s after it exited.
    left_processes: bool = False

    @property
    def last_line(self) -> str:
        """The last line on stderr (progress bars redraw with carriage returns)."""
        return self.stderr.replace("\r", "\n").strip().splitlines()[-1]


def press_ctrl_c(command: list[str], when: str, timeout: float = 120.0, **popen) -> Interrupted:
    """Run ``command`` in its own process group, as a terminal runs a foreground job, and send
    SIGINT to the whole group (what Ctrl-C does) once ``when`` appears on its stderr."""
    process = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        process_group=0,
        preexec_fn=_foreground_signals,
        **popen,
    )
    assert process.stderr is not None
    os.set_blocking(process.stderr.fileno(), False)
    seen = b""
    deadline = time.monotonic() + timeout
    try:
        while when.encode() not in seen:
            if process.poll() is not None or time.monotonic() > deadline:
                raise AssertionError(f"{when!r} never appeared on stderr: {seen.decode()[-2000:]}")
            seen += process.stderr.read() or b""
            time.sleep(0.05)
        os.killpg(process.pid, signal.SIGINT)
        os.set_blocking(process.stderr.fileno(), True)
        out, err = process.communicate(timeout=timeout)
        gone = time.monotonic() + 5.0  # multiprocessing's resource tracker exits after it
        while (left := _group_alive(process.pid)) and time.monotonic() < gone:
            time.sleep(0.1)
    finally:
        if process.poll() is None or _group_alive(process.pid):
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    return Interrupted(process.returncode, out.decode(), (seen + err).decode(), left)


def _foreground_signals() -> None:
    """In the child, before it runs: SIGINT as a shell leaves it for a foreground job, its
    default action and not blocked, whatever this test process (its threads: Celery's, the
    API's) had when it forked."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGINT])


def _group_alive(group: int) -> bool:
    try:
        os.killpg(group, 0)
    except ProcessLookupError:
        return False
    return True


@pytest.fixture(scope="session")
def ctrl_c():
    """:func:`press_ctrl_c`."""
    return press_ctrl_c
