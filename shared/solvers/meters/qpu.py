"""The ``qpu`` meter: D-Wave's QPU timing model, and a QPU solve charged its ``qpu_access_time``.

Model (D-Wave, "Operation and Timing" > "Breakdown of QPU Access Time"; SAPI timing fields):

    qpu_access_time = T_p + R * (T_a + T_r + T_d)

``T_p`` programming time (typical programming time + programming thermalization), ``R`` reads,
``T_a`` annealing time, ``T_r`` readout time (a piecewise-linear function of the number of
qubits in log-log space) and ``T_d`` the per-sample delay (plus readout thermalization). The
arithmetic is dwave-cloud-client's own ``StructuredSolver.estimate_qpu_access_time``; with a live
solver its ``problem_timing_data`` property is used, offline the Advantage_system4.1 values of
August 2022 below (as published by D-Wave and recorded in dwave-cloud-client's test data).

The model needs the number of *qubits*, known only after embedding
(:mod:`shared.solvers.qpu.bundle_shapes` looks actual embeddings up). Once a bundle structure
has been embedded (by any worker: the embedding cache records each embedding's size per solver),
estimates use that embedding's qubit count. Before, we assume :data:`QUBITS_PER_VARIABLE` qubits
per binary variable: on Pegasus a full-resolution domain-wall Tsukuba row (1152 variables)
embedded in 1956 qubits (1.7 per variable), so 2 is a slight overestimate; readout time grows
only logarithmically with the qubit count (and is flat above ~1500 qubits), so the error this
factor makes is small.

``qpu`` is charged what D-Wave reports; the offline ``qpu-sim`` has no real timing, so it reports
(and is charged) :func:`qpu_access_seconds` of its actual embedding and parameters, so that its
estimates and charges agree as the real ones do. A level's bundles reach the QPU packed: the
rests of up to a shape's disjoint embeddings in one call (:mod:`shared.solvers.qpu.packing`).
"""

from __future__ import annotations

from functools import cache
from typing import TYPE_CHECKING, Any

import numpy as np

from shared.solvers.base import LiveTiming
from shared.solvers.meters.base import BundleCall, LevelLoad, Meter
from shared.solvers.params import DEFAULT_NUM_READS, schema_defaults

if TYPE_CHECKING:
    from shared.solvers.resolved import ResolvedSolver

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


@cache
def _reference_solver():
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


class QpuAccessMeter(Meter):
    """The QPU timing model per call; a level's rests packed ``together`` per call."""

    name = "qpu"
    embeds = True
    charge_keys = ("qpu_access_time",)

    def bundle_seconds(self, call: BundleCall) -> float:
        num_qubits = call.embedding.qubits if call.embedding is not None else call.num_qubits
        if num_qubits is None:
            num_qubits = assumed_qubits(call.num_variables)
        # what the solver runs with when a parameter is not given (qpu-sim reads fewer than qpu)
        params = {**call.defaults, **(call.params or {})}
        return qpu_access_seconds(num_qubits, params, call.solver)

    def level_seconds(
        self, solver: ResolvedSolver, params: dict[str, Any], load: LevelLoad, live: Any = None
    ) -> tuple[float, int | None]:
        whole = load.qubits if load.qubits is not None else assumed_qubits(load.variables)
        qubits = max(1, round(whole * load.kept))
        together = min(max(load.sent, 1), load.together)
        calls = -(-load.sent // together)
        qubits_per_call = min(MAX_QUBITS, together * qubits)
        call = BundleCall(
            solver.spec.name, load.variables, params, qubits_per_call, None, live,
            schema_defaults(solver.spec.params),
        )  # fmt: skip
        seconds = calls * self.bundle_seconds(call)
        return seconds, qubits

    def timing_source(self, solver: ResolvedSolver) -> Any:
        """The cloud solver behind a QPU adapter (its ``problem_timing_data``), None offline."""
        try:
            adapter = solver.sampler
        except Exception:  # a missing dependency: the offline model will do
            return None
        return adapter.timing_solver() if isinstance(adapter, LiveTiming) else None


METER = QpuAccessMeter()
