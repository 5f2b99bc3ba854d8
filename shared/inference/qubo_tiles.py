"""Grid inference with a QUBO solver, tile by tile: each bundle is a tile of ``bundle_height``
rows (a segment of them with ``bundle_width``) whose edges to the pixels around it become
unaries given those pixels' starting labels (the coarser level's estimate;
:func:`shared.grid.boundary_unary`). The level's energy is that of the assembled labels on the
whole grid. (With ``certify_tiles``, the default, the host settles the level first and only the
tiles around what it leaves are solved: :mod:`shared.inference.qubo_residual`.)"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import replace

import numpy as np

from shared import settle
from shared.assembly import BundleResult, LevelSolution
from shared.bundles import Bundle
from shared.config import MatchConfig
from shared.grid import GridMRF, boundary_unary
from shared.inference.qubo import QuboStrategy, TileProblem, encoded
from shared.level_inputs import LevelInputs


class QuboTiles(QuboStrategy):
    """Tiles with their surroundings' labels as unaries; a tile of a level the host settled
    (:mod:`shared.settle`) has its certified pixels pinned to the host's labels."""

    name = "qubo-tiles"

    def problems(
        self, inputs: LevelInputs, config: MatchConfig, items: Sequence[Bundle]
    ) -> Iterator[TileProblem]:
        pin = settle.settled(inputs)
        rows: tuple[int, int] | None = None
        for bundle in items:
            start, stop, first, last = bundle.as_list()
            if rows != (start, stop):  # segments of the same rows share one cost computation
                row_costs, rows = inputs.costs(config, start, stop), (start, stop)
                grid, grid_labels, above = surroundings(inputs, config, start, stop)
            tile = (slice(start - above, stop - above), slice(first, last))
            extra = boundary_unary(grid, grid_labels, *tile)
            costs = row_costs.columns(first, last)
            costs = replace(costs, unary=costs.unary + extra)
            if pin:  # the certified pixels pinned (shared.settle)
                costs = replace(costs, unary=settle.pinned(inputs, bundle, costs))
            start_labels = self.warm_start(inputs, row_costs, bundle)
            yield encoded(inputs, config, bundle, costs, start_labels)

    def assemble(
        self, inputs: LevelInputs, results: list[BundleResult], config: MatchConfig
    ) -> LevelSolution:
        """Tiles priced their edges to the tiles around against starting labels: the level's
        energy is that of the assembled labels on the whole grid."""
        solution = super().assemble(inputs, results, config)
        height = inputs.view_height
        solution.energy = float(
            sum(
                inputs.grid(config, view * height, (view + 1) * height).energy(
                    solution.labels[view * height : (view + 1) * height]
                )
                for view in range(inputs.views)
            )
        )
        return solution


def surroundings(
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
