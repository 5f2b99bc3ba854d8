"""Bounds of every solver parameter a job may send, one pydantic model per solver.

The registry (:mod:`shared.solvers.registry`) names each solver's model; the API validates a
job's ``solver_params`` against it at submit, so a parameter that would run for days or
allocate hundreds of gigabytes (``num_sweeps=1e8``, ``num_reads=1e9``) is a 422 that states the
allowed range, never a stalled worker. The bounds are generous for real use: the largest preset
of each solver (``sa``'s ``paper``: 500 reads x 1000 sweeps) is well inside them. Time spent is
bounded separately by the solver tasks' time limits (``Settings.task_soft_time_limit``); a
per-bundle time parameter is capped at 600 s so that a bundle fits in the default limit.

The models are pure pydantic (no Ocean or Gurobi import), so importing them is cheap.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from types import UnionType
from typing import Annotated, Any, Literal, Union, get_args, get_origin

from annotated_types import Ge, Gt, Le
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    create_model,
    field_validator,
    model_validator,
)

#: Most sweeps (reads x sweeps) ``sa`` may run on one bundle: 4x the paper's setting, about a
#: minute on a full-resolution domain-wall row without fixing (1e5 sweeps/s at 336 variables).
MAX_SA_SWEEPS = 2_000_000
#: Most seconds a time parameter may give one bundle.
MAX_BUNDLE_SECONDS = 600
#: Named SA settings (``sa``'s ``preset``). ``default`` was chosen by measurement
#: (benchmarks/solvers.py); ``paper`` is the setting of the 3DV 2024 paper (500 reads, the
#: sampler's default 1000 sweeps and schedule).
SA_PRESETS: dict[str, dict[str, Any]] = {
    "default": {"num_reads": 20, "num_sweeps": 1000},
    "fast": {"num_reads": 10, "num_sweeps": 500},
    "quality": {"num_reads": 50, "num_sweeps": 5000},
    # a warm start (the coarser level's estimate) only needs refining: a short, cold anneal
    # then a steepest-descent polish (Tsukuba, accurate preset: RMSE within 1 % of exact)
    "warm": {"num_reads": 2, "num_sweeps": 200, "polish": True},
    "paper": {
        "num_reads": 500,
        "num_sweeps": 1000,
        "beta_range": "sampler-default",
        "preprocess": "none",
    },
}


def _at_most(work: float, limit: float, problem: str) -> None:
    """The bound on a product of parameters (reads x sweeps, reads x time) per bundle."""
    if work > limit:
        raise ValueError(f"{problem}; lower one of them")


class SolverParams(BaseModel):
    """Parameters every solver accepts: ``warm_start`` steers the pipeline, not the solver."""

    # schemas built at first use: a run validates one solver's at most (qhsm match's start)
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, defer_build=True)

    warm_start: bool = Field(False, description="Start each bundle from the coarser level")


class NoParams(SolverParams):
    """Solvers without tunable parameters (``exact``)."""


class AnnealParams(SolverParams):
    """``sa``: dwave-samplers' simulated annealing after roof-duality fixing."""

    preset: Literal["default", "fast", "quality", "warm", "paper"] = Field(
        "default",
        description="Named setting (shared.solvers.params.SA_PRESETS; warm: after a warm start)",
    )
    num_reads: int = Field(20, ge=1, le=1000, description="Independent anneals per bundle")
    num_sweeps: int = Field(1000, ge=1, le=100_000, description="Sweeps per anneal")
    beta_range: Literal["sampler-default"] | tuple[float, float] | None = Field(
        None, description="(hot, cold) inverse temperatures, or the sampler's own rule"
    )
    beta_schedule_type: Literal["linear", "geometric"] = "geometric"
    preprocess: Literal["roof-duality", "none"] = "roof-duality"
    polish: bool = Field(False, description="Steepest descent on every read afterwards")

    @field_validator("beta_range")
    @classmethod
    def _positive_range(cls, value: Any) -> Any:
        if isinstance(value, tuple) and not all(0 < b < 1e12 for b in value):
            raise ValueError("beta_range must be two inverse temperatures in (0, 1e12)")
        return value

    @model_validator(mode="after")
    def _bounded_work(self) -> AnnealParams:
        preset = SA_PRESETS[self.preset]  # a preset sets what is not given here
        given = self.model_fields_set
        reads = self.num_reads if "num_reads" in given else preset["num_reads"]
        sweeps = self.num_sweeps if "num_sweeps" in given else preset["num_sweeps"]
        _at_most(
            reads * sweeps,
            MAX_SA_SWEEPS,
            f"num_reads x num_sweeps = {reads * sweeps} is above {MAX_SA_SWEEPS} sweeps per "
            "bundle (4x the paper's 500 x 1000)",
        )
        return self


