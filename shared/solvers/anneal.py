"""Classical samplers from dwave-samplers: ``sa``, ``tabu`` and ``steepest-descent``.

Simulated annealing needs a temperature schedule that fits the problem. dwave-samplers derives
its default beta range from the smallest non-zero bias, and our codecs produce floating-point
residues of ~1e-19 (``D^T P D`` of equal pair costs), so its default final beta is ~1e21 and
almost every sweep is a greedy descent. :func:`beta_range` uses the same rule (a hot start at
which every spin flips with probability 1/2, a cold end with a small excitation rate) but ignores
biases below a relative tolerance and takes the cold end from a low quantile of the per-spin
smallest bias, which is robust to a few tiny ones. Measured on Tsukuba rows this turns 1-500%
gaps into about 0.1-1% at equal cost. ``sa`` also fixes variables by roof duality before
annealing (see :class:`SimulatedAnnealingSolver`); docs/benchmarks.md has the measurements.
"""

from __future__ import annotations

import time
from typing import Any, ClassVar

import dimod
import numpy as np

from shared.solvers.base import Availability, SolverError, SolveResult, result_from_sampleset

#: Named SA settings. ``default`` was chosen by measurement (benchmarks/solvers.py); ``paper`` is
#: the setting of the 3DV 2024 paper (500 reads, the sampler's default 1000 sweeps and schedule).
SA_PRESETS: dict[str, dict[str, Any]] = {
    "default": {"num_reads": 20, "num_sweeps": 1000},
    "fast": {"num_reads": 10, "num_sweeps": 500},
    "quality": {"num_reads": 50, "num_sweeps": 5000},
    "paper": {
        "num_reads": 500,
        "num_sweeps": 1000,
        "beta_range": "sampler-default",
        "preprocess": "none",
    },
}

#: Biases smaller than this fraction of the largest one count as zero for the schedule.
BIAS_TOLERANCE = 1e-6
#: Quantile of the per-spin smallest bias that sets the final temperature.
COLD_QUANTILE = 0.05
#: Target probability that a spin at the smallest gap flips on the last sweep.
COLD_EXCITATION_RATE = 0.01
#: A warm start begins this many times colder than a cold start, so that the annealer refines
#: the given state instead of melting it.
WARM_START_COOLING = 30.0


def beta_range(bqm: dimod.BinaryQuadraticModel) -> tuple[float, float]:
    """(hot, cold) inverse temperatures of the Ising form of ``bqm`` (vectorised; see module
    docstring for why not dwave-samplers' default)."""
    linear, (rows, cols, quadratic), _ = bqm.spin.to_numpy_vectors()
    abs_h, abs_j = np.abs(linear), np.abs(quadratic)
    largest = max(abs_h.max(initial=0.0), abs_j.max(initial=0.0))
    if largest == 0.0:
        return 0.1, 1.0
    field = abs_h.copy()
    np.add.at(field, rows, abs_j)
    np.add.at(field, cols, abs_j)
    hot = np.log(2.0) / (2.0 * field.max())
    tolerance = BIAS_TOLERANCE * largest
    smallest = np.where(abs_h > tolerance, abs_h, np.inf)
    significant = np.where(abs_j > tolerance, abs_j, np.inf)
    np.minimum.at(smallest, rows, significant)
    np.minimum.at(smallest, cols, significant)
    smallest = smallest[np.isfinite(smallest)]
    if smallest.size == 0:
        return hot, hot
    cold = np.log(1.0 / COLD_EXCITATION_RATE) / (2.0 * np.quantile(smallest, COLD_QUANTILE))
    return float(hot), float(max(cold, hot))


def _initial_states(initial_state: np.ndarray | None, bqm: dimod.BinaryQuadraticModel):
    """``initial_states`` argument for dwave-samplers, in the BQM's variable order 0..n-1."""
    if initial_state is None:
        return None
    state = np.asarray(initial_state, dtype=np.int8).reshape(1, -1)
    if state.shape[1] != bqm.num_variables:
        raise SolverError(
            f"initial state has {state.shape[1]} values, the bundle has {bqm.num_variables} "
            "variables"
        )
    return state, list(range(bqm.num_variables))


def _sampler_timing(sampleset: dimod.SampleSet) -> dict[str, float]:
    """dwave-samplers report nanoseconds; we report seconds."""
    timing = sampleset.info.get("timing", {})
    return {
        key.removesuffix("_ns"): value * 1e-9
        for key, value in timing.items()
        if key.endswith("_ns")
    }


def _sample(
    name: str,
    sampler: dimod.Sampler,
    bqm: dimod.BinaryQuadraticModel,
    seed: int | None,
    settings: dict[str, Any],
    warm_start: bool,
) -> SolveResult:
    """Run a dwave-samplers sampler; bad parameters become a ``SolverError`` naming the solver."""
    started = time.perf_counter()
    try:
        sampleset = sampler.sample(bqm, seed=seed, **settings)
    except (TypeError, ValueError) as error:
        raise SolverError(f"{name}: invalid parameters: {error}") from None
    info = {"num_reads": len(sampleset), "warm_start": warm_start}
    return result_from_sampleset(sampleset, bqm, started, _sampler_timing(sampleset), info)


