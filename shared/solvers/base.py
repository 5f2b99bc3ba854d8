"""The solver contract: dimod's. A bundle is a ``dimod.BinaryQuadraticModel``, a QUBO solver a
``dimod.Sampler`` whose ``sample(bqm, seed=..., initial_states=..., **params)`` returns a
``dimod.SampleSet`` with its timing (seconds, under ``info["timing"]``) and what else it
reports (chain breaks, QPU access time) in ``info``. Pre- and post-processing are composites
(:mod:`shared.solvers.composites`).

:func:`solve` is the one place that runs a sampler for the pipeline: it passes the seed and the
warm start the dimod way, times the call, turns the sample set into a :class:`SolveResult` (best
sample as an int8 array, its energy, wall time, timing, info) and maps errors to ours.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from shared.energy import Costs
from shared.solvers.errors import (  # noqa: F401 (re-exported, as they always were)
    SolverError,
    SolverUnavailableError,
    TransientSolverError,
    bad_parameters,
)

if TYPE_CHECKING:
    import dimod


@dataclass(frozen=True)
class Availability:
    """Whether a solver can run here, and if not, what to configure."""

    ok: bool
    reason: str = ""


@dataclass
class SolveResult:
    """Outcome of one :func:`solve` call.

    ``timing`` holds seconds; the key ``qpu_access_time`` is what the service charges to a user.
    ``info["simulated"]`` marks timing that an offline stand-in produced.
    """

    sample: np.ndarray
    energy: float
    wall_time: float
    timing: dict[str, float] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)
    sampleset: dimod.SampleSet | None = None


def seconds(timing: dict[str, Any]) -> dict[str, float]:
    """A sample set's timing in seconds: ``*_ns`` fields (dwave-samplers) converted, other
    numeric fields taken as seconds already (our samplers convert D-Wave's microseconds).

    Parameters
    ----------
    timing
        ``SampleSet.info["timing"]``.

    Returns
    -------
    dict
        Field (``_ns`` suffix dropped) -> seconds; non-numeric fields are left out.
    """
    out = {}
    for key, value in timing.items():
        if isinstance(value, int | float) and not isinstance(value, bool):
            if key.endswith("_ns"):
                out[key.removesuffix("_ns")] = value * 1e-9
            else:
                out[key] = float(value)
    return out


def _plain(value: Any) -> bool:
    """Whether ``value`` survives JSON (results travel between workers as JSON)."""
    if isinstance(value, str | int | float | bool) or value is None:
        return True
    if isinstance(value, list | tuple):
        return all(_plain(item) for item in value)
    if isinstance(value, dict):
        return all(isinstance(k, str) and _plain(v) for k, v in value.items())
    return False


def sample_array(sample: Mapping[Any, Any], num_variables: int) -> np.ndarray:
    """A sample keyed by the integer variables 0..n-1 as an int8 array in that order.

    Parameters
    ----------
    sample : mapping of int to int
        Variable -> value (0/1 or -1/+1), over all variables 0..n-1.
    num_variables : int
        n, the length of the result.

    Returns
    -------
    numpy.ndarray
        int8 array of shape (n,), indexed by variable.
    """
    out = np.zeros(num_variables, dtype=np.int8)
    keys = np.fromiter(sample.keys(), dtype=np.int64, count=len(sample))
    out[keys] = np.fromiter(sample.values(), dtype=np.int8, count=len(sample))
    return out


def initial_states(
    initial_state: np.ndarray | None, bqm: dimod.BinaryQuadraticModel
) -> tuple[np.ndarray, list[int]] | None:
    """A warm start as dimod's ``initial_states``.

    Parameters
    ----------
    initial_state
        One value per variable of ``bqm`` (None: no warm start).
    bqm
        The bundle's QUBO on the variables 0..n-1.

    Returns
    -------
    tuple or None
        Samples-like ``(array of shape (1, n), labels 0..n-1)``; a length that does not match
        is a ``SolverError``.
    """
    if initial_state is None:
        return None
    state = np.asarray(initial_state, dtype=np.int8).reshape(1, -1)
    if state.shape[1] != bqm.num_variables:
        raise SolverError(
            f"initial state has {state.shape[1]} values, the bundle has {bqm.num_variables} "
            "variables"
        )
    return state, list(range(bqm.num_variables))


def solve(
    sampler: dimod.Sampler,
    bqm: dimod.BinaryQuadraticModel,
    *,
    seed: int | None = None,
    initial_state: np.ndarray | None = None,
    **params: Any,
) -> SolveResult:
    """Sample ``bqm`` once for the pipeline and keep the lowest-energy sample.

    Parameters
    ----------
    sampler
        A registered solver (or any ``dimod.Sampler``).
    bqm
        The bundle's QUBO on the variables 0..n-1.
    seed
        The bundle's seed, passed when the sampler takes a ``seed`` parameter.
    initial_state
        A warm start (n values), passed as ``initial_states`` when the sampler takes them.
    **params
        The solver's parameters.

    Returns
    -------
    SolveResult
        Best sample (int8, variable order 0..n-1), its BQM energy, the wall time, the timing in
        seconds and the rest of the sample set's info.

    Raises
    ------
    SolverError
        With what to do; ``SolverUnavailableError`` and ``TransientSolverError`` where they apply.
    """
    accepted = getattr(sampler, "parameters", {})
    started = time.perf_counter()
    if seed is not None and "seed" in accepted:
        params["seed"] = seed
    states = initial_states(initial_state, bqm)
    if states is not None and "initial_states" in accepted:
        params["initial_states"] = states
    try:
        sampleset = sampler.sample(bqm, **params)
        sampleset.resolve()
    except SolverError:
        raise
    except Exception as error:  # samplers raise many types; translate what we know
        translate = getattr(sampler, "translate", None)
        if translate is None:  # a plain dimod sampler: only bad parameters are ours to word
            mapped = bad_parameters(getattr(sampler, "name", type(sampler).__name__), error)
        else:
            mapped = translate(error)
        if mapped is None:
            raise
        raise mapped from None
    return result_of(sampleset, bqm, time.perf_counter() - started)


def result_of(
    sampleset: dimod.SampleSet, bqm: dimod.BinaryQuadraticModel, wall_time: float
) -> SolveResult:
    """The pipeline's :class:`SolveResult` of a resolved sample set of ``bqm``.

    Parameters
    ----------
    sampleset : dimod.SampleSet
        Samples on the variables 0..n-1, ``info["timing"]`` as :func:`seconds` reads it.
    bqm : dimod.BinaryQuadraticModel
        The bundle's QUBO (its energy of the best sample is reported).
    wall_time : float
        Seconds the bundle took.

    Returns
    -------
    SolveResult
        Best sample, its energy, timing in seconds and the JSON-friendly info.
    """
    sample = sample_array(sampleset.first.sample, bqm.num_variables)
    info = dict(sampleset.info)
    timing = seconds(info.pop("timing", None) or {})
    return SolveResult(
        sample=sample,
        energy=float(bqm.energy(sample)),
        wall_time=wall_time,
        timing=timing,
        info={key: value for key, value in info.items() if _plain(value)},
        sampleset=sampleset,
    )


@runtime_checkable
class RowSolver(Protocol):
    """A solver that works on the MRF costs of whole rows instead of a QUBO (the exact DP).

    ``shared.inference.row_chains`` hands such a solver all rows of a task at once, which is
    what lets it vectorise over rows; it raises ``SolverError`` for bundle shapes it cannot solve.
    """

    def solve_rows(self, costs: Costs, bundle_height: int) -> np.ndarray:
        """Labels of every row of ``costs`` by this solver.

        Parameters
        ----------
        costs : Costs
            MRF costs of the task's rows: ``unary`` (h, w, K), ``pair_h`` and ``pair_v``.
        bundle_height : int
            Rows per bundle the configuration asks for.

        Returns
        -------
        numpy.ndarray
            Label index per pixel, shape (h, w).
        """
        ...


@runtime_checkable
class BatchSolver(Protocol):
    """A solver that takes a task's bundles at once and sends them as few problems as it can
    (the QPU solvers: packed calls; the hybrid solvers: a level's rests joined)."""

    def solve_batch(self, problems: list[tuple], **params: Any) -> list[SolveResult]:
        """One :class:`SolveResult` per ``(bqm, seed, warm start or None)``, in order; a
        problem's charge is shared among the bundles it carried."""
        ...


@runtime_checkable
class LiveTiming(Protocol):
    """A solver backed by a cloud QPU whose own timing data the estimates can use."""

    def timing_solver(self) -> Any:
        """The ``dwave.cloud`` solver with ``estimate_qpu_access_time`` and
        ``problem_timing_data``; None offline or when it cannot be reached."""
        ...


@runtime_checkable
class ShapePlanner(Protocol):
    """A solver that embeds on a QPU graph, so a level's bundles are planned on it
    (``shared.inference.qubo``): the widest row segment that embeds (``--bundle-width auto``) and
    each bundle shape's embedding, found once before the bundles fan out."""

    #: Where the embeddings are kept (an ``EmbeddingCache``: ``computed`` counts new ones).
    cache: Any

    def widest_bundle(
        self, *, encoding: str, candidates: int, height: int, row_width: int, margin: int
    ) -> int | None:
        """The widest row segment whose QUBO embeds (None: whole rows)."""
        ...

    def embed_shapes(
        self, *, encoding: str, candidates: int, shapes: list[tuple[int, int]]
    ) -> None:
        """Find (or look up) each shape's embedding."""
        ...