class TabuParams(SolverParams):
    """``tabu``: dwave-samplers' tabu search."""

    num_reads: int = Field(4, ge=1, le=1000)
    timeout: int = Field(25, ge=1, le=60_000, description="Milliseconds per read")
    tenure: int | None = Field(None, ge=0, le=10_000)
    num_restarts: int | None = Field(None, ge=0, le=1_000_000)

    @model_validator(mode="after")
    def _bounded_time(self) -> TabuParams:
        total = self.num_reads * self.timeout
        _at_most(
            total,
            MAX_BUNDLE_SECONDS * 1000,
            f"num_reads x timeout = {total} ms is above {MAX_BUNDLE_SECONDS} s per bundle",
        )
        return self


class DescentParams(SolverParams):
    """``steepest-descent``: greedy single-flip descent."""

    num_reads: int = Field(10, ge=1, le=10_000)


class GurobiParams(SolverParams):
    """``gurobi``: the QUBO as a MIQP."""

    time_limit: float = Field(60.0, gt=0, le=MAX_BUNDLE_SECONDS, description="Seconds per bundle")
    mip_gap: float = Field(0.0, ge=0, le=1)
    threads: int = Field(1, ge=1, le=64)


#: One point of a QPU anneal schedule: (time in microseconds, anneal fraction s).
SchedulePoint = tuple[Annotated[float, Ge(0), Le(2000)], Annotated[float, Ge(0), Le(1)]]


#: Bundles packed into one QPU call at most (``shared.solvers.qpu.packing``): the 4x4 tile's
#: translated copies number 25 on Advantage P16 and 29-46 on Zephyr Z12/Z15 with 4 labels
#: (docs/benchmarks.md, "Tile copies"), so a call takes up to 32 of them.
MAX_BUNDLES_PER_CALL = 32


class MeteredParams(SolverParams):
    """What every metered solver takes: the exact classical step before anything is sent."""

    preprocess: Literal["roof-duality", "none"] = Field(
        "roof-duality",
        description="Fix what roof duality proves on the host first; only the rest is sent "
        "(and charged)",
    )


class QPUParams(MeteredParams):
    """``qpu`` and ``qpu-sim``: D-Wave's sampler (ranges of Advantage systems).

    The parameters that set the work done are bounded here; any other ``DWaveSampler``
    parameter (``answer_mode``, ``flux_biases``, ...) is passed on and checked by the sampler
    itself (the QPU's SAPI server, or the offline mock), which refuses unknown ones.
    """

    model_config = ConfigDict(extra="allow")

    #: 20 reads: measured on qpu-sim (warm start, roof duality), reads past the first did not
    #: lower any bundle's energy gap (docs/benchmarks.md, "QPU economy"); a real QPU's reads are
    #: noisy samples, and at 20 they are a quarter of a bundle's QPU time (programming ~15 ms,
    #: a read ~0.25 ms), so fewer would save little. 500 was a habit.
    num_reads: int = Field(20, ge=1, le=10_000)
    bundles_per_call: int = Field(
        MAX_BUNDLES_PER_CALL,
        ge=1,
        le=MAX_BUNDLES_PER_CALL,
        description="Bundles packed into one QPU call at most (disjoint copies of their "
        "shape's embedding, as many as were found)",
    )
    annealing_time: float | None = Field(None, ge=0.5, le=2000, description="Microseconds")
    chain_strength: Annotated[float, Gt(0), Le(1e6)] | None = None
    anneal_schedule: list[SchedulePoint] | None = Field(None, min_length=2, max_length=12)
    programming_thermalization: float | None = Field(None, ge=0, le=10_000)
    readout_thermalization: float | None = Field(None, ge=0, le=10_000)
    reduce_intersample_correlation: bool | None = None
    auto_scale: bool | None = None


