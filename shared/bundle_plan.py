"""Planning a level's bundles before they fan out: their height (a tile, a row, or a whole view
for the grid's dual decomposition), their width (whole rows or segments: ``auto`` is the widest
that embeds) and, for solvers that embed on a QPU graph, each bundle shape's embedding."""

from __future__ import annotations

import logging
import time
from typing import Any

from shared import settle
from shared.bundles import Bundle
from shared.config import AUTO, MatchConfig
from shared.level_inputs import LevelInputs
from shared.settle import settles
from shared.solvers.base import ShapePlanner
from shared.solvers.registry import resolve

log = logging.getLogger(__name__)


def level_bundle_width(inputs: LevelInputs, config: MatchConfig) -> int | None:
    """The segment width of this level's bundles (None: whole rows); ``auto`` asks the solver
    for the widest segment that embeds (searched once per shape and target, then cached).

    Parameters
    ----------
    inputs : LevelInputs
        The level (its width and candidate count).
    config : MatchConfig
        The run's configuration.

    Returns
    -------
    int or None
        Segment width in pixels; ``None`` for whole rows.
    """
    resolved = resolve(config)
    width = resolved.bundle_width_setting()
    if width == AUTO:
        return resolved.sampler.widest_bundle(
            encoding=config.encoding,
            candidates=inputs.candidates.shape[2],
            height=config.bundle_height,
            row_width=inputs.shape[1],
            margin=config.bundle_margin,
        )
    if width is None:
        return None
    pixels = int(width)
    return None if pixels >= inputs.shape[1] else pixels


def bundle_height(inputs: LevelInputs, config: MatchConfig) -> int:
    """Rows per bundle of the level: a whole view when the solver solves grids (``exact``'s
    ``grid`` inference), else ``config.bundle_height``."""
    return inputs.view_height if resolve(config).solves_grids else config.bundle_height


def level_bundles(inputs: LevelInputs, config: MatchConfig) -> list[Bundle]:
    """Every bundle of the level (segments of the level's :func:`level_bundle_width`).

    Solvers that embed on a QPU graph embed each bundle shape here, once, before the bundles
    fan out; ``inputs.prepared`` then records the width and the embeddings computed for it.

    Parameters
    ----------
    inputs : LevelInputs
        The level; its ``prepared`` is set here.
    config : MatchConfig
        The run's configuration.

    Returns
    -------
    list of Bundle
    """
    resolved = resolve(config)
    solver = None if resolved.row_solver else resolved.sampler
    started = time.perf_counter()
    cache = solver.cache if isinstance(solver, ShapePlanner) else None
    before = cache.computed if cache is not None else 0
    if settles(config):
        return _residual_tiles(inputs, config, solver, started, before)
    width = level_bundle_width(inputs, config)
    height = bundle_height(inputs, config)
    bundles = inputs.bundles(height, width, config.bundle_margin)
    inputs.prepared = {"bundle_width": width, "bundle_height": height}
    if isinstance(solver, ShapePlanner):
        shapes = sorted({bundle.shape for bundle in bundles})
        labels = inputs.candidates.shape[2]
        solver.embed_shapes(encoding=config.encoding, candidates=labels, shapes=shapes)
        inputs.prepared = {
            "bundle_width": bundles[0].shape[1],
            "bundle_height": height,
            "embeddings_computed": (cache.computed if cache is not None else 0) - before,
            "preparation_seconds": time.perf_counter() - started,
        }
    return bundles


def _residual_tiles(
    inputs: LevelInputs, config: MatchConfig, solver: Any, started: float, before: int
) -> list[Bundle]:
    """The residual design's bundles (:mod:`shared.settle`): the host settles the level (once),
    the tiles around what it leaves unsettled are the bundles; a QPU solver embeds their one
    shape (and its copies across the chip) here."""
    settle.prepare(inputs, config)
    bundles = inputs.residual_tiles()
    inputs.prepared.update(bundle_width=settle.TILE, bundle_height=settle.TILE)
    if isinstance(solver, ShapePlanner) and bundles:
        log.info(
            "level %d: embedding the %dx%d tile shape (%d tiles to send)",
            inputs.index + 1, settle.TILE, settle.TILE, len(bundles),
        )  # fmt: skip
        cache = solver.cache
        solver.embed_shapes(
            encoding=config.encoding,
            candidates=inputs.candidates.shape[2],
            shapes=sorted({bundle.shape for bundle in bundles}),
        )
        inputs.prepared.update(
            embeddings_computed=cache.computed - before,
            preparation_seconds=time.perf_counter() - started,
        )
    return bundles
