"""Solving the bundles of one level: the unit of work a worker (or the in-process loop) runs.

:class:`~shared.level_inputs.LevelInputs` is everything needed to build any bundle of a level.
From a block of rows the worker computes the costs, encodes each bundle with the
configured codec, calls the solver adapter, decodes and repairs. A ``RowSolver`` (the exact DP)
skips the QUBO and works on the costs of blocks of rows.

With ``grid`` inference a row solver's bundle is a whole view, minimised by dual decomposition
into its row and column chains (:mod:`shared.grid`); a QUBO solver's bundle is a tile of
``bundle_height`` rows (a segment of them with ``bundle_width``) whose edges to the pixels around
it become unaries, given those pixels' starting labels (the coarser level's estimate). With
``certify_tiles`` (the default) the host settles the whole level first and only 4x4 tiles around
what it leaves unsettled are solved (:mod:`shared.settle`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from functools import partial
from typing import TYPE_CHECKING

import numpy as np

from shared.assembly import BundleResult, LevelSolution
from shared.bundle_plan import level_bundles
from shared.bundles import Bundle, bundle_seed
from shared.config import Inference, MatchConfig
from shared.encodings import get_codec
from shared.energy import Costs, mrf_energy, row_energies
from shared.grid import DualResult, GridMRF, boundary_unary
from shared.grid_inference import minimiser
from shared.level_inputs import BundleSpec, LevelInputs
from shared.provenance_map import Stage, filled
from shared.settle import assemble_level, pinned, tile_config
from shared.solvers.base import BatchSolver, RowSolver, SolveResult
from shared.solvers.registry import resolve

if TYPE_CHECKING:
    import dimod
from shared.threads import threads

BundleProgress = Callable[[int, int], None]
"""``(units done, units total)`` within a level: bundles (rows for a row solver)."""

#: Parameters in ``MatchConfig.solver_params`` that steer this module, not the solver.
PIPELINE_PARAMS = {"warm_start"}

#: A row solver takes as many rows at once as keep one block's pairwise cost arrays (float64,
#: horizontal and vertical, K x K per pixel) within this: large enough to vectorise, small
#: enough that memory is bounded by the block, not by the image (one block per core at a time).
COST_BLOCK_BYTES = 32 * 2**20

#: Grids (whole views) minimised at the same time hold at most about this much dual
#: decomposition state between them; a larger view's grid waits for the other's to finish (the
#: same maps: each grid is minimised on its own). Keeps a 2000 x 2000 pair within 2 GiB.
GRID_STATE_BYTES = 2**30
#: (h, w, K) 4-byte arrays a grid's dual decomposition holds at its peak: unary, candidates,
#: the transposed unary, two multiplier arrays, the primal's neighbour costs and chain buffers
#: (TRW-S holds fewer: unary, candidates and its four message arrays).
GRID_STATE_ARRAYS = 7


def solve_bundles(
    inputs: LevelInputs,
    config: MatchConfig,
    bundles: Sequence[BundleSpec],
    progress: BundleProgress | None = None,
) -> list[BundleResult]:
    """Solve the given bundles (:class:`Bundle` or row ranges) of a level with
    ``config.solver``.

    Parameters
    ----------
    inputs : LevelInputs
        The level, as prepared by :func:`level_bundles`.
    config : MatchConfig
        The run's configuration.
    bundles : list of Bundle or tuple of int
        The bundles to solve, e.g. one task's share of the level.
    progress : callable, optional
        Called with (bundles solved, bundles given) after each bundle (a row solver: after
        each block of rows).

    Returns
    -------
    list of BundleResult
        One per bundle, in the given order.

    Raises
    ------
    ValueError
        If a row solver is given segments rather than whole rows.
    """
    if not bundles:
        return []
    if "settle" in inputs.prepared:  # the residual design's tiles (shared.settle)
        config = tile_config(config)
    items = [inputs.as_bundle(spec) for spec in bundles]
    resolved = resolve(config)
    if resolved.row_solver:  # no sampler built for exact's grids (no dimod import)
        width = inputs.shape[1]
        if any(b.col_start != 0 or b.col_stop != width for b in items):
            raise ValueError(f"{config.solver} solves whole rows only, not row segments")
        row_ranges = [(b.row_start, b.row_stop) for b in items]
        if resolved.solves_grids:
            return _solve_grids(inputs, config, row_ranges, progress)
        return _solve_on_costs(resolved.rows(), inputs, config, row_ranges, progress)
    solver = resolved.sampler
    codec = get_codec(config.encoding)
    params = {k: v for k, v in config.solver_params.items() if k not in PIPELINE_PARAMS}
    problems: Iterable[TileProblem] = encoded_bundles(inputs, config, items)
    batch = solver.solve_batch if isinstance(solver, BatchSolver) else None
    if batch is not None:  # one problem for many bundles (hybrid: a level's BQM)
        problems = list(problems)
        outcomes = iter(batch([(p.bqm, p.seed, p.initial) for p in problems], **params))
    results = []
    for problem in problems:
        if batch is not None:
            outcome = next(outcomes)
        else:
            outcome = solver.solve(
                problem.bqm, seed=problem.seed, initial_state=problem.initial, **params
            )
        results.append(_bundle_result(problem, outcome, codec))
        if progress is not None:
            progress(len(results), len(items))
    return results


@dataclass
class TileProblem:
    """One QUBO bundle as the solver gets it: its costs (with a grid tile's boundary unaries),
    QUBO, seed and warm start."""

    bundle: Bundle
    costs: Costs
    bqm: dimod.BinaryQuadraticModel
    seed: int
    initial: np.ndarray | None


def _bundle_result(problem: TileProblem, outcome: SolveResult, codec) -> BundleResult:
    """A bundle's result from the solver's ``outcome``: its decoded labels and their energy."""
    start, stop, first, last = problem.bundle.as_list()
    decoded = codec.decode(problem.costs, outcome.sample)
    per_pixel = codec.variables_per_pixel(problem.costs.num_labels)
    stages = sampler_stages(
        decoded.invalid, outcome.info.get("fixed_variables"), per_pixel, decoded.labels
    )
    info = {k: v for k, v in outcome.info.items() if k != "fixed_variables"}
    return BundleResult(
        row_start=start,
        row_stop=stop,
        labels=decoded.labels,
        energy=mrf_energy(problem.costs, decoded.labels),
        repaired=decoded.repaired,
        wall_time=outcome.wall_time,
        timing=outcome.timing,
        info=info,
        col_start=first,
        col_stop=last,
        stages=stages,
    )


def sampler_stages(
    invalid: np.ndarray | None, fixed: list[int] | None, per_pixel: int, labels: np.ndarray
) -> np.ndarray:
    """A sampled bundle's provenance codes: :attr:`Stage.SOLVER`, :attr:`Stage.ROOF_DUALITY`
    where roof duality fixed every variable of the pixel (``fixed``: the bundle's variables it
    fixed, pixel-major as the codecs number them, ``per_pixel`` a pixel), and
    :attr:`Stage.REPAIRED` where the bits were no valid code (``invalid``)."""
    stages = filled(labels.shape, Stage.SOLVER)
    if fixed:
        mask = np.zeros(labels.size * per_pixel, dtype=bool)
        mask[np.asarray(fixed, dtype=np.int64)] = True
        whole = mask.reshape(labels.size, per_pixel).all(axis=1).reshape(labels.shape)
        stages[whole] = Stage.ROOF_DUALITY
    if invalid is not None:
        stages[invalid] = Stage.REPAIRED
    return stages


def grid_stages(outcome: DualResult) -> np.ndarray:
    """A host-minimised grid's codes: :attr:`Stage.CERTIFIED` where dual decomposition's row and
    column copies agree (everywhere when the labelling is proved optimal), else
    :attr:`Stage.HOST`."""
    if outcome.unsettled is None:
        proved = outcome.disagreeing == 0
        return filled(outcome.labels.shape, Stage.CERTIFIED if proved else Stage.HOST)
    return np.where(outcome.unsettled, np.uint8(Stage.HOST), np.uint8(Stage.CERTIFIED))


def _surroundings(
    inputs: LevelInputs, config: MatchConfig, start: int, stop: int
) -> tuple[GridMRF, np.ndarray, int]:
    """The grid of rows [start, stop) and the rows just above and below (within the view), the
    starting labels of its pixels (:meth:`LevelInputs.starting_labels`: the coarser estimate,
    or the data term's minimum on the coarsest level), and its first row."""
    view_start = (start // inputs.view_height) * inputs.view_height
    above, below = max(start - 1, view_start), min(stop + 1, view_start + inputs.view_height)
    grid = inputs.grid(config, above, below)
    labels = inputs.initial_labels[above:below] if inputs.initial_labels is not None else None
    if labels is None:
        labels = grid.unary.argmin(axis=2).astype(np.int32)
    return grid, labels, above


def _solve_grids(
    inputs: LevelInputs,
    config: MatchConfig,
    row_ranges: list[tuple[int, int]],
    progress: BundleProgress | None = None,
) -> list[BundleResult]:
    """Each bundle (a whole view) minimised as a grid over its chains (dual decomposition or
    TRW-S, ``grid_inference``); the views side by side in threads (the compiled chain kernels
    release the GIL)."""
    inputs.binned_volumes()
    minimise = minimiser(config)

    def solve(rows: tuple[int, int]) -> BundleResult:
        started = time.perf_counter()
        outcome = minimise(inputs.grid(config, *rows), config.dual_iterations, config.dual_gap)
        return BundleResult(
            row_start=rows[0],
            row_stop=rows[1],
            labels=outcome.labels,
            energy=outcome.energy,
            lower_bound=outcome.lower_bound,
            repaired=0,
            wall_time=time.perf_counter() - started,
            info={"dual_iterations": outcome.iterations, "disagreeing": outcome.disagreeing},
            stages=grid_stages(outcome),
        )

    results: list[BundleResult] = []
    with ThreadPoolExecutor(grids_at_once(inputs, row_ranges)) as pool:
        for result in pool.map(solve, row_ranges):
            results.append(result)
            if progress is not None:
                progress(len(results), len(row_ranges))
    return results


def grids_at_once(inputs: LevelInputs, row_ranges: Sequence[tuple[int, int]]) -> int:
    """Grids to minimise side by side: one per core, as many as :data:`GRID_STATE_BYTES`
    holds (at least one)."""
    rows = max(stop - start for start, stop in row_ranges)
    grid_bytes = 4 * GRID_STATE_ARRAYS * rows * inputs.candidates[0].size
    return max(1, min(len(row_ranges), threads(), GRID_STATE_BYTES // max(grid_bytes, 1)))


def encoded_bundles(
    inputs: LevelInputs, config: MatchConfig, items: Sequence[Bundle]
) -> Iterator[TileProblem]:
    """Each bundle as a :class:`TileProblem`, one at a time.

    A grid tile's edges to the pixels around it become unaries given their starting labels
    (with the residual design, :mod:`shared.settle`, the host's labels, and the tile's certified
    pixels pinned to them); the starting labels are the warm start when the run warm-starts.

    Parameters
    ----------
    inputs : LevelInputs
        The level.
    config : MatchConfig
        The run's configuration.
    items : sequence of Bundle
        The bundles (segments of the same rows one after another share their costs).

    Yields
    ------
    TileProblem
    """
    codec = get_codec(config.encoding)
    resolved = resolve(config)
    warm = resolved.warm_start
    grid_tiles = config.inference is Inference.GRID
    rows: tuple[int, int] | None = None
    for bundle in items:
        start, stop, first, last = bundle.as_list()
        if rows != (start, stop):  # segments of the same rows share one cost computation
            row_costs, rows = inputs.costs(config, start, stop), (start, stop)
            if grid_tiles:
                grid, grid_labels, above = _surroundings(inputs, config, start, stop)
        costs = row_costs.columns(first, last)
        if grid_tiles:
            tile = (slice(start - above, stop - above), slice(first, last))
            extra = boundary_unary(grid, grid_labels, *tile)
            costs = replace(costs, unary=costs.unary + extra)
            if "settle" in inputs.prepared:  # the certified pixels pinned (shared.settle)
                costs = replace(costs, unary=pinned(inputs, bundle, costs))
        seed = bundle_seed(config.seed, inputs.index, start, first)
        initial = None
        if warm:
            labels = inputs.starting_labels(row_costs, start, stop)[:, first:last]
            initial = codec.encode_labels(labels, costs.num_labels)
        bqm = codec.encode(costs, config.rectifier)
        yield TileProblem(bundle, costs, bqm, seed, initial)


def _solve_on_costs(
    solver: RowSolver,
    inputs: LevelInputs,
    config: MatchConfig,
    row_ranges: list[tuple[int, int]],
    progress: BundleProgress | None = None,
) -> list[BundleResult]:
    """A row solver on blocks of consecutive bundles' rows at once (vectorised over rows, memory
    bounded by :data:`COST_BLOCK_BYTES`, not by the image)."""
    width, labels = inputs.candidates.shape[1], inputs.candidates.shape[2]
    rows = max(config.bundle_height, COST_BLOCK_BYTES // (2 * 8 * width * labels * labels))
    blocks = _blocks(sorted(row_ranges), rows, inputs.view_height)
    inputs.binned_volumes()
    results: list[BundleResult] = []
    # numpy releases the GIL inside its loops: threads overlap the blocks (both views)
    with ThreadPoolExecutor(min(len(blocks), threads())) as pool:
        for block_results in pool.map(partial(_solve_block, solver, inputs, config), blocks):
            results.extend(block_results)
            if progress is not None:
                progress(len(results), len(row_ranges))
    return results


def _solve_block(
    solver: RowSolver, inputs: LevelInputs, config: MatchConfig, block: list[tuple[int, int]]
) -> list[BundleResult]:
    """One block of consecutive bundles' rows: costs, the row solver, each bundle's energy."""
    started = time.perf_counter()
    first, last = block[0][0], block[-1][1]
    costs = inputs.costs(config, first, last)
    labels = solver.solve_rows(costs, config.bundle_height)
    chains = row_energies(costs, labels) if config.bundle_height == 1 else None
    share = (time.perf_counter() - started) / len(block)
    results = []
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
                stages=filled(bundle_labels.shape, Stage.CERTIFIED),  # a row's exact optimum
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


def solve_level_in_process(
    inputs: LevelInputs, config: MatchConfig, progress: BundleProgress | None = None
) -> LevelSolution:
    """The in-process ``solve_level``: every bundle of the level, one after another.

    Parameters
    ----------
    inputs : LevelInputs
        The prepared level.
    config : MatchConfig
        The run's configuration (solver, encoding, seed).
    progress : callable, optional
        Called with (bundles solved, bundles of the level) as they are solved.

    Returns
    -------
    LevelSolution
    """
    bundles = level_bundles(inputs, config)
    if progress is not None:
        progress(0, len(bundles))
    return assemble_level(inputs, solve_bundles(inputs, config, bundles, progress), config)