#: Reads per QPU call when ``num_reads`` is not given (the estimates use it too).
DEFAULT_NUM_READS: int = QPUParams.model_fields["num_reads"].default


class SimulatedQPUParams(QPUParams):
    """``qpu-sim``: the ``qpu`` parameters, read budget included, so that the stand-in is charged
    what ``qpu`` would be for the same bundles (a mock read is a steepest descent on the embedded
    problem, about 1 ms of CPU; reads past the first added nothing measurable with a warm start
    and roof duality: docs/benchmarks.md, "QPU economy")."""


class DimodAnnealParams(SolverParams):
    """``dimod:dwave.samplers.SimulatedAnnealingSampler``: the sampler's own parameters, bounded
    as ``sa``'s (``AnnealParams`` adds our presets, fixing and polish on top)."""

    num_reads: int | None = Field(None, ge=1, le=1000)
    num_sweeps: int | None = Field(None, ge=1, le=100_000)
    beta_range: tuple[float, float] | None = None
    beta_schedule_type: Literal["linear", "geometric"] | None = None

    @field_validator("beta_range")
    @classmethod
    def _positive_range(cls, value: Any) -> Any:
        if value is not None and not all(0 < b < 1e12 for b in value):
            raise ValueError("beta_range must be two inverse temperatures in (0, 1e12)")
        return value

    @model_validator(mode="after")
    def _bounded_work(self) -> DimodAnnealParams:
        reads, sweeps = self.num_reads or 1, self.num_sweeps or 1000  # the sampler's defaults
        _at_most(
            reads * sweeps,
            MAX_SA_SWEEPS,
            f"num_reads x num_sweeps = {reads * sweeps} is above {MAX_SA_SWEEPS} sweeps per bundle",
        )
        return self


class ReadsParams(SolverParams):
    """``dimod:`` samplers whose work is set by ``num_reads`` alone (random, tree
    decomposition)."""

    num_reads: int | None = Field(None, ge=1, le=1000)


def bounds_schema(name: str, bounds: Mapping[str, tuple[float, float]]) -> type[SolverParams]:
    """A schema for a deployment's own ``dimod:`` sampler (``Settings.dimod_samplers``): each
    named parameter a number within its [low, high]; any other parameter is refused.

    Parameters
    ----------
    name : str
        The sampler class's dotted path (the model's name).
    bounds : mapping
        Parameter -> (low, high).

    Returns
    -------
    type of SolverParams
    """
    fields: dict[str, Any] = {
        key: (int | float | None, Field(None, ge=low, le=high))
        for key, (low, high) in bounds.items()
    }
    return create_model(f"Params[{name}]", __base__=SolverParams, **fields)


class LeapHybridParams(MeteredParams):
    """``hybrid``: Leap's hybrid BQM solver."""

    time_limit: float | None = Field(None, ge=3, le=MAX_BUNDLE_SECONDS, description="Seconds")


class KerberosParams(MeteredParams):
    """``hybrid-sim``: dwave-hybrid's Kerberos with the mock QPU."""

    max_iter: int = Field(10, ge=1, le=1000)
    max_time: float | None = Field(None, gt=0, le=MAX_BUNDLE_SECONDS, description="Seconds")
    convergence: int = Field(3, ge=1, le=1000)
    sa_reads: int = Field(1, ge=1, le=100)
    sa_sweeps: int = Field(1000, ge=1, le=100_000)
    tabu_timeout: int = Field(100, ge=1, le=60_000, description="Milliseconds")
    qpu_reads: int = Field(100, ge=1, le=10_000)
    max_subproblem_size: int = Field(50, ge=1, le=1000)