class _Classical:
    offline = False
    uses_qpu_time = False

    def available(self) -> Availability:
        return Availability(True, "always available (CPU, dwave-samplers)")


class SimulatedAnnealingSolver(_Classical):
    """``sa``: dwave-samplers' SimulatedAnnealingSampler with a measured default schedule.

    By default the BQM is first reduced by roof duality (dwave-preprocessing): variables that
    take the same value in every optimum are fixed exactly (a max-flow, milliseconds), and only
    the rest is annealed. On Tsukuba's domain-wall rows this fixes every variable at the 1/2 and
    full-resolution levels (convex smoothness makes them submodular) and about 60% at 1/4.

    Parameters: ``preset`` (see :data:`SA_PRESETS`), ``num_reads``, ``num_sweeps``,
    ``beta_range`` (a pair, or ``"sampler-default"`` for dwave-samplers' own rule),
    ``beta_schedule_type``, ``preprocess`` (``"roof-duality"`` or ``"none"``) and ``polish``
    (steepest descent on every read afterwards). With ``initial_state`` every read starts from
    that state at a colder start temperature.
    """

    name = "sa"
    description = "Simulated annealing (dwave-samplers) after roof-duality fixing, classical CPU"

    def solve(
        self,
        bqm: dimod.BinaryQuadraticModel,
        *,
        seed: int | None = None,
        initial_state: np.ndarray | None = None,
        **params: Any,
    ) -> SolveResult:
        preset_name = params.pop("preset", "default")
        if preset_name not in SA_PRESETS:
            raise SolverError(
                f"unknown sa preset {preset_name!r}; presets: {', '.join(SA_PRESETS)}"
            )
        settings = {**SA_PRESETS[preset_name], **params}
        preprocess = settings.pop("preprocess", "roof-duality")
        if preprocess not in PREPROCESSORS:
            raise SolverError(
                f"unknown sa preprocess {preprocess!r}; choose from {', '.join(PREPROCESSORS)}"
            )
        started = time.perf_counter()
        initial = _check_initial_state(initial_state, bqm)
        fixed: dict[int, int] = {}
        if preprocess == "roof-duality":
            from dwave.preprocessing import roof_duality

            _, fixed = roof_duality(bqm, strict=True)
        sample = np.zeros(bqm.num_variables, dtype=np.int8)
        if fixed:
            sample[list(fixed)] = list(fixed.values())
        info: dict[str, Any] = {
            "preset": preset_name,
            "preprocess": preprocess,
            "fixed_fraction": len(fixed) / max(bqm.num_variables, 1),
            "warm_start": initial is not None,
        }
        timing: dict[str, float] = {}
        if len(fixed) < bqm.num_variables:
            rest, free = fix_variables(bqm, fixed)
            sampleset, used = _anneal(
                rest, seed, None if initial is None else initial[free], settings
            )
            best = sampleset.record.sample[sampleset.record.energy.argmin()]
            order = np.fromiter(sampleset.variables, dtype=np.int64, count=len(free))
            sample[free[order]] = best
            timing = _sampler_timing(sampleset)
            info.update(used, num_reads=len(sampleset))
        return SolveResult(
            sample=sample,
            energy=float(bqm.energy(sample)),
            wall_time=time.perf_counter() - started,
            timing=timing,
            info=info,
        )


def fix_variables(
    bqm: dimod.BinaryQuadraticModel, fixed: dict[int, int]
) -> tuple[dimod.BinaryQuadraticModel, np.ndarray]:
    """The BQM on the free variables, relabelled 0..m-1, and their original numbers.

    Vectorised equivalent of ``bqm.fix_variables`` (dimod's is quadratic in the number of
    variables and took 0.9 s on a full-resolution row)."""
    n = bqm.num_variables
    linear, (rows, cols, quadratic), offset = bqm.binary.to_numpy_vectors(variable_order=range(n))
    values = np.zeros(n)
    is_fixed = np.zeros(n, dtype=bool)
    if fixed:
        keys = np.fromiter(fixed.keys(), dtype=np.int64, count=len(fixed))
        values[keys] = np.fromiter(fixed.values(), dtype=float, count=len(fixed))
        is_fixed[keys] = True
    linear = linear.astype(float).copy()
    offset = float(offset) + float(linear[is_fixed] @ values[is_fixed])
    row_fixed, col_fixed = is_fixed[rows], is_fixed[cols]
    both = row_fixed & col_fixed
    offset += float(np.sum(quadratic[both] * values[rows[both]] * values[cols[both]]))
    np.add.at(
        linear, rows[col_fixed & ~row_fixed], (quadratic * values[cols])[col_fixed & ~row_fixed]
    )
    np.add.at(
        linear, cols[row_fixed & ~col_fixed], (quadratic * values[rows])[row_fixed & ~col_fixed]
    )
    free = np.flatnonzero(~is_fixed)
    number = np.full(n, -1, dtype=np.int64)
    number[free] = np.arange(free.size)
    keep = ~row_fixed & ~col_fixed
    reduced = dimod.BinaryQuadraticModel.from_numpy_vectors(
        linear[free],
        (number[rows[keep]], number[cols[keep]], quadratic[keep]),
        offset,
        dimod.BINARY,
    )
    return reduced, free


