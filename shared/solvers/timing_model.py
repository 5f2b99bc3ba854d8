"""What one metered D-Wave call costs: the QPU timing model, the hybrid charge, and who is
metered at all.

QPU model (D-Wave, "Operation and Timing" > "Breakdown of QPU Access Time"; SAPI timing fields):

    qpu_access_time = T_p + R * (T_a + T_r + T_d)

``T_p`` programming time (typical programming time + programming thermalization), ``R`` reads,
``T_a`` annealing time, ``T_r`` readout time (a piecewise-linear function of the number of
qubits in log-log space) and ``T_d`` the per-sample delay (plus readout thermalization). The
arithmetic is dwave-cloud-client's own ``StructuredSolver.estimate_qpu_access_time``; with a live
solver its ``problem_timing_data`` property is used, offline the Advantage_system4.1 values of
August 2022 below (as published by D-Wave and recorded in dwave-cloud-client's test data).

The QPU model needs the number of *qubits*, known only after embedding
(:mod:`shared.solvers.bundle_shapes` looks actual embeddings up). Once a bundle structure
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

All functions return seconds. Per level and per job the estimates are
:mod:`shared.solvers.qpu_time`'s.
"""

from __future__ import annotations

from functools import cache
from typing import TYPE_CHECKING, Any

import numpy as np

from shared.solvers.params import DEFAULT_NUM_READS, schema_defaults
from shared.solvers.registry import UnknownSolver, spec

if TYPE_CHECKING:
    from shared.solvers.embedding_cache import EmbeddingSize

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
    """The model a job on ``solver_name`` is charged with: ``"qpu"`` (the QPU timing model),
    ``"hybrid"`` (Leap's hybrid charge), or None for an unmetered or unknown solver.

    It is the registry's ``SolverSpec.meter``, read when asked, so a solver registered at any
    time (``register()``, a ``qhsm.solvers`` entry point) is estimated like the built-in ones.
    The offline stand-ins are metered too: they are charged what the model says the real service
    would take, so the accounting can be exercised without a token.
    """
    try:
        return spec(solver_name).meter
    except UnknownSolver:
        return None


def is_metered(solver_name: str) -> bool:
    """Whether jobs on ``solver_name`` spend (real or simulated) D-Wave time from a budget:
    the QPU and hybrid solvers, their offline stand-ins and any metered plugin (:func:`meter_of`
    names a model); False for unknown names."""
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