def schema_defaults(model: type[SolverParams]) -> dict[str, Any]:
    """The sampler defaults a schema states (fields with a non-None default, ``warm_start``
    excluded): the one place a solver's default parameters are written.

    Parameters
    ----------
    model
        A solver's parameter schema.

    Returns
    -------
    dict
        Parameter name -> default value.
    """
    return {
        name: field.default
        for name, field in model.model_fields.items()
        if name != "warm_start" and field.default is not None and not field.is_required()
    }


class InvalidSolverParamsError(ValueError):
    """``solver_params`` outside the solver's schema; the message lists the allowed ranges."""


def allowed(model: type[BaseModel]) -> str:
    """The model's parameters with their ranges, e.g. ``num_reads (int, 1..1000)``.

    Parameters
    ----------
    model : type of pydantic.BaseModel
        A solver's parameter schema.

    Returns
    -------
    str
        Comma-separated ``name (type, low..high)``; the range only when both bounds are declared.
    """
    parts = []
    for name, field in model.model_fields.items():
        low = high = None
        for item in field.metadata:
            low = getattr(item, "ge", None) if getattr(item, "ge", None) is not None else low
            low = getattr(item, "gt", None) if getattr(item, "gt", None) is not None else low
            high = getattr(item, "le", None) if getattr(item, "le", None) is not None else high
        kind = _kind(field.annotation)
        bounds = f", {low:g}..{high:g}" if low is not None and high is not None else ""
        parts.append(f"{name} ({kind}{bounds})")
    return ", ".join(parts)


def _kind(annotation: Any) -> str:
    """A short, readable type: ``int``, ``'linear'|'geometric'``, ``bool``."""
    if get_origin(annotation) is Literal:
        return "|".join(map(str, get_args(annotation)))
    args = [a for a in get_args(annotation) if a is not type(None)]
    if args and get_origin(annotation) in (Union, UnionType):
        return " or ".join(_kind(a) for a in args)
    if get_origin(annotation) is Annotated:
        return _kind(args[0])
    return getattr(annotation, "__name__", None) or str(annotation).replace("typing.", "")


def check(model: type[SolverParams], solver: str, params: dict[str, Any]) -> dict[str, Any]:
    """``params`` validated against ``model``: the parameters as given, with coerced types.

    Raises :class:`InvalidSolverParamsError` naming each bad parameter and the allowed ranges.

    Parameters
    ----------
    model : type of SolverParams
        The solver's schema.
    solver : str
        Solver name, for the message.
    params : dict
        ``solver_params`` as given.

    Returns
    -------
    dict
        The given parameters only, JSON-typed after validation.

    Raises
    ------
    InvalidSolverParamsError
        When a parameter is unknown or out of range.
    """
    try:
        parsed = model.model_validate(params)
    except ValidationError as error:
        problems = "; ".join(
            f"{'.'.join(map(str, e['loc'])) or 'solver_params'}: {_message(e)}"
            for e in error.errors()
        )
        raise InvalidSolverParamsError(
            f"solver_params for {solver!r}: {problems}. Allowed parameters: {allowed(model)}"
        ) from None
    return parsed.model_dump(mode="json", exclude_unset=True)


def _message(error: Mapping[str, Any]) -> str:
    if error["type"] == "extra_forbidden":
        return "unknown parameter"
    value = error.get("input")
    shown = f" (got {value!r})" if isinstance(value, int | float | str) else ""
    if isinstance(value, float) and not math.isfinite(value):
        shown = f" (got {value})"
    return f"{error['msg'].removeprefix('Value error, ')}{shown}"
