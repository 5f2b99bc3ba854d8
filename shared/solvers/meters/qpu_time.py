"""Estimates of metered D-Wave time, before anything is sent: per level and per job, and what a
worker reserves for a task's bundles.

The service reserves a bundle's estimate from its owner's budget before the bundle goes to the
QPU (or the hybrid solver) and settles the reservation with the time the sample set reports, so
the estimate only has to be a sensible upper-ish bound; the charge is always the reported time.

The cost of one call and how a level's bundles become calls are the solver's meter's
(:mod:`shared.solvers.meters`), the shapes the levels' bundles take and their known embeddings
:mod:`shared.solvers.qpu.bundle_shapes`'; this module walks the planned levels and asks them. The
meters' names are re-exported here, where the service and the tests have always imported the
model from.

Every estimate is handed the job's :class:`~shared.solvers.resolved.ResolvedSolver` (resolved
with its configuration, once, by the caller): its warm start, its parameter schema and, for the
live timing data, its sampler come from there; nothing here looks a solver up again.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from shared.bundles import bundle_rows, segment_columns
from shared.config import MatchConfig
from shared.encodings import get_codec
from shared.inference.table import settles
from shared.pyramid import level_shape, plan
from shared.residual import LevelResidual
from shared.settle import TILE, tiles_of
from shared.solvers.meters import (
    LevelLoad,
    Meter,
    bundle_seconds,
    charged_seconds,
    is_metered,
    meter_for,
    meter_of,
)
from shared.solvers.meters.hybrid import (
    HYBRID_MAX_VARIABLES,
    HYBRID_MINIMUM_TIME_LIMIT,
    hybrid_charge_seconds,
    hybrid_level_seconds,
)
from shared.solvers.meters.qpu import (
    ADVANTAGE_TIMING_DATA,
    MAX_QUBITS,
    QUBITS_PER_VARIABLE,
    assumed_qubits,
    qpu_access_seconds,
)
from shared.solvers.qpu.bundle_shapes import (
    AUTO_VARIABLES_GUESS,
    auto_width_key,
    bundle_digest,
    known_embedding,
    segment_width,
    shape_bqm,
)
from shared.solvers.qpu.embedding_cache import EmbeddingCache
from shared.solvers.qpu.packing import packed_copies
from shared.solvers.qpu.qpu_settings import reverse_anneal
from shared.solvers.resolved import ResolvedSolver

__all__ = [
    "ADVANTAGE_TIMING_DATA",
    "AUTO_VARIABLES_GUESS",
    "HYBRID_MAX_VARIABLES",
    "HYBRID_MINIMUM_TIME_LIMIT",
    "MAX_QUBITS",
    "QUBITS_PER_VARIABLE",
    "JobEstimate",
    "LevelEstimate",
    "assumed_qubits",
    "auto_width_key",
    "batch_estimate",
    "bundle_digest",
    "bundle_estimate",
    "bundle_seconds",
    "charged_seconds",
    "hybrid_charge_seconds",
    "hybrid_level_seconds",
    "is_metered",
    "job_seconds",
    "known_embedding",
    "level_estimate",
    "meter_of",
    "qpu_access_seconds",
    "sampler_params",
    "segment_width",
    "shape_bqm",
]


@dataclass(frozen=True)
class LevelEstimate:
    """One pyramid level: its bundles, their size and the estimated charge of all of them.

    ``qubits_per_bundle`` is the QPU qubit count the estimate used (None for hybrid solvers);
    ``embedding_known`` says whether it is an actual embedding's or the assumption's."""

    index: int
    shape: tuple[int, int]
    bundles: int
    variables_per_bundle: int
    seconds: float
    qubits_per_bundle: int | None = None
    embedding_known: bool = False
    #: Bundles expected to reach the metered solver (the rest roof duality solves on the host).
    bundles_sent: int | None = None
    #: Share of the level's variables expected to reach it.
    variables_share: float = 1.0
    #: The residual design (:mod:`shared.settle`): pixels the host certifies and pixels in the
    #: tiles sent (None without it, or without a survey).
    pixels_certified: int | None = None
    pixels_sent: int | None = None

    @property
    def classical_share(self) -> float:
        """Share of the level's bundles solved on the host (charged nothing)."""
        sent = self.bundles if self.bundles_sent is None else self.bundles_sent
        return 1.0 - sent / max(self.bundles, 1)

    def as_dict(self) -> dict[str, Any]:
        """The wire form (``POST /v1/estimate``, ``qhsm estimate --json``)."""
        return {
            "index": self.index,
            "height": self.shape[0],
            "width": self.shape[1],
            "bundles": self.bundles,
            "bundles_sent": self.bundles if self.bundles_sent is None else self.bundles_sent,
            "classical_share": self.classical_share,
            "variables_share": self.variables_share,
            "variables_per_bundle": self.variables_per_bundle,
            "qubits_per_bundle": self.qubits_per_bundle,
            "embedding_known": self.embedding_known,
            "pixels_certified": self.pixels_certified,
            "pixels_sent": self.pixels_sent,
            "seconds": self.seconds,
        }


