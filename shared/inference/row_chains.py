"""Rows inference with a row solver (``exact``): each bundle is one row's chain (the paper's MRF,
no edge between rows), minimised exactly on its costs by the solver's dynamic programme, blocks
of consecutive rows at once (vectorised over rows, memory bounded by :data:`COST_BLOCK_BYTES`,
not by the image)."""

from __future__ import annotations

import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from functools import partial

from shared.assembly import BundleResult
from shared.bundles import Bundle
from shared.config import MatchConfig
from shared.energy import mrf_energy, row_energies
from shared.inference.base import (
    LevelInference,
    Termination,
    width_setting,
)
from shared.level_inputs import LevelInputs
from shared.provenance_map import Stage, filled
from shared.solvers.base import RowSolver
from shared.solvers.resolved import ResolvedSolver
from shared.threads import threads

#: A row solver takes as many rows at once as keep one block's pairwise cost arrays (float64,
#: horizontal and vertical, K x K per pixel) within this: large enough to vectorise, small
#: enough that memory is bounded by the block, not by the image (one block per core at a time).
COST_BLOCK_BYTES = 32 * 2**20


class RowChains(LevelInference):
    """Blocks of rows solved by ``solver``'s :class:`RowSolver` (built on first use), in
    threads (numpy releases the GIL inside its loops: the blocks of both views overlap)."""

    name = "row-chains"
    whole_rows = True
    reads_initial_labels = False  # each row's chain is solved exactly
    termination = Termination.OPTIMAL

    def __init__(self, solver: ResolvedSolver) -> None:
        self.solver = solver

    def width_setting(self, config: MatchConfig) -> int | str | None:
        return width_setting(self.solver, config)  # whole rows, one a bundle

    def plan(self, inputs: LevelInputs, config: MatchConfig) -> list[Bundle]:
        self.width_setting(config)
        inputs.prepared = {"bundle_width": None, "bundle_height": config.bundle_height}
        return inputs.bundles(config.bundle_height, None, config.bundle_margin)

    def _solve(
        self, inputs: LevelInputs, config: MatchConfig, items: list[Bundle]
    ) -> Iterator[list[BundleResult]]:
        row_ranges = [(b.row_start, b.row_stop) for b in items]
        width, labels = inputs.shape[1], inputs.count
        rows = max(config.bundle_height, COST_BLOCK_BYTES // (2 * 8 * width * labels * labels))
        blocks = _blocks(sorted(row_ranges), rows, inputs.view_height)
        inputs.binned_volumes()
        with ThreadPoolExecutor(min(len(blocks), threads())) as pool:
            yield from pool.map(partial(_solve_block, self.solver.rows(), inputs, config), blocks)


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
