"""Classical samplers from dwave-samplers: ``sa``, ``tabu`` and ``steepest-descent``.

Simulated annealing needs a temperature schedule that fits the problem. dwave-samplers derives
its default beta range from the smallest non-zero bias, and our codecs produce floating-point
residues of ~1e-19 (``D^T P D`` of equal pair costs), so its default final beta is ~1e21 and
almost every sweep is a greedy descent. :func:`beta_range` uses the same rule (a hot start at
which every spin flips with probability 1/2, a cold end with a small excitation rate) but ignores
biases below a relative tolerance and takes the cold end from a low quantile of the per-spin
smallest bias, which is robust to a few tiny ones. Measured on Tsukuba rows this turns 1-500%
gaps into about 0.1-1% at equal cost. ``sa`` also fixes variables by roof duality before
annealing (:class:`shared.solvers.composites.RoofDualityComposite`); docs/benchmarks.md has the
measurements.
"""

from __future__ import annotations

from typing import Any

import dimod
import numpy as np

from shared.solvers.base import SolverError
from shared.solvers.composites import PREPROCESSORS, RoofDualityComposite, SolverComposite
from shared.solvers.params import SA_PRESETS

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
    docstring for why not dwave-samplers' default).

    Parameters
    ----------
    bqm : dimod.BinaryQuadraticModel
        The problem, in either vartype (its Ising form is read).

    Returns
    -------
    tuple of float
        ``(hot, cold)`` inverse temperatures, ``cold >= hot``; ``(0.1, 1.0)`` when every bias is 0.
    """
    linear, (rows, cols, quadratic), *_ = bqm.spin.to_numpy_vectors()
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


class TunedAnnealer(dimod.Sampler):
    """dwave-samplers' simulated annealing with the schedule of :func:`beta_range` (colder by
    :data:`WARM_START_COOLING` from a warm start) and an optional steepest-descent ``polish`` of
    every read. ``beta_range="sampler-default"`` keeps dwave-samplers' own rule."""

    parameters: dict[str, list] = {  # noqa: RUF012 (dimod's interface)
        "num_reads": [],
        "num_sweeps": [],
        "beta_range": [],
        "beta_schedule_type": [],
        "polish": [],
        "seed": [],
        "initial_states": [],
        "initial_states_generator": [],
    }
    properties: dict[str, Any] = {}  # noqa: RUF012

    def sample(
        self,
        bqm: dimod.BinaryQuadraticModel,
        *,
        polish: bool = False,
        initial_states: Any = None,
        **settings: Any,
    ) -> dimod.SampleSet:
        """Simulated annealing of ``bqm`` in its Ising form, with the tuned schedule unless
        ``beta_range="sampler-default"``.

        Parameters
        ----------
        bqm : dimod.BinaryQuadraticModel
            The problem, BINARY or SPIN.
        polish : bool, default False
            Whether to run steepest descent from every read afterwards.
        initial_states : samples-like, optional
            Warm start in the BQM's vartype; it also makes the schedule start colder.
        **settings
            ``SimulatedAnnealingSampler`` parameters; ``beta_range`` None means :func:`beta_range`.

        Returns
        -------
        dimod.SampleSet
            Reads in the BQM's vartype; info has ``beta_range``, ``polished`` and ``num_reads``.
        """
        from dwave.samplers import SimulatedAnnealingSampler, SteepestDescentSolver

        # The samplers work on the Ising form; converting once here (dimod's C++ routine)
        # instead of through the binary BQM's spin view (Python loops) saves most of the
        # per-bundle overhead.
        spin = bqm.change_vartype(dimod.SPIN, inplace=False)
        schedule = settings.pop("beta_range", None)
        if schedule is None:
            hot, cold = beta_range(spin)
            if initial_states is not None:
                hot = min(hot * WARM_START_COOLING, cold)
            settings["beta_range"] = (hot, cold)
        elif schedule != "sampler-default":
            settings["beta_range"] = tuple(schedule)
        if initial_states is not None:
            states, labels = dimod.as_samples(initial_states)
            if bqm.vartype is dimod.BINARY:
                states = 2 * states.astype(np.int8) - 1
            settings["initial_states"] = (states, labels)
        sampleset = SimulatedAnnealingSampler().sample(spin, **settings)
        if polish:
            sampleset = SteepestDescentSolver().sample(
                spin,
                initial_states=sampleset,  # type: ignore[arg-type]  # a SampleSet is samples-like
            )
        sampleset = sampleset.change_vartype(bqm.vartype)
        sampleset.info.update(
            beta_range=[float(b) for b in sampleset.info.get("beta_range", ())],
            polished=bool(polish),
            num_reads=len(sampleset),
        )
        return sampleset


class SimulatedAnnealing(SolverComposite):
    """``sa``: :class:`TunedAnnealer` inside :class:`RoofDualityComposite`, with named settings.

    Parameters: ``preset`` (see :data:`SA_PRESETS`; ``warm`` after a warm start unless the
    reads or sweeps are given), ``num_reads``, ``num_sweeps``, ``beta_range`` (a pair, or
    ``"sampler-default"``), ``beta_schedule_type``, ``preprocess`` (``"roof-duality"`` or
    ``"none"``) and ``polish`` (steepest descent on every read afterwards).
    """

    #: ``sa``'s defaults are its presets (:data:`SA_PRESETS`), chosen in :meth:`configure`.
    defaults: dict[str, Any] = {}  # noqa: RUF012

    def configure(self, params: dict[str, Any], warm: bool) -> tuple[dict[str, Any], dict]:
        """The annealer's settings for ``params``: the chosen preset under the given parameters.

        Parameters
        ----------
        params : dict
            The call's ``sa`` parameters, ``preset`` among them.
        warm : bool
            Whether the call has a warm start (``warm`` preset unless reads or sweeps are given).

        Returns
        -------
        settings : dict
            Parameters for the child, ``preprocess`` included.
        report : dict
            ``{"preset": name}`` for the sample set's info.

        Raises
        ------
        SolverError
            For an unknown preset or preprocess.
        """
        params = dict(params)
        tuned = {"preset", "num_reads", "num_sweeps"} & set(params)
        preset = params.pop("preset", "warm" if warm and not tuned else "default")
        if preset not in SA_PRESETS:
            raise SolverError(f"unknown sa preset {preset!r}; presets: {', '.join(SA_PRESETS)}")
        settings = {**SA_PRESETS[preset], **params}
        preprocess = settings.setdefault("preprocess", "roof-duality")
        if preprocess not in PREPROCESSORS:
            raise SolverError(
                f"unknown sa preprocess {preprocess!r}; choose from {', '.join(PREPROCESSORS)}"
            )
        return settings, {"preset": preset}


def simulated_annealing() -> SimulatedAnnealing:
    """The ``sa`` solver."""
    return SimulatedAnnealing(RoofDualityComposite(TunedAnnealer()))


def tabu() -> SolverComposite:
    """The ``tabu`` solver: dwave-samplers' TabuSampler (MST2 multistart tabu search); a warm
    start seeds every read."""
    from dwave.samplers import TabuSampler

    return SolverComposite(TabuSampler())


def steepest_descent() -> SolverComposite:
    """The ``steepest-descent`` solver: greedy single-flip descent (dwave-samplers), a baseline
    and a polisher. From a warm start it returns that state's local minimum."""
    from dwave.samplers import SteepestDescentSolver

    return SolverComposite(SteepestDescentSolver(), warm_overrides={"num_reads": 1})