@dataclass(frozen=True)
class JobEstimate:
    """The estimated metered time of a whole job (0 for unmetered solvers)."""

    solver: str
    seconds: float
    bundles: int
    levels: list[LevelEstimate] = field(default_factory=list)

    @property
    def bundles_sent(self) -> int:
        """Bundles expected to reach the metered solver."""
        return sum(level.bundles - round(level.classical_share * level.bundles)
                   for level in self.levels)  # fmt: skip

    def as_dict(self) -> dict[str, Any]:
        return {
            "solver": self.solver,
            "metered": is_metered(self.solver),
            "seconds": self.seconds,
            "bundles": self.bundles,
            "bundles_sent": self.bundles_sent,
            "classical_share": 1.0 - self.bundles_sent / max(self.bundles, 1),
            "levels": [level.as_dict() for level in self.levels],
        }


def sampler_params(solver_params: dict[str, Any], warm: bool) -> dict[str, Any]:
    """The QPU parameters a bundle is sent with: a warm-started bundle (``warm_start`` and a
    coarser estimate) is a reverse anneal with the adapter's schedule, re-initialised per read.

    Parameters
    ----------
    solver_params : dict
        The job's ``solver_params``; ``warm_start`` is dropped.
    warm : bool
        Whether the bundle is warm-started.

    Returns
    -------
    dict
        A new dict of the QPU parameters (the reverse-anneal ones added when warm).
    """
    params = {key: value for key, value in solver_params.items() if key != "warm_start"}
    if warm:  # only the initial state's presence matters to the model
        reverse_anneal(params, [(0, 1)], given_win=True)
    return params


