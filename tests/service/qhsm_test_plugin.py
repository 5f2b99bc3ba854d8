"""Fake solvers for the service tests, loaded by workers and the API through QHSM_PLUGINS.

They return the all-zero sample, which every codec decodes by repair to the cheapest label
given no valid neighbour: deterministic, so distributed and in-process runs can be compared.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from shared.solvers import Availability, SolverError, SolveResult, TransientSolverError, register


class _Fake:
    description = "test fake"
    offline = True
    uses_qpu_time = False

    def __init__(self, name: str):
        self.name = name

    def available(self) -> Availability:
        return Availability(True, "test fake")

    def solve(self, bqm, *, seed=None, initial_state=None, **params: Any) -> SolveResult:
        started = time.perf_counter()
        self.act(seed)
        sample = np.zeros(bqm.num_variables, dtype=np.int8)
        return SolveResult(
            sample=sample,
            energy=float(bqm.energy(sample)),
            wall_time=time.perf_counter() - started,
            timing={"fake_access_time": 0.001},
        )

    def act(self, seed: int | None) -> None:
        pass


class _Slow(_Fake):
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


class _Flaky(_Fake):
    """Fails once per bundle seed with a transient error, then succeeds."""

    def act(self, seed: int | None) -> None:
        marker = Path(os.environ["QHSM_TEST_MARKERS"]) / f"flaky-{seed}"
        if not marker.exists():
            marker.write_text("failed once")
            raise TransientSolverError("fake-flaky: rate limited, try again later")


class _Broken(_Fake):
    def act(self, seed: int | None) -> None:
        raise SolverError("fake-broken: the device is on fire; use another solver")


class _Sleepy(_Fake):
    """Sleeps far longer than its task's time limit (interruptible: the soft limit stops it)."""

    def act(self, seed: int | None) -> None:
        time.sleep(600)


class _Hung(_Fake):
    """Like a solver stuck in native code: swallows the soft time limit and keeps going."""

    def act(self, seed: int | None) -> None:
        deadline = time.monotonic() + 600
        while time.monotonic() < deadline:
            try:
                time.sleep(600)
            except Exception:  # SoftTimeLimitExceeded
                continue


class _Split(_Fake):
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


class _Unavailable(_Fake):
    def available(self) -> Availability:
        return Availability(False, "fake-unavailable needs hardware this machine lacks")


register("fake-slow", lambda: _Slow("fake-slow"))
register("fake-flaky", lambda: _Flaky("fake-flaky"))
register("fake-broken", lambda: _Broken("fake-broken"))
register("fake-routed", lambda: _Fake("fake-routed"))
register("fake-sleepy", lambda: _Sleepy("fake-sleepy"))
register("fake-hung", lambda: _Hung("fake-hung"))
register("fake-split", lambda: _Split("fake-split"))
register("fake-unavailable", lambda: _Unavailable("fake-unavailable"))
