"""Fake solvers for the service tests, registered through the ``qhsm.solvers`` entry-point
group: ``qhsm_test_plugin-0.dist-info`` beside this file names each class under its solver name
(a sampler factory, registered under the entry point's name: the name is stated there only), so
any process with this folder on ``sys.path`` / ``PYTHONPATH`` (the API and workers of the tests)
finds them.

They return the all-zero sample, which every codec decodes by repair to the cheapest label
given no valid neighbour: deterministic, so distributed and in-process runs can be compared.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import dimod
import numpy as np

from shared.solvers import Availability, Sampler, SolverError, TransientSolverError


class Fake(Sampler):
    parameters: dict[str, list] = {"seed": []}  # noqa: RUF012
    properties: dict[str, Any] = {}  # noqa: RUF012

    def available(self) -> Availability:
        return Availability(True, "test fake")

    def run(self, bqm, params: dict[str, Any], *, seed, initial_states) -> dimod.SampleSet:
        self.act(seed)
        zeros = np.zeros((1, bqm.num_variables), dtype=np.int8)
        info = {"timing": {"fake_access_time": 0.001}}
        return dimod.SampleSet.from_samples_bqm((zeros, range(bqm.num_variables)), bqm, info=info)

    def act(self, seed: int | None) -> None:
        pass


class Slow(Fake):
    """Sleeps per bundle; while solving, a file named after the process id marks it busy."""

    def act(self, seed: int | None) -> None:
        seconds = float(os.environ.get("QHSM_TEST_SLOW_SECONDS", "0"))
        markers = os.environ.get("QHSM_TEST_MARKERS")
        marker = Path(markers) / f"busy-{os.getpid()}" if markers else None
        if marker:
            marker.write_text(str(os.getpid()))
        try:
            time.sleep(seconds)
        finally:
            if marker:
                marker.unlink(missing_ok=True)


class Flaky(Fake):
    """Fails once per bundle seed with a transient error, then succeeds."""

    def act(self, seed: int | None) -> None:
        marker = Path(os.environ["QHSM_TEST_MARKERS"]) / f"flaky-{seed}"
        if not marker.exists():
            marker.write_text("failed once")
            raise TransientSolverError("fake-flaky: rate limited, try again later")


class Broken(Fake):
    def act(self, seed: int | None) -> None:
        raise SolverError("fake-broken: the device is on fire; use another solver")


class Sleepy(Fake):
    """Sleeps far longer than its task's time limit (interruptible: the soft limit stops it)."""

    def act(self, seed: int | None) -> None:
        time.sleep(600)


class Hung(Fake):
    """Like a solver stuck in native code: swallows the soft time limit and keeps going."""

    def act(self, seed: int | None) -> None:
        deadline = time.monotonic() + 600
        while time.monotonic() < deadline:
            try:
                time.sleep(600)
            except Exception:  # SoftTimeLimitExceeded
                continue


class Split(Fake):
    """The first bundle ever sleeps (a busy marker names its process); every later one fails
    after a second: a job that fails while another of its tasks still runs."""

    def act(self, seed: int | None) -> None:
        markers = Path(os.environ["QHSM_TEST_MARKERS"])
        first = markers / "split-first"
        try:
            first.touch(exist_ok=False)
        except FileExistsError:
            time.sleep(1)
            raise SolverError("fake-split: this bundle fails") from None
        (markers / f"split-busy-{os.getpid()}").write_text("sleeping")
        time.sleep(600)


class Hog(Fake):
    """Allocates and touches more memory than the test workers' ceiling (2 GiB, well within
    the machine's): only ``QHSM_TASK_MEMORY_LIMIT_MB`` stops it."""

    def act(self, seed: int | None) -> None:
        hog = np.ones(2 * 2**30 // 8)
        hog[-1] = seed or 0


class Unavailable(Fake):
    def available(self) -> Availability:
        return Availability(False, "fake-unavailable needs hardware this machine lacks")
