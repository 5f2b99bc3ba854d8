"""The one pipeline: coarse-to-fine MRF stereo over a spatial pyramid.

    for each level k (coarse to fine):
        prepare_level   downsample, candidates (from level k-1), warm-start labels
        solve_level     injected: in process (CLI, tests) or a Celery fan-out (service)
        finish_level    labels -> disparities, median filter
    finish              upsample to full resolution, bilateral filter

``run_pipeline`` runs the loop synchronously. The service calls the same three functions from
its fan-in callbacks, so the level logic lives only here.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import numpy as np

from shared import filters, pyramid
from shared.config import MatchConfig
from shared.images import check_pair
from shared.solve import LevelInputs, LevelSolution, solve_level_in_process

SolveLevel = Callable[[LevelInputs, MatchConfig], LevelSolution]
Progress = Callable[[int, int], None]


@dataclass
class LevelReport:
    """What one level did, for the CLI's ``--json`` and the job status."""

    index: int
    downsample: int
    height: int
    width: int
    candidates: int
    bundles: int
    energy: float
    repaired: int
    seconds: float
    solver_seconds: float
    timing: dict[str, float] = field(default_factory=dict)


@dataclass
class MatchResult:
    """Full-resolution left-view disparity (float32, pixels) and per-level reports."""

    disparity: np.ndarray
    levels: list[LevelReport]
    seconds: float

    def summary(self) -> dict:
        return {"seconds": self.seconds, "levels": [asdict(level) for level in self.levels]}


def prepare_level(
    left: np.ndarray,
    right: np.ndarray,
    config: MatchConfig,
    index: int,
    previous: np.ndarray | None = None,
) -> LevelInputs:
    """Inputs of level ``index``; ``previous`` is level ``index - 1``'s filtered disparity."""
    level = config.levels[index]
    left_k = pyramid.downsample(left, level.downsample)
    right_k = pyramid.downsample(right, level.downsample)
    max_k = pyramid.level_max_disparity(config.max_disparity, level.downsample)
    if previous is None:
        candidates = pyramid.initial_candidates(left_k.shape, level.candidates, max_k)
        initial = None
    else:
        candidates = pyramid.refined_candidates(previous, left_k.shape, level.candidates, max_k)
        target = pyramid.upsample_disparity(previous, left_k.shape)
        initial = np.abs(candidates - target[:, :, None]).argmin(axis=2).astype(np.int32)
    return LevelInputs(
        index=index,
        level=level,
        left=left_k,
        right=right_k,
        candidates=candidates,
        initial_labels=initial,
    )


def finish_level(inputs: LevelInputs, solution: LevelSolution, config: MatchConfig) -> np.ndarray:
    """The level's disparity map (level pixels) from its labels, median-filtered if enabled."""
    picked = np.take_along_axis(inputs.candidates, solution.labels[:, :, None], axis=2)[:, :, 0]
    disparity = picked.astype(np.float32)
    if config.median:
        disparity = filters.median(disparity, config.median_size)
    return disparity


def finish(disparity: np.ndarray, shape: tuple[int, int], config: MatchConfig) -> np.ndarray:
    """Full-resolution result: scale to ``shape`` if the last level is coarser, then bilateral."""
    if disparity.shape != shape:
        disparity = pyramid.upsample_disparity(disparity, shape)
    if config.bilateral:
        disparity = filters.bilateral(
            disparity,
            config.bilateral_diameter,
            config.bilateral_sigma_color,
            config.bilateral_sigma_space,
        )
    return disparity.astype(np.float32)


def report(inputs: LevelInputs, solution: LevelSolution, seconds: float) -> LevelReport:
    height, width = inputs.shape
    return LevelReport(
        index=inputs.index,
        downsample=inputs.level.downsample,
        height=height,
        width=width,
        candidates=inputs.level.candidates,
        bundles=solution.bundles,
        energy=solution.energy,
        repaired=solution.repaired,
        seconds=seconds,
        solver_seconds=solution.solver_seconds,
        timing=solution.timing,
    )


def run_pipeline(
    left: np.ndarray,
    right: np.ndarray,
    config: MatchConfig,
    solve_level: SolveLevel = solve_level_in_process,
    progress: Progress | None = None,
) -> MatchResult:
    """Match a rectified pair (float32 gray in [0, 1]); returns the left view's disparity."""
    check_pair(left, right)
    started = time.perf_counter()
    reports: list[LevelReport] = []
    disparity: np.ndarray | None = None
    for index in range(len(config.levels)):
        level_started = time.perf_counter()
        inputs = prepare_level(left, right, config, index, disparity)
        solution = solve_level(inputs, config)
        disparity = finish_level(inputs, solution, config)
        reports.append(report(inputs, solution, time.perf_counter() - level_started))
        if progress is not None:
            progress(index + 1, len(config.levels))
    assert disparity is not None  # levels has at least one entry (validated)
    result = finish(disparity, left.shape, config)
    return MatchResult(disparity=result, levels=reports, seconds=time.perf_counter() - started)