def level_estimate(
    solver: ResolvedSolver,
    index: int,
    shape: tuple[int, int],
    candidates: int,
    views: int = 1,
    cache: EmbeddingCache | None = None,
    residual: LevelResidual | None = None,
) -> LevelEstimate:
    """Bundle count x per-bundle time of level ``index`` (``shape`` = one view's height, width;
    ``views`` = 2 with the left-right check, whose right view has as many bundles again).

    Every bundle is estimated at the size of the level's largest bundle, with that bundle
    shape's actual embedding when ``cache`` knows one.

    Parameters
    ----------
    solver : ResolvedSolver
        The run's solver, resolved with its configuration.
    index : int
        The level's index in the pyramid.
    shape : (int, int)
        One view's height and width at the level, pixels.
    candidates : int
        Labels per pixel at the level.
    views : int, default 1
        1, or 2 with the left-right check.
    cache : EmbeddingCache, optional
        Where known embedding sizes and ``auto`` widths are looked up.
    residual : LevelResidual, optional
        What the host's settling and roof duality leave of the level's bundles
        (:func:`shared.residual.survey`); None: every bundle is assumed sent whole (an upper
        bound).

    Returns
    -------
    LevelEstimate
        Bundles, variables per bundle, qubits and the total estimated seconds of the level.
    """
    config = _config(solver)
    height, width = shape
    if settles(solver):  # the residual design: 4x4 tiles (shared.settle)
        tallest, columns = min(TILE, height), min(TILE, width)
        bundles = tiles_of(height, width, views)
    else:
        rows = bundle_rows(height, config.bundle_height)
        tallest = max(stop - start for start, stop in rows)
        columns = segment_width(config, config.bundle_height, width, candidates, cache) or width
        segments = len(segment_columns(width, columns, config.bundle_margin))
        bundles = views * len(rows) * segments
    variables = tallest * columns * get_codec(config.encoding).variables_per_pixel(candidates)
    params = sampler_params(config.solver_params, warm=solver.warm_start)
    embedding = known_embedding(
        cache, config.solver, config.encoding, (tallest, columns), candidates
    )
    if residual is None:  # (job_residual gives None when nothing is solved on the host)
        residual = LevelResidual(0, 1.0, 1.0, 1.0)
    sent = round(residual.sent_share * bundles)
    seconds, qubits = 0.0, None
    meter = meter_for(config.solver)
    if meter is not None:
        load = LevelLoad(
            bundles=bundles,
            sent=sent,
            variables=variables,
            kept=residual.sent_variables_share,  # of a sent bundle's variables (and qubits)
            variables_share=residual.variables_share,
            qubits=embedding.qubits if embedding else None,
            together=(  # a shape's disjoint copies on the QPU graph, one call
                packed_copies(cache, config, (tallest, columns), candidates, settles(solver))
                if meter.embeds
                else 1
            ),
        )
        seconds, qubits = meter.level_seconds(solver, params, load)
    return LevelEstimate(
        index=index,
        shape=(height, width),
        bundles=bundles,
        variables_per_bundle=variables,
        seconds=seconds,
        qubits_per_bundle=qubits,
        embedding_known=embedding is not None,
        bundles_sent=sent,
        variables_share=residual.variables_share,
        pixels_certified=residual.certified,
        pixels_sent=None if residual.tiles is None else residual.tiles * tallest * columns,
    )


def job_seconds(
    solver: ResolvedSolver,
    shape: tuple[int, int],
    max_disparity: int,
    cache: EmbeddingCache | None = None,
    residual: list[LevelResidual] | None = None,
) -> JobEstimate:
    """Estimate a job before accepting it: total seconds and bundles, and one
    :class:`LevelEstimate` per level, from the run's ``solver`` (resolved with its
    configuration), the image ``shape`` (height, width), its resolved ``max_disparity``, the
    pyramid and the solver parameters; nothing is embedded or solved.

    ``cache`` is where the actual embeddings of earlier jobs are looked up (the service's shared
    store; None: assumptions only); ``residual`` what roof duality leaves per level
    (:func:`shared.residual.job_residual`; None: bundles sent whole).
    """
    config = _config(solver)
    views = 2 if config.lr_check else 1
    levels = [
        level_estimate(
            solver,
            level.index,
            level_shape(shape, level.downsample),
            level.candidates,
            views,
            cache,
            residual[position] if residual else None,
        )
        for position, level in enumerate(plan(config, max_disparity))
    ]
    return JobEstimate(
        solver=config.solver,
        seconds=float(sum(level.seconds for level in levels)),
        bundles=sum(level.bundles for level in levels),
        levels=levels,
    )


# --- what a worker reserves for the bundles it is about to send -------------------------------


def _config(solver: ResolvedSolver) -> MatchConfig:
    if solver.config is None:
        raise ValueError(f"{solver.spec.name} was resolved without the job's configuration")
    return solver.config


