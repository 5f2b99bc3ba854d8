"""Grid inference with a row solver (``exact``): a bundle is a whole view, its 4-connected grid
minimised over its row and column chains with a lower bound: dual decomposition
(:func:`shared.grid.dual_decomposition`) or TRW-S (:func:`shared.grid_inference.trws`), as
``grid_inference`` says (:func:`shared.grid_inference.minimiser`)."""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from shared.assembly import BundleResult
from shared.bundles import Bundle
from shared.config import MatchConfig
from shared.grid import DualResult
from shared.grid_inference import Minimiser
from shared.inference.base import (
    LevelInference,
    Termination,
    width_setting,
)
from shared.level_inputs import LevelInputs
from shared.provenance_map import Stage, filled
from shared.solvers.resolved import ResolvedSolver
from shared.threads import holding_core, threads

#: Grids (whole views) minimised at the same time hold at most about this much dual
#: decomposition state between them; a larger view's grid waits for the other's to finish (the
#: same maps: each grid is minimised on its own). Keeps a 2000 x 2000 pair within 2 GiB.
GRID_STATE_BYTES = 2**30
#: (h, w, K) 4-byte arrays a grid's dual decomposition holds at its peak: unary, candidates,
#: the transposed unary, two multiplier arrays, the primal's neighbour costs and chain buffers
#: (TRW-S holds fewer: unary, candidates and its four message arrays).
GRID_STATE_ARRAYS = 7


class GridViews(LevelInference):
    """Each view's whole grid, minimised by ``minimise`` (the views side by side in threads:
    the compiled chain kernels release the GIL)."""

    whole_rows = True
    reads_initial_labels = False  # each view's grid is minimised from scratch

    def __init__(self, name: str, minimise: Minimiser, solver: ResolvedSolver) -> None:
        self.name = name
        self.minimise = minimise
        self.solver = solver

    def width_setting(self, config: MatchConfig) -> int | str | None:
        return width_setting(self.solver, config)  # whole rows (each view's grid)

    def plan(self, inputs: LevelInputs, config: MatchConfig) -> list[Bundle]:
        self.width_setting(config)
        height = inputs.view_height
        inputs.prepared = {"bundle_width": None, "bundle_height": height}
        return inputs.bundles(height, None, config.bundle_margin)

    def _solve(
        self, inputs: LevelInputs, config: MatchConfig, items: list[Bundle]
    ) -> Iterator[list[BundleResult]]:
        row_ranges = [(b.row_start, b.row_stop) for b in items]
        inputs.prepare_costs()

        at_once = grids_at_once(inputs, row_ranges)
        # grids one at a time (2000 x 2000): the other core builds half of each grid's costs
        workers = threads() if at_once == 1 else 1

        def solve(rows: tuple[int, int]) -> BundleResult:
            started = time.perf_counter()
            grid = inputs.grid(config, *rows, workers=workers)
            with holding_core():  # a core this view's grid holds (threads.spare_core)
                outcome = self.minimise(grid, config.dual_iterations, config.dual_gap)
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

        with ThreadPoolExecutor(at_once) as pool:
            for result in pool.map(solve, row_ranges):
                yield [result]

    def assemble(self, inputs: LevelInputs, results: list[BundleResult], config: MatchConfig):
        solution = super().assemble(inputs, results, config)
        solution.termination = termination(results, config)
        return solution


def termination(results: list[BundleResult], config: MatchConfig) -> str | None:
    """Why the views' minimisation stopped: every view proven optimal, one stopped at the
    iteration limit, else at the gap (None when the results do not say: an older worker's)."""
    infos = [r.info for r in results]
    if not infos or any("disagreeing" not in info for info in infos):
        return None
    if all(info["disagreeing"] == 0 for info in infos):
        return Termination.OPTIMAL
    if any(info.get("dual_iterations", 0) >= config.dual_iterations for info in infos):
        return Termination.ITERATIONS
    return Termination.GAP


def grids_at_once(inputs: LevelInputs, row_ranges: Sequence[tuple[int, int]]) -> int:
    """Grids to minimise side by side: one per core, as many as :data:`GRID_STATE_BYTES`
    holds (at least one)."""
    rows = max(stop - start for start, stop in row_ranges)
    grid_bytes = 4 * GRID_STATE_ARRAYS * rows * inputs.shape[1] * inputs.count
    return max(1, min(len(row_ranges), threads(), GRID_STATE_BYTES // max(grid_bytes, 1)))


def grid_stages(outcome: DualResult) -> np.ndarray:
    """A host-minimised grid's codes: :attr:`Stage.CERTIFIED` where dual decomposition's row and
    column copies agree (everywhere when the labelling is proved optimal), else
    :attr:`Stage.HOST`."""
    if outcome.unsettled is None:
        proved = outcome.disagreeing == 0
        return filled(outcome.labels.shape, Stage.CERTIFIED if proved else Stage.HOST)
    return np.where(outcome.unsettled, np.uint8(Stage.HOST), np.uint8(Stage.CERTIFIED))
