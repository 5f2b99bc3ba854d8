"""The residual design of a QUBO solver's level: the host settles the grid, the solver gets only
what is left.

    prepare    each view's whole grid minimised by dual decomposition on the host
               (``dual_iterations``, no gap stop): a pixel whose row and column copies agree
               is *certified*; the others are *unsettled*. The host's labels are ``exact``'s
               (the same decomposition stopped at ``dual_gap``: better maps on Tsukuba).
               The 4x4 tiles (aligned, the last row and column of tiles shifted inward to keep
               the shape: one embedding serves all)
               holding an unsettled pixel are the level's bundles; their neighbours are fixed to
               the host's labels (:func:`shared.grid.boundary_unary`, through
               ``LevelInputs.initial_labels``, which become the host's labels), which are also
               the warm start; a tile's certified pixels are pinned to them (:func:`pinned`),
               so roof duality fixes their variables on the host.
    solve      only those tiles go to the solver (``qpu``, ``hybrid``, ``sa`` and the
               stand-ins): a QPU call carries many of them (one shape, its disjoint copies)
    merge      from the host's labels, each tile's answer replaces them only where it lowers
               the level's energy (priced against the labels around it as they are then), so
               the level's energy never rises above the host's

Why: the whole-view decomposition leaves 0.06-0.5 % of the pixels unsettled and is certified
within ~0.06 % of the optimum; a 3-row tile sent whole held ~3 unsettled pixels of 75, and the
QPU time was 5,351 calls on Tsukuba. The counts (certified, sent, improved pixels) answer the
lab's question: how often the annealer improves on the host. ``inputs.prepared["settle"]``
carries the plan (JSON: the service keeps it with the level's inputs).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from shared.assembly import BundleResult, LevelSolution, embedding_summary
from shared.bundles import Bundle
from shared.config import MatchConfig
from shared.energy import Costs
from shared.grid import GridMRF, boundary_unary, dual_decomposition
from shared.grid_inference import minimiser
from shared.level_inputs import LevelInputs
from shared.provenance_map import Stage

#: Rows and columns of a sent tile (one shape: embedded once, copied across the chip).
TILE = 4


@dataclass(frozen=True)
class Residual:
    """One level's counts: ``pixels`` of the level, ``certified`` by the host's dual
    decomposition (row and column copies agree), ``unsettled`` (the others), ``tiles`` sent and
    the ``pixels_sent`` they hold, ``tiles_improved`` (the solver's answer lowered the energy)
    and ``pixels_improved`` (pixels whose label that changed)."""

    pixels: int
    certified: int
    unsettled: int
    tiles: int
    pixels_sent: int
    tiles_improved: int = 0
    pixels_improved: int = 0
    host_seconds: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def settled(inputs: LevelInputs) -> bool:
    """Whether the host settled the level (:func:`prepare` recorded its plan)."""
    return "settle" in inputs.prepared


def tiles(inputs: LevelInputs) -> list[Bundle]:
    """The tiles :func:`prepare` chose (empty when every pixel is settled)."""
    return [Bundle(*tile) for tile in inputs.prepared["settle"]["tile_list"]]


def tile_config(config: MatchConfig) -> MatchConfig:
    """The configuration a sent tile is encoded with: :data:`TILE` rows (vertical edges in its
    costs), no per-tile certificate (the level's host step did that)."""
    return config.model_copy(update={"bundle_height": TILE, "certify_tiles": False})


def starts(size: int) -> np.ndarray:
    """First row (column) of every tile along an axis of ``size``: multiples of :data:`TILE`,
    the last one shifted inward to keep the tile whole (a smaller axis: one tile at 0)."""
    if size <= TILE:
        return np.zeros(1, dtype=np.int64)
    first = np.arange(0, size, TILE)
    return np.minimum(first, size - TILE)


def tiles_of(height: int, width: int, views: int = 1) -> int:
    """Tiles that cover a level of ``views`` views of ``height`` x ``width`` pixels."""
    return views * len(starts(height)) * len(starts(width))


def unsettled_tiles(unsettled: np.ndarray) -> list[tuple[int, int]]:
    """The (row, column) origins of the tiles that hold an unsettled pixel of one view.

    Parameters
    ----------
    unsettled : numpy.ndarray
        (h, w) bool.

    Returns
    -------
    list of (int, int)
        Row-major, each tile once.
    """
    height, width = unsettled.shape
    rows, columns = starts(height), starts(width)
    found: list[tuple[int, int]] = []
    for top in rows:
        band = np.asarray(unsettled[top : top + TILE].any(axis=0), dtype=np.int64)
        # reduceat sums up to the next start: the last (shifted) tile reads its own window
        hits = np.add.reduceat(band, columns) > 0
        hits[-1] = bool(band[columns[-1] : columns[-1] + TILE].any())
        found.extend((int(top), int(columns[i])) for i in np.flatnonzero(hits))
    return found


def prepare(inputs: LevelInputs, config: MatchConfig) -> Residual:
    """The host step: settle each view, keep its labels as the level's ``initial_labels``
    (boundary and warm start of the sent tiles) and the tiles to send in
    ``inputs.prepared["settle"]``. Done once (a second call returns the recorded counts).

    Parameters
    ----------
    inputs : LevelInputs
        The level; its ``initial_labels`` and ``prepared`` are set.
    config : MatchConfig
        The run's configuration (``dual_iterations``).

    Returns
    -------
    Residual
        The level's counts before solving.
    """
    if "settle" in inputs.prepared:
        return _counts(inputs.prepared["settle"])
    started = time.perf_counter()
    inputs.prepare_costs()
    height = inputs.view_height
    labels = np.empty(inputs.shape, dtype=np.int32)
    tiles: list[list[int]] = []
    loose: list[np.ndarray] = []
    unsettled = bound = 0.0
    for view in range(inputs.views):
        top = view * height
        grid = inputs.grid(config, top, top + height)
        outcome = dual_decomposition(grid, config.dual_iterations)
        # the labels exact gives (stopped at dual_gap): on Tsukuba their RMSE is 3 % below the
        # longer run's, whose disagreements are still the fewer (0.3 % of the pixels, not 4 %)
        labels[top : top + height] = (
            minimiser(config)(grid, config.dual_iterations, config.dual_gap).labels
            if config.dual_gap > 0 or minimiser(config) is not dual_decomposition
            else outcome.labels
        )
        assert outcome.unsettled is not None
        unsettled += int(outcome.unsettled.sum())
        loose.append(np.argwhere(outcome.unsettled) + np.array([top, 0]))
        bound += outcome.lower_bound
        tiles.extend(
            [top + row, top + row + min(TILE, height), column, column + min(TILE, inputs.shape[1])]
            for row, column in unsettled_tiles(outcome.unsettled)
        )
    inputs.initial_labels = labels
    pixels = inputs.shape[0] * inputs.shape[1]
    sent = sum((b[1] - b[0]) * (b[3] - b[2]) for b in tiles)
    counts = Residual(
        pixels=pixels,
        certified=pixels - int(unsettled),
        unsettled=int(unsettled),
        tiles=len(tiles),
        pixels_sent=sent,
        host_seconds=time.perf_counter() - started,
    )
    inputs.prepared["settle"] = {
        **counts.as_dict(),
        "lower_bound": bound,
        "tile_list": tiles,
        "unsettled_pixels": np.concatenate(loose).tolist(),
    }
    return counts


def _counts(recorded: dict[str, Any]) -> Residual:
    return Residual(**{k: v for k, v in recorded.items() if k in Residual.__dataclass_fields__})


def pinned(inputs: LevelInputs, tile: Bundle, costs: Costs) -> np.ndarray:
    """A sent tile's unary with its certified pixels pinned to the host's labels: every other
    label costs :func:`pin` more, more than it could gain from its edges, so roof duality fixes
    those pixels' variables on the host and only the unsettled pixels' reach the solver (fewer
    qubits, fewer hybrid variables); the tile's answer then changes only unsettled pixels.

    Parameters
    ----------
    inputs : LevelInputs
        The level, after :func:`prepare`.
    tile : Bundle
        The tile.
    costs : Costs
        Its costs, boundary terms included in the unary.

    Returns
    -------
    numpy.ndarray
        A new array.
    """
    assert inputs.initial_labels is not None
    unary = costs.unary
    rows = slice(tile.row_start, tile.row_stop)
    columns = slice(tile.col_start, tile.col_stop)
    certified = np.ones(unary.shape[:2], dtype=bool)
    for row, column in inputs.prepared["settle"]["unsettled_pixels"]:
        if rows.start <= row < rows.stop and columns.start <= column < columns.stop:
            certified[row - rows.start, column - columns.start] = False
    host = inputs.initial_labels[rows, columns]
    penalty = np.full(unary.shape, pin(costs), dtype=unary.dtype)
    np.put_along_axis(penalty, host[:, :, None], 0.0, axis=2)
    return unary + penalty * certified[:, :, None]


def pin(costs: Costs) -> float:
    """What a pinned pixel's other labels cost more: a tenth more than the tile's unary range
    plus four of its dearest edges (more than any change of label can save)."""
    edges = max(
        (float(pair.max()) for pair in (costs.pair_h, costs.pair_v) if pair.size), default=0.0
    )
    return 1.1 * (float(np.ptp(costs.unary)) + 4 * edges) + 1e-6


def merge(inputs: LevelInputs, results: list[BundleResult], config: MatchConfig) -> LevelSolution:
    """The level from the host's labels and the solved tiles: each tile's answer is kept only
    where it lowers the energy (each connected part of its changes on its own,
    :func:`_keep_improving`), priced against its neighbours' labels as they are when it is
    considered (tiles in row-major order), so the level's energy is at most the host's.

    Parameters
    ----------
    inputs : LevelInputs
        The level, after :func:`prepare` (``initial_labels`` are the host's).
    results : list of BundleResult
        The solved tiles, any order.
    config : MatchConfig
        The run's configuration.

    Returns
    -------
    LevelSolution
        ``residual``: the level's :class:`Residual` counts.
    """
    recorded = inputs.prepared["settle"]
    assert inputs.initial_labels is not None
    labels = inputs.initial_labels.copy()
    stages = host_stages(inputs)
    height = inputs.view_height
    grids = [inputs.grid(config, v * height, (v + 1) * height) for v in range(inputs.views)]
    improved = changed = 0
    for result in sorted(results, key=lambda r: (r.row_start, r.col_start)):
        view = result.row_start // height
        top = result.row_start - view * height
        rows = slice(top, top + result.labels.shape[0])
        columns = slice(result.col_start, result.col_start + result.labels.shape[1])
        view_labels = labels[view * height : (view + 1) * height]  # a view: written in place
        view_stages = stages[view * height : (view + 1) * height]
        proposed_stages = Stage.SOLVER if result.stages is None else result.stages
        kept = _keep_improving(
            grids[view], view_labels, rows, columns, result.labels, view_stages, proposed_stages
        )
        improved, changed = improved + (kept > 0), changed + kept
    energy = sum(
        grids[v].energy(labels[v * height : (v + 1) * height]) for v in range(inputs.views)
    )
    counts = _counts(recorded)
    residual = Residual(
        **{**counts.as_dict(), "tiles_improved": improved, "pixels_improved": changed}
    )
    prepared = {k: v for k, v in inputs.prepared.items() if k != "settle"}
    timing: dict[str, float] = {}
    for result in results:
        for key, value in result.timing.items():
            timing[key] = timing.get(key, 0.0) + float(value)
    return LevelSolution(
        labels=labels,
        energy=float(energy),
        repaired=int(sum(r.repaired for r in results)),
        bundles=len(results),
        solver_seconds=float(sum(r.wall_time for r in results)) + counts.host_seconds,
        timing=timing,
        info=embedding_summary(results, prepared),
        lower_bound=float(recorded["lower_bound"]),
        residual=residual.as_dict(),
        stages=stages,
    )


def _keep_improving(
    grid: GridMRF,
    labels: np.ndarray,
    rows: slice,
    columns: slice,
    proposed: np.ndarray,
    stages: np.ndarray,
    proposed_stages: np.ndarray | int,
) -> int:
    """Write into ``labels`` each connected part of a tile's answer that lowers the level's
    energy, given the labels around it as they are; return the pixels changed. The kept
    parts' provenance codes go into ``stages`` (a pinned, certified pixel stays certified).

    A part is a 4-connected set of pixels where ``proposed`` differs from ``labels``: two parts
    share no edge, so their energy changes add up and keeping exactly the parts that lower the
    energy is the best of the answer's subsets. A part that leaves the energy as it is (within
    float rounding) keeps the host's labels: the annealer's answer wins only where it is
    strictly better, never on a tie, and a pixel changed without lowering the energy (e.g. one
    the tile's own problem left free beside an improving part) stays the host's.
    """
    from scipy import ndimage  # slow to import: only where tiles are merged

    current = labels[rows, columns]
    parts, count = ndimage.label(current != proposed)
    tile_stages = stages[rows, columns]  # a view: written in place
    codes = np.broadcast_to(np.asarray(proposed_stages, dtype=stages.dtype), proposed.shape)
    kept = 0
    for part in range(1, count + 1):
        where = parts == part
        candidate = np.where(where, proposed, labels[rows, columns])
        before, after = _tile_energies(grid, labels, rows, columns, candidate)
        if after < before - 1e-9 * max(1.0, abs(before)):
            labels[rows, columns] = candidate
            settled = where & (tile_stages != Stage.CERTIFIED)
            tile_stages[settled] = codes[settled]
            kept += int(where.sum())
    return kept


def host_stages(inputs: LevelInputs) -> np.ndarray:
    """A settled level's provenance codes before its tiles: :attr:`Stage.CERTIFIED`, and
    :attr:`Stage.HOST` at the pixels the host left unsettled."""
    stages = np.full(inputs.shape, int(Stage.CERTIFIED), dtype=np.uint8)
    loose = np.asarray(inputs.prepared["settle"]["unsettled_pixels"], dtype=np.int64)
    if loose.size:
        stages[loose[:, 0], loose[:, 1]] = Stage.HOST
    return stages


def _tile_energies(
    grid: GridMRF, labels: np.ndarray, rows: slice, columns: slice, proposed: np.ndarray
) -> tuple[float, float]:
    """The energy of a tile's terms (its unaries, its own edges, its edges to the fixed pixels
    around it) with its current labels and with ``proposed``: their difference is the level's."""
    height, width = grid.shape
    window = (
        slice(max(rows.start - 1, 0), min(rows.stop + 1, height)),
        slice(max(columns.start - 1, 0), min(columns.stop + 1, width)),
    )
    around = grid.tile(*window)
    inner = (
        slice(rows.start - window[0].start, rows.stop - window[0].start),
        slice(columns.start - window[1].start, columns.stop - window[1].start),
    )
    extra = boundary_unary(around, labels[window], *inner)
    tile = around.tile(*inner, extra)
    return tile.energy(labels[rows, columns]), tile.energy(proposed)
