"""Fixtures shared by every test package: synthetic scenes and the optional Middlebury data."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from dataclasses import dataclass

import numpy as np
import pytest

from shared.datasets import default_middlebury_dir, load_scene
from shared.energy import Costs
from shared.synthetic import SyntheticScene, make_scene

_TEMPORARY_DATA_DIR: str | None = None


def pytest_configure(config) -> None:
    """Nothing a test runs writes to the user's own data folder (the default QHSM_DATA_DIR):
    unless QHSM_DATA_DIR is set, it is a temporary folder (subprocesses inherit it), removed at
    the end."""
    global _TEMPORARY_DATA_DIR
    if "QHSM_DATA_DIR" not in os.environ:
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
