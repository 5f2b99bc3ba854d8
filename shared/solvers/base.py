"""The solver contract: dimod's. A bundle is a ``dimod.BinaryQuadraticModel``; a solver returns
its best sample (as an array in variable order 0..n-1), that sample's BQM energy, the wall time,
the solver's own timing and whatever else it reports (chain breaks, QPU access time)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from shared.config import MatchConfig
from shared.energy import Costs

if TYPE_CHECKING:  # dimod is imported where a BQM is built, not by the exact row path
    import dimod


@dataclass(frozen=True)
class Availability:
    """Whether a solver can run here, and if not, what to configure."""

    ok: bool
    reason: str = ""


@dataclass
class SolveResult:
    """Outcome of one ``solve`` call.

    ``timing`` holds seconds (D-Wave's microseconds are converted in the adapter); the key
    ``qpu_access_time`` is what the service charges to a user. ``simulated`` marks timing that
    an offline stand-in produced.
    """

    sample: np.ndarray
    energy: float
    wall_time: float
    timing: dict[str, float] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)
    sampleset: dimod.SampleSet | None = None


class SolverError(RuntimeError):
    """A solver failed; the message says what is wrong and what to do. Not worth retrying."""


class SolverUnavailable(SolverError):
    """The solver cannot run here (missing token, licence or package)."""


class TransientSolverError(SolverError):
    """A failure worth retrying later (rate limit, timeout, solver offline)."""


@runtime_checkable
class Solver(Protocol):
    """Adapter interface every solver implements."""

    name: str
    description: str
    #: True where results come from an offline stand-in for a cloud service.
    offline: bool
    #: True where the solver spends metered D-Wave time (needs the token and a quota).
    uses_qpu_time: bool
    #: Whether bundles start from the best guess at hand unless the config says otherwise
    #: (``MatchConfig.warm_start``): classical local searches refine one far more cheaply than
    #: they find a minimum from scratch; QPU and cloud solvers start cold unless asked.
    warm_start_default: bool = False

    def available(self) -> Availability: ...

    def solve(
        self,
        bqm: dimod.BinaryQuadraticModel,
        *,
        seed: int | None = None,
        initial_state: np.ndarray | None = None,
        **params: Any,
    ) -> SolveResult: ...


def sample_array(sample: dict[Any, int] | dimod.SampleView, num_variables: int) -> np.ndarray:
    """A sample keyed by the integer variables 0..n-1 as an int8 array in that order."""
    out = np.zeros(num_variables, dtype=np.int8)
    keys = np.fromiter(sample.keys(), dtype=np.int64, count=len(sample))
    out[keys] = np.fromiter(sample.values(), dtype=np.int8, count=len(sample))
    return out


def result_from_sampleset(
    sampleset: dimod.SampleSet,
    bqm: dimod.BinaryQuadraticModel,
    started: float,
    timing: dict[str, float] | None = None,
    info: dict[str, Any] | None = None,
) -> SolveResult:
    """Build a :class:`SolveResult` from a resolved sample set (its lowest-energy sample)."""
    best = sampleset.first
    sample = sample_array(best.sample, bqm.num_variables)
    return SolveResult(
        sample=sample,
        energy=float(bqm.energy(sample)),
        wall_time=time.perf_counter() - started,
        timing=dict(timing or {}),
        info=dict(info or {}),
        sampleset=sampleset,
    )


@runtime_checkable
class RowSolver(Protocol):
    """A solver that works on the MRF costs of whole rows instead of a QUBO (the exact DP).

    ``shared.solve`` hands such a solver all rows of a task at once, which is what lets it
    vectorise over rows; it raises ``SolverError`` for bundle shapes it cannot solve.
    """

    def solve_rows(self, costs: Costs, bundle_height: int) -> np.ndarray: ...


def uses_warm_start(config: MatchConfig) -> bool:
    """Whether ``config``'s bundles are warm-started: ``solver_params["warm_start"]`` (kept for
    old clients) or ``MatchConfig.warm_start`` when given, else the solver's default."""
    if "warm_start" in config.solver_params:
        return bool(config.solver_params["warm_start"])
    if config.warm_start is not None:
        return config.warm_start
    from shared.solvers.registry import get_solver

    return bool(getattr(get_solver(config.solver), "warm_start_default", False))
