"""Where the pipeline variants run: in this process (a process pool) or through a service.

Remote runs (``--url``): ``shared`` does not import HTTP code; the service package provides a
*runner* in the entry-point group ``qhsm.runners`` under the name ``http`` (see
:mod:`shared.bench` for its contract). The baselines always run in this process.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, Protocol
from urllib.parse import urlsplit

import numpy as np

from shared.bench.experiments import BenchError
from shared.config import MatchConfig
from shared.datasets import Scene

RUNNER_GROUP = "qhsm.runners"


@dataclass
class RunOutput:
    """What running one scene produced: full-resolution disparity (px) and per-level reports."""

    disparity: np.ndarray
    seconds: float
    levels: list[dict] = field(default_factory=list)
    info: dict = field(default_factory=dict)


class RemoteRunner(Protocol):
    """Entry point ``qhsm.runners:http``: run one scene through the service at ``url``."""

    def __call__(self, left: Path, right: Path, config: MatchConfig, url: str) -> Any: ...


SceneRunner = Callable[[Scene, np.ndarray, np.ndarray, MatchConfig], RunOutput]


def local_runner(processes: int = 0) -> SceneRunner:
    """Run the one pipeline here.

    Parameters
    ----------
    processes
        1: in this process; else a local process pool of that many processes (0: one per core).

    Returns
    -------
    SceneRunner
        ``run(scene, left, right, config) -> RunOutput``.
    """
    from shared.pipeline import run_pipeline

    def run(scene: Scene, left: np.ndarray, right: np.ndarray, config: MatchConfig) -> RunOutput:
        if processes != 1:
            from shared.process_pool import ProcessPoolLevelSolver

            with ProcessPoolLevelSolver(processes) as solve_level:
                result = run_pipeline(left, right, config, solve_level)
        else:
            result = run_pipeline(left, right, config)
        summary = result.summary()
        return RunOutput(
            result.disparity,
            result.seconds,
            summary["levels"],
            info={"disparity_range": summary["disparity_range"]},
        )

    return run


def remote_runner(url: str) -> SceneRunner:
    """Resolve the service's runner from the ``qhsm.runners`` entry points.

    Parameters
    ----------
    url
        The service's http(s) URL.

    Returns
    -------
    SceneRunner
        ``run(scene, left, right, config) -> RunOutput``, timed here unless the runner says.
    """
    scheme = urlsplit(url).scheme.lower()
    if scheme not in ("http", "https"):
        raise BenchError(f"--url must be an http(s) URL, got {url!r}")
    found = entry_points(group=RUNNER_GROUP, name="http")
    if not found:
        raise BenchError(
            "--url needs the service package installed: no 'http' runner is registered in the "
            f"entry-point group {RUNNER_GROUP!r} (pip install -e . in the repository)"
        )
    runner: RemoteRunner = next(iter(found)).load()

    def run(scene: Scene, left: np.ndarray, right: np.ndarray, config: MatchConfig) -> RunOutput:
        started = time.perf_counter()
        outcome = runner(scene.left, scene.right, config, url)
        return _as_output(outcome, time.perf_counter() - started)

    return run


def _as_output(outcome: Any, elapsed: float) -> RunOutput:
    """Accept the runner return shapes documented in :mod:`shared.bench`."""
    if isinstance(outcome, RunOutput):
        return outcome
    if isinstance(outcome, tuple):
        disparity, levels = outcome
        return RunOutput(np.asarray(disparity, np.float32), elapsed, list(levels))
    levels = getattr(outcome, "levels", [])
    levels = [level if isinstance(level, dict) else asdict(level) for level in levels]
    seconds = getattr(outcome, "seconds", None)
    return RunOutput(
        np.asarray(outcome.disparity, np.float32), elapsed if seconds is None else seconds, levels
    )
