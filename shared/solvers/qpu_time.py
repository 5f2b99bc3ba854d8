"""Estimates of metered D-Wave time, before anything is sent: per level and per job.

The service reserves a bundle's estimate from its owner's budget before the bundle goes to the
QPU (or the hybrid solver) and settles the reservation with the time the sample set reports, so
the estimate only has to be a sensible upper-ish bound; the charge is always the reported time.

The cost of one call is :mod:`shared.solvers.timing_model`'s, the shapes the levels' bundles take
and their known embeddings :mod:`shared.solvers.bundle_shapes`'; this module walks the planned
levels. The names of both are re-exported here, where the service and the tests have always
imported the model from.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from shared.bundles import bundle_rows, segment_columns
from shared.config import MatchConfig
from shared.encodings import get_codec
from shared.pyramid import level_shape, plan
from shared.residual import LevelResidual
from shared.solvers.bundle_shapes import (
    AUTO_VARIABLES_GUESS,
    auto_width_key,
    bundle_digest,
    known_embedding,
    segment_width,
    shape_bqm,
)
from shared.solvers.embedding_cache import EmbeddingCache
from shared.solvers.qpu_settings import reverse_anneal
from shared.solvers.registry import uses_warm_start
from shared.solvers.timing_model import (
    ADVANTAGE_TIMING_DATA,
    HYBRID_MAX_VARIABLES,
    HYBRID_MINIMUM_TIME_LIMIT,
    MAX_QUBITS,
    QUBITS_PER_VARIABLE,
    assumed_qubits,
    bundle_seconds,
    charged_seconds,
    hybrid_charge_seconds,
    hybrid_level_seconds,
    is_metered,
    meter_of,
    qpu_access_seconds,
)

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
    "bundle_digest",
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
    config: MatchConfig,
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
    config : MatchConfig
        The run's configuration.
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
        What tile certificates and roof duality leave of the level's bundles
        (:func:`shared.residual.survey`); None: every bundle is assumed sent whole (an upper
        bound).

    Returns
    -------
    LevelEstimate
        Bundles, variables per bundle, qubits and the total estimated seconds of the level.
    """
    height, width = shape
    rows = bundle_rows(height, config.bundle_height)
    tallest = max(stop - start for start, stop in rows)
    columns = segment_width(config, config.bundle_height, width, candidates, cache) or width
    segments = len(segment_columns(width, columns, config.bundle_margin))
    bundles = views * len(rows) * segments
    variables = tallest * columns * get_codec(config.encoding).variables_per_pixel(candidates)
    params = sampler_params(config.solver_params, warm=uses_warm_start(config))
    embedding = known_embedding(
        cache, config.solver, config.encoding, (tallest, columns), candidates
    )
    if residual is None:  # (job_residual gives None when nothing is solved on the host)
        residual = LevelResidual(0, 1.0, 1.0, 1.0)
    sent = round(residual.sent_share * bundles)
    kept = residual.sent_variables_share  # of a sent bundle's variables (and qubits)
    qubits = None
    if meter_of(config.solver) == "qpu":  # rests packed: `together` per QPU call
        whole = embedding.qubits if embedding else assumed_qubits(variables)
        qubits = max(1, round(whole * kept))
        from shared.solvers.packing import packed_copies

        shape = (tallest, columns)
        together = min(max(sent, 1), packed_copies(cache, config, shape, candidates))
        calls = -(-sent // together)
        seconds = calls * bundle_seconds(
            config.solver, variables, params, num_qubits=min(MAX_QUBITS, together * qubits)
        )
    elif meter_of(config.solver) == "hybrid":  # the level's rests joined into blocks
        seconds = hybrid_level_seconds(bundles * variables * residual.variables_share, params)
    else:
        seconds = sent * bundle_seconds(config.solver, max(1, round(variables * kept)), params)
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
    )


def job_seconds(
    config: MatchConfig,
    shape: tuple[int, int],
    max_disparity: int,
    cache: EmbeddingCache | None = None,
    residual: list[LevelResidual] | None = None,
) -> JobEstimate:
    """Estimate a job before accepting it: total seconds and bundles, and one
    :class:`LevelEstimate` per level, from the image ``shape`` (height, width), its resolved
    ``max_disparity``, the pyramid and the solver parameters; nothing is embedded or solved.

    ``cache`` is where the actual embeddings of earlier jobs are looked up (the service's shared
    store; None: assumptions only); ``residual`` what roof duality leaves per level
    (:func:`shared.residual.job_residual`; None: bundles sent whole).
    """
    views = 2 if config.lr_check else 1
    levels = [
        level_estimate(
            config,
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
