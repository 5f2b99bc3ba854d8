"""Grid inference with a QUBO solver and ``certify_tiles`` (the default): the residual design
of :mod:`shared.settle`. The host settles each view's whole grid once (:meth:`prepare`: on the
service's control worker, before the level's inputs are kept); the bundles are the 4x4 tiles
around the pixels it leaves unsettled, each with its neighbours fixed to the host's labels and its
certified pixels pinned; the level is the host's labels with each tile's answer where it lowers
the energy (:func:`shared.settle.merge`). A level not settled (yet) is cut and assembled as
:class:`~shared.inference.qubo_tiles.QuboTiles` with a certificate per tile."""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator, Sequence

from shared import settle
from shared.activity import report
from shared.assembly import BundleResult, LevelSolution
from shared.bundles import Bundle
from shared.config import MatchConfig
from shared.inference.base import Termination
from shared.inference.qubo import TileProblem
from shared.inference.qubo_tiles import QuboTiles
from shared.level_inputs import LevelInputs
from shared.solvers.base import ShapePlanner

log = logging.getLogger(__name__)


class ResidualTiles(QuboTiles):
    """The host's settlement, then the tiles it leaves."""

    name = "qubo-residual"
    reads_initial_labels = False  # the host's settlement gives the tiles' labels

    def prepare(self, inputs: LevelInputs, config: MatchConfig) -> str | None:
        report("settling the level on the host (dual decomposition of each view)")
        counts = settle.prepare(inputs, config)
        return (
            f"settled on the host in {counts.host_seconds:.1f} s: {counts.unsettled} of "
            f"{counts.pixels} pixels unsettled, {counts.tiles} tiles to send"
        )

    def plan(self, inputs: LevelInputs, config: MatchConfig) -> list[Bundle]:
        """The host settles the level (once); the tiles around what it leaves unsettled are the
        bundles; a QPU solver embeds their one shape (and its copies across the chip) here."""
        solver = self.sampler
        started = time.perf_counter()
        before = solver.cache.computed if isinstance(solver, ShapePlanner) else 0
        settle.prepare(inputs, config)
        bundles = settle.tiles(inputs)
        inputs.prepared.update(bundle_width=settle.TILE, bundle_height=settle.TILE)
        if isinstance(solver, ShapePlanner) and bundles:
            log.info(
                "level %d: embedding the %dx%d tile shape (%d tiles to send)",
                inputs.plan.index + 1, settle.TILE, settle.TILE, len(bundles),
            )  # fmt: skip
            solver.embed_shapes(
                encoding=config.encoding,
                candidates=inputs.count,
                shapes=sorted({bundle.shape for bundle in bundles}),
            )
            inputs.prepared.update(
                embeddings_computed=solver.cache.computed - before,
                preparation_seconds=time.perf_counter() - started,
            )
        return bundles

    def planned(self, inputs: LevelInputs, config: MatchConfig) -> list[Bundle]:
        if settle.settled(inputs):
            return settle.tiles(inputs)
        return super().planned(inputs, config)

    def bundle_config(self, inputs: LevelInputs, config: MatchConfig) -> MatchConfig:
        """A settled level's tiles: :func:`shared.settle.tile_config`."""
        return settle.tile_config(config) if settle.settled(inputs) else config

    def problems(
        self, inputs: LevelInputs, config: MatchConfig, items: Sequence[Bundle]
    ) -> Iterator[TileProblem]:
        return super().problems(inputs, self.bundle_config(inputs, config), items)

    def assemble(
        self, inputs: LevelInputs, results: list[BundleResult], config: MatchConfig
    ) -> LevelSolution:
        if not settle.settled(inputs):
            return super().assemble(inputs, results, config)
        solution = settle.merge(inputs, results, config)
        solution.termination = Termination.SAMPLED if results else Termination.SETTLED
        return solution
