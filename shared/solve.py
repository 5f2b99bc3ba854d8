"""Solving the bundles of one level: the unit of work a worker (or the in-process loop) runs.

``LevelInputs`` is everything needed to build any bundle of a level: the level's images and
candidate array. From a block of rows the worker computes the costs, encodes each bundle with the
configured codec, calls the solver adapter, decodes and repairs. A ``RowSolver`` (the exact DP)
skips the QUBO and works on the costs of the whole block at once.
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from functools import partial
from multiprocessing import get_context

import numpy as np

from shared.bundles import bundle_rows, bundle_seed
from shared.config import LevelConfig, MatchConfig
from shared.encodings import get_codec
from shared.energy import Costs, level_costs, mrf_energy
from shared.solvers import get_solver
from shared.solvers.base import RowSolver

#: Parameters in ``MatchConfig.solver_params`` that steer this module, not the solver.
PIPELINE_PARAMS = {"warm_start"}


@dataclass
class LevelInputs:
    """A level's images (float32, level resolution) and candidates (h, w, K) int32.

    ``initial_labels`` (h, w) is the coarser level's estimate expressed as labels, used for warm
    starts; ``None`` on the coarsest level.
    """

    index: int
    level: LevelConfig
    left: np.ndarray
    right: np.ndarray
    candidates: np.ndarray
    initial_labels: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return self.left.shape

    def costs(self, config: MatchConfig, start: int = 0, stop: int | None = None) -> Costs:
        """Costs of rows [start, stop) (the right image is only ever read on the same rows)."""
        rows = slice(start, stop)
        return level_costs(
            self.left[rows], self.right[rows], self.candidates[rows], self.level, config.regularizer
        )


@dataclass
class BundleResult:
    """Labels (rows, w) of one bundle with its MRF energy and the solver's report."""

    row_start: int
    row_stop: int
    labels: np.ndarray
    energy: float
    repaired: int
    wall_time: float
    timing: dict[str, float] = field(default_factory=dict)
    info: dict = field(default_factory=dict)


@dataclass
class LevelSolution:
    """All bundles of a level put back together."""

    labels: np.ndarray
    energy: float
    repaired: int
    bundles: int
    solver_seconds: float
    timing: dict[str, float] = field(default_factory=dict)


def solve_bundles(
    inputs: LevelInputs, config: MatchConfig, row_ranges: list[tuple[int, int]]
) -> list[BundleResult]:
    """Solve the given bundles (row ranges) of a level with ``config.solver``."""
    if not row_ranges:
        return []
    solver = get_solver(config.solver)
    if isinstance(solver, RowSolver):
        return _solve_on_costs(solver, inputs, config, row_ranges)
    codec = get_codec(config.encoding)
    params = {k: v for k, v in config.solver_params.items() if k not in PIPELINE_PARAMS}
    warm = bool(config.solver_params.get("warm_start")) and inputs.initial_labels is not None
    results = []
    for start, stop in row_ranges:
        costs = inputs.costs(config, start, stop)
        bqm = codec.encode(costs, config.rectifier)
        initial = (
            codec.encode_labels(inputs.initial_labels[start:stop], costs.num_labels)
            if warm
            else None
        )
        outcome = solver.solve(
            bqm, seed=bundle_seed(config.seed, inputs.index, start), initial_state=initial, **params
        )
        decoded = codec.decode(costs, outcome.sample)
        results.append(
            BundleResult(
                row_start=start,
                row_stop=stop,
                labels=decoded.labels,
                energy=mrf_energy(costs, decoded.labels),
                repaired=decoded.repaired,
                wall_time=outcome.wall_time,
                timing=outcome.timing,
                info=outcome.info,
            )
        )
    return results


def _solve_on_costs(
    solver: RowSolver, inputs: LevelInputs, config: MatchConfig, row_ranges: list[tuple[int, int]]
) -> list[BundleResult]:
    """A row solver on the smallest block of rows covering ``row_ranges``, all rows at once."""
    started = time.perf_counter()
    first, last = min(r[0] for r in row_ranges), max(r[1] for r in row_ranges)
    costs = inputs.costs(config, first, last)
    labels = solver.solve_rows(costs, config.bundle_height)
    share = (time.perf_counter() - started) / len(row_ranges)
    results = []
    for start, stop in row_ranges:
        rows = costs.rows(start - first, stop - first)
        bundle_labels = labels[start - first : stop - first]
        results.append(
            BundleResult(
                row_start=start,
                row_stop=stop,
                labels=bundle_labels,
                energy=mrf_energy(rows, bundle_labels),
                repaired=0,
                wall_time=share,
            )
        )
    return results


def assemble(inputs: LevelInputs, results: list[BundleResult]) -> LevelSolution:
    """Put bundle results back into one label map; every row must be covered exactly once."""
    height, width = inputs.shape
    labels = np.full((height, width), -1, dtype=np.int32)
    covered = np.zeros(height, dtype=np.int32)
    timing: dict[str, float] = {}
    results = sorted(results, key=lambda r: r.row_start)  # sums independent of arrival order
    for result in results:
        labels[result.row_start : result.row_stop] = result.labels
        covered[result.row_start : result.row_stop] += 1
        for key, value in result.timing.items():
            timing[key] = timing.get(key, 0.0) + float(value)
    if not np.all(covered == 1):
        missing = np.flatnonzero(covered == 0).tolist()
        doubled = np.flatnonzero(covered > 1).tolist()
        raise ValueError(
            f"level {inputs.index}: rows missing {missing[:10]}, rows solved twice {doubled[:10]}"
        )
    return LevelSolution(
        labels=labels,
        energy=float(sum(r.energy for r in results)),
        repaired=int(sum(r.repaired for r in results)),
        bundles=len(results),
        solver_seconds=float(sum(r.wall_time for r in results)),
        timing=timing,
    )


def solve_level_in_process(inputs: LevelInputs, config: MatchConfig) -> LevelSolution:
    """The in-process ``solve_level``: every bundle of the level, one after another."""
    rows = bundle_rows(inputs.shape[0], config.bundle_height)
    return assemble(inputs, solve_bundles(inputs, config, rows))


class ProcessPoolLevelSolver:
    """A ``solve_level`` that spreads a level's bundles over local worker processes.

    Bundles are independent and seeded by position, so the result equals the sequential one.
    Row solvers (the exact DP) are vectorised over rows already and run in this process. Use as a
    context manager so the pool lives across levels.
    """

    def __init__(self, processes: int | None = None) -> None:
        self.processes = processes or os.cpu_count() or 1
        self._pool: ProcessPoolExecutor | None = None

    def __enter__(self) -> ProcessPoolLevelSolver:
        if self.processes > 1:
            # spawn, not fork: forking a process that already runs threads (OpenBLAS, OpenCV,
            # an HTTP client) can deadlock the children. Solvers come from the registry's
            # importable factories, so every child sees the same adapters.
            self._pool = ProcessPoolExecutor(self.processes, mp_context=get_context("spawn"))
        return self

    def __exit__(self, *exc_info: object) -> None:
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
            self._pool = None

    def __call__(self, inputs: LevelInputs, config: MatchConfig) -> LevelSolution:
        if self._pool is None or isinstance(get_solver(config.solver), RowSolver):
            return solve_level_in_process(inputs, config)
        rows = bundle_rows(inputs.shape[0], config.bundle_height)
        chunks = [rows[i :: self.processes * 4] for i in range(self.processes * 4)]
        solve = partial(solve_bundles, inputs, config)
        results = [r for chunk in self._pool.map(solve, [c for c in chunks if c]) for r in chunk]
        return assemble(inputs, results)