def _call_basis(
    inputs, config: MatchConfig, solver: ResolvedSolver
) -> tuple[Meter, int, int, dict[str, Any]] | None:
    """What a worker's reservation is estimated with: the solver's meter, the level's labels
    per pixel, binary variables per pixel and the sampler parameters; None when unmetered."""
    meter = meter_for(config.solver)
    if meter is None:
        return None
    labels = inputs.count
    per_pixel = get_codec(config.encoding).variables_per_pixel(labels)
    warm = solver.warm_start
    return meter, labels, per_pixel, sampler_params(config.solver_params, warm)


def bundle_estimate(
    inputs, config, start: int, stop: int, columns: int | None = None, *, solver: ResolvedSolver
) -> float:
    """Estimated charge of the bundle of rows [start, stop) of a level (no BQM is built), with
    the shape's actual embedding once any worker has embedded one and, with a D-Wave token, the
    live solver's own timing data: the amount reserved before it is sent.

    Parameters
    ----------
    inputs
        The level's inputs (``shared.bundles``), for its candidate labels.
    config
        The job's ``MatchConfig`` (solver, encoding, solver parameters).
    start, stop : int
        The bundle's rows.
    columns : int or None
        Width of a row segment; None: whole rows.
    solver : ResolvedSolver
        The job's solver, resolved once for the task (warm start, live timing data).

    Returns
    -------
    float
        Seconds to reserve for the bundle.
    """
    from shared.solvers.qpu.embedding_cache import default_cache

    basis = _call_basis(inputs, config, solver)
    if basis is None:
        return 0.0
    meter, labels, per_pixel, params = basis
    width = inputs.shape[1] if columns is None else columns
    variables = (stop - start) * width * per_pixel
    if not meter.embeds:
        return bundle_seconds(config.solver, variables, params)
    embedding = known_embedding(
        default_cache(), config.solver, config.encoding, (stop - start, width), labels
    )
    live = meter.timing_source(solver)
    return bundle_seconds(config.solver, variables, params, embedding=embedding, solver=live)


def batch_estimate(inputs, config, bundles: list, *, solver: ResolvedSolver) -> float:
    """Estimated charge of bundles sent as one batch, before roof duality (an upper bound): the
    meter's charge of them as a level's load (QPU: each shape's bundles in packed calls, as the
    job's estimate counts them; hybrid: joined into blocks of the solver's size).

    Parameters
    ----------
    inputs
        The level's inputs.
    config
        The job's ``MatchConfig``.
    bundles : list of Bundle
        The batch.
    solver : ResolvedSolver
        The job's solver, resolved once for the task.

    Returns
    -------
    float
        Seconds to reserve for the whole batch (one reservation).
    """
    basis = _call_basis(inputs, config, solver)
    if basis is None:
        return 0.0
    meter, labels, per_pixel, params = basis
    if not meter.embeds:  # one load: every bundle's variables
        pixels = sum((b.row_stop - b.row_start) * (b.col_stop - b.col_start) for b in bundles)
        load = LevelLoad(bundles=1, sent=1, variables=pixels * per_pixel)
        return meter.level_seconds(solver, params, load)[0]
    from shared.solvers.qpu.embedding_cache import default_cache

    cache = default_cache()
    live = meter.timing_source(solver)
    groups: dict[tuple[int, int], list] = {}
    for bundle in bundles:
        groups.setdefault(bundle.shape, []).append(bundle)
    seconds = 0.0
    for shape, group in groups.items():  # one load per shape: its embedding, its copies
        size = known_embedding(cache, config.solver, config.encoding, shape, labels)
        load = LevelLoad(
            bundles=len(group),
            sent=len(group),
            variables=shape[0] * shape[1] * per_pixel,
            qubits=size.qubits if size else None,
            together=packed_copies(cache, config, shape, labels),
        )
        seconds += meter.level_seconds(solver, params, load, live=live)[0]
    return seconds
