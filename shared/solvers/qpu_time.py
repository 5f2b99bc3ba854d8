"""Estimates of metered D-Wave time, before anything is sent: per bundle and per job.

The service reserves a bundle's estimate from its owner's budget before the bundle goes to the
QPU (or the hybrid solver) and settles the reservation with the time the sample set reports, so
the estimate only has to be a sensible upper-ish bound; the charge is always the reported time.

QPU model (D-Wave, "Operation and Timing" > "Breakdown of QPU Access Time"; SAPI timing fields):

    qpu_access_time = T_p + R * (T_a + T_r + T_d)

``T_p`` programming time (typical programming time + programming thermalization), ``R`` reads,
``T_a`` annealing time, ``T_r`` readout time (a piecewise-linear function of the number of
qubits in log-log space) and ``T_d`` the per-sample delay (plus readout thermalization). The
arithmetic is dwave-cloud-client's own ``StructuredSolver.estimate_qpu_access_time``; with a live
solver its ``problem_timing_data`` property is used, offline the Advantage_system4.1 values of
August 2022 below (as published by D-Wave and recorded in dwave-cloud-client's test data).

The QPU model needs the number of *qubits*, known only after embedding. Once a bundle structure
has been embedded (by any worker: the embedding cache records each embedding's size per solver),
estimates use that embedding's qubit count. Before, we assume :data:`QUBITS_PER_VARIABLE` qubits
per binary variable: on Pegasus a full-resolution domain-wall Tsukuba row (1152 variables)
embedded in 1956 qubits (1.7 per variable), so 2 is a slight overestimate; readout time grows
only logarithmically with the qubit count (and is flat above ~1500 qubits), so the error this
factor makes is small.

Charges: ``qpu`` and ``hybrid`` are charged what D-Wave reports. The offline stand-ins have no real
timing, so they are charged what this model says the real service would take for the same problem
(``qpu-sim``: :func:`qpu_access_seconds` of its actual embedding and parameters; ``hybrid-sim``:
:func:`hybrid_charge_seconds` of its size), so that their estimates and charges agree as the real
ones do.

Hybrid model: Leap's hybrid BQM solver charges about its run time, which is the requested
``time_limit`` or, when unset, the solver's minimum for the problem size (the
``minimum_time_limit`` property: a piecewise-linear curve in the number of variables). Offline we
use the curve Leap's ``hybrid_binary_quadratic_model_version2`` reports (3 s up to 1024
variables, 10 s at 4096, 40 s at 10000, ...).

All functions return seconds. (About 360 lines of code, the rest numpydoc: the timing data and
the job-level estimate, which walks the planned levels and their bundle shapes, belong with the
model they feed.)
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from functools import cache, lru_cache
from typing import Any

import numpy as np

from shared.bundles import bundle_rows, segment_columns
from shared.config import AUTO, MatchConfig
from shared.encodings import get_codec
from shared.energy import Costs
from shared.pyramid import level_shape, plan
from shared.residual import LevelResidual
from shared.solvers.base import uses_warm_start
from shared.solvers.embedding_cache import EmbeddingCache, EmbeddingSize, structure_digest
from shared.solvers.params import DEFAULT_NUM_READS, schema_defaults
from shared.solvers.registry import UnknownSolver, spec

log = logging.getLogger(__name__)

#: Advantage_system4.1 ``problem_timing_data`` (August 2022), microseconds.
ADVANTAGE_TIMING_DATA: dict[str, Any] = {
    "version": "1.0.0",
    "typical_programming_time": 14072.88,
    "reverse_annealing_with_reinit_prog_time_delta": 0.0,
    "reverse_annealing_without_reinit_prog_time_delta": 5.55,
    "default_programming_thermalization": 1000.0,
    "default_annealing_time": 20.0,
    "readout_time_model": "pwl_log_log",
    "readout_time_model_parameters": [
        0.0,
        0.7699665876947938,
        1.7242758696010096,
        2.711975459489206,
        3.1639057672764026,
        3.750276915153992,
        1.539131714800995,
        1.8726623164229292,
        2.125631787097315,
        2.332672340068556,
        2.371606651233025,
        2.3716219271760215,
    ],
    "qpu_delay_time_per_sample": 20.54,
    "reverse_annealing_with_reinit_delay_time_delta": -4.5,
    "reverse_annealing_without_reinit_delay_time_delta": -1.5,
    "default_readout_thermalization": 0.0,
    "decorrelation_max_nominal_anneal_time": 2000.0,
    "decorrelation_time_range": [500.0, 10000.0],
}

#: ``minimum_time_limit`` of hybrid_binary_quadratic_model_version2: [variables, seconds] pairs.
HYBRID_MINIMUM_TIME_LIMIT: list[list[float]] = [
    [1, 3.0],
    [1024, 3.0],
    [4096, 10.0],
    [10000, 40.0],
    [30000, 200.0],
    [100000, 600.0],
    [1000000, 600.0],
]

#: Variables of one hybrid problem at most (Leap's hybrid BQM solver's
#: ``maximum_number_of_variables``): a level's bundles are joined into blocks of this size.
HYBRID_MAX_VARIABLES = 1_000_000

#: Qubits per binary variable assumed before an embedding exists (see the module docstring).
QUBITS_PER_VARIABLE = 2.0
#: Working qubits of an Advantage (Pegasus P16) QPU: no embedding uses more.
MAX_QUBITS = 5627

#: The QPU parameters the timing model reads (others do not change the access time).
_QPU_TIMING_PARAMS = (
    "annealing_time",
    "anneal_schedule",
    "initial_state",
    "reinitialize_state",
    "programming_thermalization",
    "readout_thermalization",
    "reduce_intersample_correlation",
)


def meter_of(solver_name: str) -> str | None:
    """The model a job on this solver is charged with: the registry's ``SolverSpec.meter``,
    read when asked, so a solver registered at any time (``register()``, a ``qhsm.solvers``
    entry point) is estimated like the built-in ones. The offline stand-ins are metered too:
    they are charged what the model says the real service would take, so the accounting can be
    exercised without a token.

    Parameters
    ----------
    solver_name : str
        A registry name (or any string).

    Returns
    -------
    str or None
        ``"qpu"`` (the QPU timing model), ``"hybrid"`` (Leap's hybrid charge), or None for an
        unmetered or unknown solver.
    """
    try:
        return spec(solver_name).meter
    except UnknownSolver:
        return None


def is_metered(solver_name: str) -> bool:
    """Whether jobs on this solver spend (real or simulated) D-Wave time from a budget.

    Parameters
    ----------
    solver_name : str
        A registry name (or any string).

    Returns
    -------
    bool
        True when :func:`meter_of` names a model (the QPU and hybrid solvers, their offline
        stand-ins and any metered plugin); False for unknown names.
    """
    return meter_of(solver_name) is not None


def charged_seconds(timing: dict[str, float]) -> float:
    """What one solve costs its owner: the hybrid ``charge_time`` when reported, else the
    ``qpu_access_time`` (both already in seconds in a ``SolveResult``); 0 when neither.

    Parameters
    ----------
    timing : dict of str to float
        ``SolveResult.timing`` of one solve, in seconds.

    Returns
    -------
    float
        Seconds charged, never negative.
    """
    for key in ("charge_time", "qpu_access_time"):
        value = timing.get(key)
        if value is not None:
            return max(0.0, float(value))
    return 0.0


@cache
def _reference_solver(timing_key: str = "advantage"):
    """A cloud-client solver object carrying only the offline timing data (no network)."""
    from dwave.cloud.solver import StructuredSolver

    data = {
        "identity": {"name": "offline-timing-model"},
        "status": "ONLINE",
        "description": "Advantage_system4.1 timing data (offline estimates)",
        "properties": {
            "category": "qpu",
            "supported_problem_types": ["ising", "qubo"],
            "qubits": [0],
            "couplers": [],
            "num_qubits": 1,
            "parameters": {"num_reads": ""},
            "problem_timing_data": ADVANTAGE_TIMING_DATA,
        },
    }
    return StructuredSolver(client=None, data=data)


def qpu_access_seconds(num_qubits: int, params: dict[str, Any] | None = None, solver=None) -> float:
    """Estimated QPU access time of one problem on ``num_qubits`` qubits with these sampler
    parameters. ``solver`` is a live ``dwave.cloud`` solver (its own timing data); default:
    the offline Advantage model.

    Parameters
    ----------
    num_qubits : int
        Qubits the embedded problem uses (at least 1 is assumed).
    params : dict, optional
        Sampler parameters; ``num_reads`` (default ``DEFAULT_NUM_READS``) and the annealing and
        thermalization parameters the model reads.
    solver : dwave.cloud solver, optional
        Whose ``estimate_qpu_access_time`` is used; None: the offline Advantage_system4.1 model.

    Returns
    -------
    float
        Estimated ``qpu_access_time``, seconds.
    """
    params = params or {}
    solver = solver or _reference_solver()
    options = {key: params[key] for key in _QPU_TIMING_PARAMS if params.get(key) is not None}
    reads = int(params.get("num_reads") or DEFAULT_NUM_READS)
    micros = solver.estimate_qpu_access_time(max(1, int(num_qubits)), num_reads=reads, **options)
    return float(micros) * 1e-6


def hybrid_charge_seconds(
    num_variables: int,
    params: dict[str, Any] | None = None,
    minimum_time_limit: list[list[float]] | None = None,
) -> float:
    """Estimated charge of one hybrid BQM problem: ``time_limit`` if given, never below the
    solver's minimum for ``num_variables`` (LeapHybridSampler.min_time_limit's interpolation).

    Parameters
    ----------
    num_variables : int
        Binary variables of the problem.
    params : dict, optional
        Solver parameters; only ``time_limit`` (seconds) is read.
    minimum_time_limit : list of [variables, seconds], optional
        The solver's ``minimum_time_limit`` curve; default :data:`HYBRID_MINIMUM_TIME_LIMIT`.

    Returns
    -------
    float
        Estimated ``charge_time``, seconds.
    """
    params = params or {}
    curve = np.asarray(minimum_time_limit or HYBRID_MINIMUM_TIME_LIMIT, dtype=float)
    minimum = float(np.interp(num_variables, curve[:, 0], curve[:, 1]))
    requested = params.get("time_limit")
    return max(minimum, float(requested)) if requested is not None else minimum


def hybrid_level_seconds(variables: float, params: dict[str, Any] | None = None) -> float:
    """Charge of ``variables`` sent to the hybrid solver as blocks of at most
    :data:`HYBRID_MAX_VARIABLES` (``shared.solvers.hybrid``: a level's rests, joined).

    Parameters
    ----------
    variables : float
        Variables left of the level's bundles (0: nothing is sent).
    params : dict, optional
        Solver parameters (``time_limit``).

    Returns
    -------
    float
        Seconds: the blocks' charges, the variables shared evenly between them.
    """
    if variables <= 0:
        return 0.0
    count = int(np.ceil(variables / HYBRID_MAX_VARIABLES))
    return count * hybrid_charge_seconds(max(1, round(variables / count)), params)


def assumed_qubits(num_variables: int) -> int:
    """Qubits assumed for a bundle whose structure has not been embedded yet.

    Parameters
    ----------
    num_variables : int
        Binary variables of the bundle's QUBO.

    Returns
    -------
    int
        ``QUBITS_PER_VARIABLE`` qubits per variable, rounded up, at most :data:`MAX_QUBITS`.
    """
    return min(MAX_QUBITS, int(np.ceil(num_variables * QUBITS_PER_VARIABLE)))


def bundle_seconds(
    solver_name: str,
    num_variables: int,
    params: dict[str, Any] | None = None,
    *,
    num_qubits: int | None = None,
    embedding: EmbeddingSize | None = None,
    solver=None,
) -> float:
    """Estimated charge of one bundle of ``num_variables`` binary variables; 0 if unmetered.

    ``embedding`` (or ``num_qubits``) is the bundle's actual embedding when known; ``solver`` a
    live cloud solver whose ``estimate_qpu_access_time`` and timing data replace the offline
    model.

    Parameters
    ----------
    solver_name : str
        Registry name of the solver.
    num_variables : int
        Binary variables of the bundle's QUBO.
    params : dict, optional
        The bundle's sampler parameters (over the schema's defaults for QPU solvers).
    num_qubits : int, optional
        Qubits of the bundle's embedding; default :func:`assumed_qubits`.
    embedding : EmbeddingSize, optional
        The actual embedding's size; its qubits win over ``num_qubits``.
    solver : dwave.cloud solver, optional
        Live solver for the QPU model (None: the offline model).

    Returns
    -------
    float
        Estimated metered seconds of the bundle.
    """
    meter = meter_of(solver_name)
    if meter == "qpu":
        if embedding is not None:
            num_qubits = embedding.qubits
        if num_qubits is None:
            num_qubits = assumed_qubits(num_variables)
        # what the solver runs with when a parameter is not given (qpu-sim reads fewer than qpu)
        params = {**schema_defaults(spec(solver_name).params), **(params or {})}
        return qpu_access_seconds(num_qubits, params, solver)
    if meter == "hybrid":
        return hybrid_charge_seconds(num_variables, params)
    return 0.0


def shape_bqm(encoding: str, height: int, width: int, candidates: int):
    """The QUBO of a bundle of this shape with zero costs: the QUBO's graph does not depend on
    the costs (zero terms are kept), so it has the structure of every bundle of the shape.

    Parameters
    ----------
    encoding : str
        Label encoding (``one-hot``, ``domain-wall``, ...), a codec name.
    height, width : int
        Bundle size in pixels (rows, columns).
    candidates : int
        Disparity labels per pixel.

    Returns
    -------
    dimod.BinaryQuadraticModel
        The codec's QUBO of all-zero costs.
    """
    zeros = np.zeros((height, width, candidates))
    costs = Costs(
        candidates=np.zeros((height, width, candidates), dtype=np.int32),
        unary=zeros,
        pair_h=np.zeros((height, max(0, width - 1), candidates, candidates)),
        pair_v=np.zeros((max(0, height - 1), width, candidates, candidates)),
    )
    return get_codec(encoding).encode(costs)


@lru_cache(maxsize=256)
def bundle_digest(encoding: str, height: int, width: int, candidates: int) -> str:
    """Structure digest of every bundle of this shape (:func:`shape_bqm`).

    Parameters
    ----------
    encoding : str
        Codec name of the label encoding.
    height, width : int
        Bundle rows and columns, pixels.
    candidates : int
        Labels per pixel.

    Returns
    -------
    str
        The :func:`~shared.solvers.embedding_cache.structure_digest` (cached per shape).
    """
    return structure_digest(shape_bqm(encoding, height, width, candidates))


def known_embedding(
    cache: EmbeddingCache | None,
    solver_name: str,
    encoding: str,
    shape: tuple[int, int],
    candidates: int,
) -> EmbeddingSize | None:
    """The size of the embedding ``solver_name`` uses for bundles of ``shape`` (rows, width)
    with ``candidates`` labels, if any worker has embedded one; None otherwise (and for
    solvers that do not embed).

    Parameters
    ----------
    cache : EmbeddingCache or None
        Where sizes are looked up; None: none known.
    solver_name : str
        Registry name of the solver.
    encoding : str
        Codec name of the label encoding.
    shape : (int, int)
        Bundle rows and columns, pixels.
    candidates : int
        Labels per pixel.

    Returns
    -------
    EmbeddingSize or None
        The recorded size; None when unknown, too large to embed, not a QPU solver, or the store
        is unreachable.
    """
    if cache is None or meter_of(solver_name) != "qpu":
        return None
    height, width = shape
    if height * width * get_codec(encoding).variables_per_pixel(candidates) > MAX_QUBITS:
        return None  # cannot embed, so never was (and its QUBO may be too big to build here)
    try:
        return cache.known_size(
            solver_name, bundle_digest(str(encoding), height, width, candidates)
        )
    except Exception as error:  # an unreachable store only costs us the better estimate
        log.warning("embedding sizes unavailable (%s); assuming %.1f qubits per variable",
                    error, QUBITS_PER_VARIABLE)  # fmt: skip
        return None


#: Before ``--bundle-width auto`` has run for a level shape, estimates assume segments of about
#: this many QUBO variables (64 domain-wall pixels of 6 labels; P16 embeds them in ~15 s).
AUTO_VARIABLES_GUESS = 320


def auto_width_key(
    solver_name: str, encoding: str, height: int, candidates: int, row_width: int, margin: int
) -> str:
    """Store key of the width ``auto`` chose for this level shape.

    Parameters
    ----------
    solver_name : str
        Registry name of the solver.
    encoding : str
        Codec name of the label encoding.
    height : int
        Bundle height, rows.
    candidates : int
        Labels per pixel.
    row_width : int
        The level's row width, pixels.
    margin : int
        ``bundle_margin``, pixels.

    Returns
    -------
    str
        A key for :meth:`~shared.solvers.embedding_cache.EmbeddingCache.record_width`.
    """
    return f"{solver_name}-{encoding}-{height}x{row_width}-{candidates}-{margin}"


def segment_width(
    config: MatchConfig,
    height: int,
    row_width: int,
    candidates: int,
    cache: EmbeddingCache | None,
) -> int | None:
    """The segment width the run will use on a level (None: whole rows): the configured one,
    or for ``auto`` (the QPU solvers' default) the width chosen before, else a guess.

    Parameters
    ----------
    config : MatchConfig
        The run's configuration (solver, encoding, bundle width and margin).
    height : int
        Bundle height, rows.
    row_width : int
        The level's row width, pixels.
    candidates : int
        Labels per pixel at the level.
    cache : EmbeddingCache or None
        Where an earlier ``auto`` choice is looked up; None: guess.

    Returns
    -------
    int or None
        Segment width in pixels; None for whole rows (also when the width is not below
        ``row_width``).
    """
    setting = config.bundle_width
    if setting is None and meter_of(config.solver) == "qpu":
        setting = AUTO
    if setting != AUTO:
        return setting if setting is None or setting < row_width else None
    if cache is not None:
        key = auto_width_key(
            config.solver, str(config.encoding), height, candidates, row_width, config.bundle_margin
        )
        try:
            known, width = cache.known_width(key)
        except Exception:  # an unreachable store only costs us the better estimate
            known, width = False, None
        if known:
            return width
    per_pixel = height * get_codec(config.encoding).variables_per_pixel(candidates)
    guess = max(2 * config.bundle_margin + 1, AUTO_VARIABLES_GUESS // per_pixel)
    return guess if guess < row_width else None


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
    if warm:
        from shared.solvers.dwave import WARM_START_SCHEDULE

        params.setdefault("anneal_schedule", WARM_START_SCHEDULE)
        params.setdefault("initial_state", [(0, 1)])  # only its presence matters to the model
        params.setdefault("reinitialize_state", True)
        params.pop("annealing_time", None)
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
    """Estimate a job before accepting it, from the image ``shape`` (height, width), its
    resolved ``max_disparity``, the pyramid and the solver parameters: nothing is embedded or
    solved. ``cache``: where the actual embeddings of earlier jobs are looked up (the service's
    shared store).

    Parameters
    ----------
    config : MatchConfig
        The job's configuration.
    shape : (int, int)
        Image height and width, pixels.
    max_disparity : int
        The resolved maximum disparity, pixels.
    cache : EmbeddingCache, optional
        The shared embedding cache; None: assumptions only.
    residual : list of LevelResidual, optional
        Per level, what roof duality leaves (:func:`job_residual`); None: bundles sent whole.

    Returns
    -------
    JobEstimate
        Total seconds and bundles, and one :class:`LevelEstimate` per level.
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