#: Exact reductions ``sa`` may apply before annealing.
PREPROCESSORS = ("roof-duality", "none")


def _check_initial_state(
    initial_state: np.ndarray | None, bqm: dimod.BinaryQuadraticModel
) -> np.ndarray | None:
    if initial_state is None:
        return None
    state = np.asarray(initial_state, dtype=np.int8).ravel()
    if state.size != bqm.num_variables:
        raise SolverError(
            f"initial state has {state.size} values, the bundle has {bqm.num_variables} variables"
        )
    return state


def _anneal(
    bqm: dimod.BinaryQuadraticModel,
    seed: int | None,
    initial: np.ndarray | None,
    settings: dict[str, Any],
) -> tuple[dimod.SampleSet, dict[str, Any]]:
    """Simulated annealing (plus optional steepest-descent polish) of ``bqm``."""
    from dwave.samplers import SimulatedAnnealingSampler, SteepestDescentSolver

    settings = dict(settings)
    polish = bool(settings.pop("polish", False))
    # The samplers work on the Ising form; converting once here (dimod's C++ routine) instead of
    # through the binary BQM's spin view (Python loops) saves most of the per-bundle overhead.
    spin = bqm.change_vartype(dimod.SPIN, inplace=False)
    schedule = settings.pop("beta_range", None)
    if schedule is None:
        hot, cold = beta_range(spin)
        if initial is not None:
            hot = min(hot * WARM_START_COOLING, cold)
        settings["beta_range"] = (hot, cold)
    elif schedule != "sampler-default":
        settings["beta_range"] = tuple(schedule)
    if initial is not None:
        settings.update(
            initial_states=(2 * initial.reshape(1, -1).astype(np.int8) - 1, list(spin.variables)),
            initial_states_generator="tile",
        )
    try:
        sampleset = SimulatedAnnealingSampler().sample(spin, seed=seed, **settings)
        if polish:
            sampleset = SteepestDescentSolver().sample(spin, initial_states=sampleset)
    except (TypeError, ValueError) as error:
        raise SolverError(f"sa: invalid parameters: {error}") from None
    sampleset = sampleset.change_vartype(dimod.BINARY)
    used = {
        "beta_range": [float(b) for b in sampleset.info.get("beta_range", ())],
        "polished": polish,
    }
    return sampleset, used


class TabuSolver(_Classical):
    """``tabu``: dwave-samplers' TabuSampler (MST2 multistart tabu search).

    Parameters: ``num_reads`` (default 4: a single read can cycle on tiny problems),
    ``timeout`` (milliseconds per read, default 25), ``tenure``, ``num_restarts``.
    ``initial_state`` seeds every read.
    """

    name = "tabu"
    description = "Tabu search (dwave-samplers), classical CPU"
    defaults: ClassVar[dict[str, Any]] = {"num_reads": 4, "timeout": 25}

    def solve(
        self,
        bqm: dimod.BinaryQuadraticModel,
        *,
        seed: int | None = None,
        initial_state: np.ndarray | None = None,
        **params: Any,
    ) -> SolveResult:
        from dwave.samplers import TabuSampler

        settings = {**self.defaults, **params}
        initial = _initial_states(initial_state, bqm)
        if initial is not None:
            settings.update(initial_states=initial, initial_states_generator="tile")
        return _sample(self.name, TabuSampler(), bqm, seed, settings, initial is not None)


class SteepestDescentSolver(_Classical):
    """``steepest-descent``: greedy single-flip descent (dwave-samplers), a baseline and a
    polisher. From ``initial_state`` it returns that state's local minimum; otherwise the best
    of ``num_reads`` (default 10) random starts."""

    name = "steepest-descent"
    description = "Steepest descent (dwave-samplers): local minimum, baseline / polisher"
    defaults: ClassVar[dict[str, Any]] = {"num_reads": 10}

    def solve(
        self,
        bqm: dimod.BinaryQuadraticModel,
        *,
        seed: int | None = None,
        initial_state: np.ndarray | None = None,
        **params: Any,
    ) -> SolveResult:
        from dwave.samplers import SteepestDescentSolver as Descent

        settings = {**self.defaults, **params}
        initial = _initial_states(initial_state, bqm)
        if initial is not None:
            settings.update(initial_states=initial, num_reads=1)
        return _sample(self.name, Descent(), bqm, seed, settings, initial is not None)
