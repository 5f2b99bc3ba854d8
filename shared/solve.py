"""Solving the bundles of one level: the unit of work a worker (or the in-process loop) runs.

``LevelInputs`` is everything needed to build any bundle of a level: the level's images and
candidate array. From a block of rows the worker computes the costs, encodes each bundle with the
configured codec, calls the solver adapter, decodes and repairs. A ``RowSolver`` (the exact DP)
skips the QUBO and works on the costs of blocks of rows.
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from functools import partial
from multiprocessing import get_context

import numpy as np

from shared.bundles import bundle_rows, bundle_seed
from shared.config import DataTerm, LevelConfig, MatchConfig
from shared.data_terms import (
    ad_census_volume,
    bin_minimum,
    gather,
    squared_difference,
    squared_volume,
)
from shared.encodings import get_codec
from shared.energy import Costs, mrf_costs, mrf_energy, row_energies
from shared.images import to_gray
from shared.pyramid import LevelPlan
from shared.solvers import get_solver
from shared.solvers.base import RowSolver, uses_warm_start

#: Parameters in ``MatchConfig.solver_params`` that steer this module, not the solver.
PIPELINE_PARAMS = {"warm_start"}

#: A row solver takes as many rows at once as keep one block's pairwise cost arrays (float64,
#: horizontal and vertical, K x K per pixel) within this: large enough to vectorise, small
#: enough that memory is bounded by the block, not by the image.
COST_BLOCK_BYTES = 64 * 2**20


@dataclass
class LevelInputs:
    """Everything needed to build any bundle of a level.

    ``left`` / ``right`` are the level's images (float32 in [0, 1], gray or BGR colour) and
    ``candidates`` (rows, w, K) int32 the labels each pixel may take. With ``views`` = 2 the
    arrays hold two matching problems one below the other: rows [0, h) are the left view's,
    rows [h, 2h) the right view's as the mirrored pair (both images flipped, roles swapped).
    Bundles, tasks and progress therefore treat the right view as more rows of the same level;
    costs never mix the two. ``initial_labels`` (rows, w) is the coarser level's estimate as
    labels, for warm starts; ``None`` on the coarsest level.
    """

    plan: LevelPlan
    left: np.ndarray
    right: np.ndarray
    candidates: np.ndarray
    initial_labels: np.ndarray | None = None
    views: int = 1
    #: Optional per-view full cost volumes (in process only; workers build costs per block).
    volumes: list[np.ndarray] | None = None
    _binned: list[np.ndarray] | None = field(default=None, init=False, repr=False)

    @property
    def index(self) -> int:
        return self.plan.index

    @property
    def level(self) -> LevelConfig:
        return self.plan.mrf

    @property
    def shape(self) -> tuple[int, int]:
        """(rows of all views, width)."""
        return self.left.shape[0], self.left.shape[1]

    @property
    def view_height(self) -> int:
        return self.left.shape[0] // self.views

    def view_parts(self, start: int, stop: int) -> list[tuple[int, int, int]]:
        """Rows [start, stop) split by view, as (view, first row, stop row) in view rows."""
        parts = []
        height = self.view_height
        for view in range(self.views):
            first, last = max(start, view * height), min(stop, (view + 1) * height)
            if first < last:
                parts.append((view, first - view * height, last - view * height))
        return parts

    def starting_labels(self, costs: Costs, start: int, stop: int) -> np.ndarray:
        """A warm start for rows [start, stop): the coarser level's estimate, or on the coarsest
        level the data term's winner-takes-all (``costs`` are those rows' costs)."""
        if self.initial_labels is not None:
            return self.initial_labels[start:stop]
        return costs.unary.argmin(axis=2).astype(np.int32)

    def bundle_rows(self, bundle_height: int) -> list[tuple[int, int]]:
        """The level's bundles as row ranges: each view tiled on its own, so that no bundle
        spans the seam between the two views."""
        height = self.view_height
        return [
            (view * height + start, view * height + stop)
            for view in range(self.views)
            for start, stop in bundle_rows(height, bundle_height)
        ]

    def view_images(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """(left, right) image of each view."""
        height = self.view_height
        return [
            (self.left[v * height : (v + 1) * height], self.right[v * height : (v + 1) * height])
            for v in range(self.views)
        ]

    def _bin_costs(self, data_term: DataTerm, view: int, first: int, last: int) -> np.ndarray:
        """The data term of every label (bins, last - first, w) on rows of one view."""
        if self.volumes is None:
            left, right = self.view_images()[view]
            volume_of = ad_census_volume if data_term is DataTerm.AD_CENSUS else squared_volume
            volume = volume_of(left, right, self.plan.max_disparity, first, last)
            return bin_minimum(volume, self.plan.bin_width)
        if self._binned is None:
            self._binned = [bin_minimum(v, self.plan.bin_width) for v in self.volumes]
        return self._binned[view][:, first:last]

    def costs(self, config: MatchConfig, start: int = 0, stop: int | None = None) -> Costs:
        """Costs of rows [start, stop) (a block that spans both views has no edge between)."""
        stop = self.shape[0] if stop is None else stop
        height = self.view_height
        blocks = []
        for view, first, last in self.view_parts(start, stop):
            base = view * height
            left, right = self.view_images()[view]
            candidates = self.candidates[base + first : base + last]
            guide = to_gray(left[first:last])
            if config.data_term is DataTerm.SQUARED and self.plan.bin_width == 1:
                # the paper's path: evaluated at the candidates only
                unary = squared_difference(guide, to_gray(right[first:last]), candidates)
            else:
                bin_costs = self._bin_costs(config.data_term, view, first, last)
                unary = gather(bin_costs, candidates)
            blocks.append(
                mrf_costs(
                    unary,
                    candidates,
                    guide,
                    self.level,
                    config.regularizer,
                    vertical=config.bundle_height > 1,
                )
            )
        return Costs.stack(blocks)


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
    warm = uses_warm_start(config)
    results = []
    for start, stop in row_ranges:
        costs = inputs.costs(config, start, stop)
        bqm = codec.encode(costs, config.rectifier)
        initial = (
            codec.encode_labels(inputs.starting_labels(costs, start, stop), costs.num_labels)
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
    """A row solver on blocks of consecutive bundles' rows at once (vectorised over rows, memory
    bounded by :data:`COST_BLOCK_BYTES`, not by the image)."""
    width, labels = inputs.candidates.shape[1], inputs.candidates.shape[2]
    rows = max(config.bundle_height, COST_BLOCK_BYTES // (2 * 8 * width * labels * labels))
    results = []
    for block in _blocks(sorted(row_ranges), rows, inputs.view_height):
        started = time.perf_counter()
        first, last = block[0][0], block[-1][1]
        costs = inputs.costs(config, first, last)
        labels = solver.solve_rows(costs, config.bundle_height)
        chains = row_energies(costs, labels) if config.bundle_height == 1 else None
        share = (time.perf_counter() - started) / len(block)
        for start, stop in block:
            bundle_labels = labels[start - first : stop - first]
            energy = (
                float(chains[start - first])
                if chains is not None
                else mrf_energy(costs.rows(start - first, stop - first), bundle_labels)
            )
            results.append(
                BundleResult(
                    row_start=start,
                    row_stop=stop,
                    labels=bundle_labels,
                    energy=energy,
                    repaired=0,
                    wall_time=share,
                )
            )
    return results


def _blocks(
    row_ranges: list[tuple[int, int]], rows: int, view_height: int
) -> list[list[tuple[int, int]]]:
    """Consecutive, contiguous row ranges grouped into blocks of at most ``rows`` rows of one
    view (a gap between ranges, or the seam between views, starts a new block)."""
    blocks: list[list[tuple[int, int]]] = []
    for start, stop in row_ranges:
        first = blocks[-1][0][0] if blocks else 0
        if (
            blocks
            and blocks[-1][-1][1] == start
            and stop - first <= rows
            and start // view_height == first // view_height
        ):
            blocks[-1].append((start, stop))
        else:
            blocks.append([(start, stop)])
    return blocks


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
    rows = inputs.bundle_rows(config.bundle_height)
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
        rows = inputs.bundle_rows(config.bundle_height)
        chunks = [rows[i :: self.processes * 4] for i in range(self.processes * 4)]
        # the children build costs per bundle; the in-process volume cache is not worth sending
        solve = partial(solve_bundles, replace(inputs, volumes=None), config)
        results = [r for chunk in self._pool.map(solve, [c for c in chunks if c]) for r in chunk]
        return assemble(inputs, results)
