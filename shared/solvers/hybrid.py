"""``hybrid`` (Leap's hybrid BQM solver) and ``hybrid-sim`` (dwave-hybrid's Kerberos, offline).

Kerberos races tabu search, simulated annealing and QPU-solved subproblems (energy-impact
decomposition) and keeps the best; ``hybrid-sim`` gives it the offline ``MockDWaveSampler`` as
its QPU, so it runs anywhere and its QPU timing is not real. It is a stand-in for the workflow
shape, not for Leap's proprietary solver, and is always named as such. It reports (and is charged)
the ``charge_time`` Leap's hybrid solver would bill for a problem of its size
(:func:`shared.solvers.meters.hybrid.hybrid_charge_seconds`).

Both solve a task's bundles as few problems as the solver takes (:meth:`_HybridBatch.solve_batch`):
roof duality first on each bundle, then what is left of all of them joined into blocks of at most
:data:`~shared.solvers.meters.hybrid.HYBRID_MAX_VARIABLES` variables. Leap bills its minimum time
per problem, so one block per level costs what one row did. ``hybrid`` sends each block as one BQM;
``hybrid-sim`` runs Kerberos on each bundle's rest (what it can run here) and is charged what Leap
would bill for the block. A block's charge is shared by its bundles in proportion to their
variables.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import dimod
import numpy as np

from shared.solvers.base import Availability, SolverError, SolveResult, result_of
from shared.solvers.composites import reduce
from shared.solvers.qpu import leap
from shared.solvers.qpu.dwave import mock_qpu
from shared.solvers.qpu.packing import joined, split
from shared.solvers.sampler import Sampler


def blocks(sizes: list[int], limit: int) -> list[list[int]]:
    """Consecutive indices grouped so that each group's sizes add up to at most ``limit`` (a
    size above it alone).

    Parameters
    ----------
    sizes : list of int
        Variables of each problem.
    limit : int
        Variables of one block at most.

    Returns
    -------
    list of list of int
        Indices into ``sizes``, in order.
    """
    groups: list[list[int]] = []
    total = limit + 1
    for index, size in enumerate(sizes):
        if total + size > limit:
            groups.append([])
            total = 0
        groups[-1].append(index)
        total += size
    return groups


class _HybridBatch(Sampler):
    """A task's bundles as few hybrid problems as the solver takes (see the module docstring)."""

    simulated: bool

    def max_variables(self) -> int:
        """Variables of one problem at most (the solver's limit)."""
        from shared.solvers.meters.hybrid import HYBRID_MAX_VARIABLES

        return HYBRID_MAX_VARIABLES

    def sample_block(
        self, rests: list[dimod.BinaryQuadraticModel], params: dict[str, Any], seeds, states
    ) -> tuple[list[dimod.SampleSet], dict[str, float]]:
        """Samples of each rest of one block, and the block's timing (seconds)."""
        raise NotImplementedError

    def solve_batch(self, problems: list[tuple], **params: Any) -> list[SolveResult]:
        """Solve bundles ``(bqm, seed, warm start or None)`` in as few problems as fit.

        Parameters
        ----------
        problems : list of tuple
            Each bundle's QUBO on 0..n-1, seed and warm start (n values or None).
        **params
            Solver parameters over the defaults (``preprocess``, ``time_limit``, ...).

        Returns
        -------
        list of SolveResult
            One per bundle, in order; a block's charge is shared in proportion to the bundles'
            variables left; a bundle roof duality solved is charged nothing.
        """
        started = time.perf_counter()
        params = {**self.defaults, **params}
        preprocess = params.pop("preprocess", "roof-duality")
        with self.translating():
            reductions = [reduce(bqm, preprocess) for bqm, _, _ in problems]
            sets: list[dimod.SampleSet | None] = [None] * len(problems)
            sent = [i for i, r in enumerate(reductions) if r.rest is not None]
            sizes = [int(reductions[i].free.size) for i in sent]
            for block in blocks(sizes, self.max_variables()):
                chosen = [sent[j] for j in block]
                rests = [r for r in (reductions[i].rest for i in chosen) if r is not None]
                states = [reductions[i].states(_as_states(problems[i][2])) for i in chosen]
                seeds = [problems[i][1] for i in chosen]
                samplesets, timing = self.sample_block(rests, dict(params), seeds, states)
                total = sum(sizes[j] for j in block)
                for i, sampleset in zip(chosen, samplesets, strict=True):
                    share = reductions[i].free.size / total
                    sampleset.info["timing"] = {k: v * share for k, v in timing.items()}
                    sampleset.info["block_variables"] = total
                    sampleset.info["block_bundles"] = len(block)
                    sets[i] = sampleset
        each = (time.perf_counter() - started) / max(len(problems), 1)
        return [
            result_of(
                reduction.complete(sampleset, {"simulated": self.simulated})
                if sampleset is not None
                else reduction.complete(None, {"timing": {}, "simulated": self.simulated}),
                reduction.bqm,
                each,
            )
            for reduction, sampleset in zip(reductions, sets, strict=True)
        ]


def _as_states(initial_state) -> Any:
    if initial_state is None:
        return None
    state = np.asarray(initial_state, dtype=np.int8).reshape(1, -1)
    return state, list(range(state.shape[1]))


class LeapHybridSolver(_HybridBatch):
    """``hybrid``: ``LeapHybridSampler`` (needs ``DWAVE_API_TOKEN``); ``time_limit`` in seconds
    (Leap's minimum for the problem size when unset). Warm starts are not supported by Leap's
    BQM solver, so ``initial_states`` are ignored and reported as such. It decomposes problems
    itself: bundles are whole rows, with no QPU graph to embed on (so it reaches Leap through
    :mod:`~shared.solvers.qpu.leap`, not as a QPU adapter)."""

    name = "hybrid"
    simulated = False
    parameters: dict[str, list] = {  # noqa: RUF012
        "time_limit": [],
        "initial_states": [],
        "preprocess": [],
    }
    properties: dict[str, Any] = {"simulated": False}  # noqa: RUF012

    def __init__(self) -> None:
        self._sampler: Any = None
        self._lock = threading.Lock()

    def available(self) -> Availability:
        return leap.available(self.settings)

    def translate(self, error: Exception) -> SolverError:
        """Ocean's exceptions as our typed errors, with the token scrubbed from the text."""
        settings = self.settings
        return leap.translate(self.name, error, settings, leap.secret(settings))

    def _make_sampler(self):
        from dwave.system import LeapHybridSampler

        return leap.connect(self.name, LeapHybridSampler, self.settings)

    def _build_sampler(self):
        """:meth:`_make_sampler`, its errors as ours."""
        with self.translating():
            return self._make_sampler()

    def run(self, bqm, params: dict[str, Any], *, seed, initial_states) -> dimod.SampleSet:
        """Send the BQM to Leap's hybrid solver and convert its timing to seconds.

        Parameters
        ----------
        bqm : dimod.BinaryQuadraticModel
            The problem; refused before upload when above the solver's variable limit.
        params : dict
            ``LeapHybridSampler`` parameters (``time_limit``, seconds).
        seed : int or None
            Ignored: Leap takes no seed.
        initial_states : samples-like or None
            Ignored; reported as ``warm_start_ignored``.

        Returns
        -------
        dimod.SampleSet
            Leap's samples; info has ``timing`` (seconds) and ``qpu_access_time``.

        Raises
        ------
        SolverError
            When the problem has too many variables for the solver.
        """
        reduction = reduce(bqm, params.pop("preprocess", "roof-duality"))
        if reduction.rest is None:
            return reduction.complete(None, {"timing": {}, "simulated": False})
        return reduction.complete(self._sample_rest(reduction.rest, params, initial_states))

    def _sample_rest(self, bqm, params: dict[str, Any], initial_states) -> dimod.SampleSet:
        with self._lock:
            if self._sampler is None:
                self._sampler = self._build_sampler()
        self._check_size(bqm)
        sampleset = self._sampler.sample(bqm, **params)
        sampleset.resolve()
        # Leap reports microseconds, like the QPU
        timing = {
            key: float(value) * 1e-6
            for key, value in sampleset.info.items()
            if key in ("qpu_access_time", "run_time", "charge_time")
        }
        sampleset.info.clear()
        sampleset.info.update(
            {
                "timing": timing,
                "qpu_access_time": timing.get("qpu_access_time", 0.0),
                "simulated": False,
                "warm_start": False,
                "warm_start_ignored": initial_states is not None,
            }
        )
        return sampleset

    def sample_block(
        self, rests: list[dimod.BinaryQuadraticModel], params: dict[str, Any], seeds, states
    ) -> tuple[list[dimod.SampleSet], dict[str, float]]:
        """One Leap problem for the block: the rests' disjoint union, split back per rest."""
        sampleset = self._sample_rest(joined(rests), params, None)
        timing = dict(sampleset.info["timing"])
        out = split(sampleset, rests)
        for part in out:
            part.info.update(simulated=False, warm_start=False)
        return out, timing

    def _check_size(self, bqm: dimod.BinaryQuadraticModel) -> None:
        """Refuse what the solver would refuse after a long upload (its size limits)."""
        limit = self._sampler.properties.get("maximum_number_of_variables")
        if limit is not None and bqm.num_variables > int(limit):
            raise SolverError(
                f"{self.name}: the problem is too large for the hybrid solver "
                f"({bqm.num_variables} variables, at most {limit} variables); use smaller "
                "bundles (--bundle-height) or --encoding domain-wall"
            )


class KerberosSolver(_HybridBatch):
    """``hybrid-sim``: dwave-hybrid's Kerberos workflow with ``MockDWaveSampler`` as its QPU.

    Parameters: those of ``hybrid.reference.kerberos.Kerberos`` (``max_iter``, ``max_time``,
    ``convergence``, ``sa_sweeps``, ``tabu_timeout``, ``qpu_reads``, ``max_subproblem_size``);
    defaults in ``KerberosParams``. The first of ``initial_states`` is Kerberos' initial sample.
    """

    name = "hybrid-sim"
    simulated = True
    parameters: dict[str, list] = {"seed": [], "initial_states": [], "preprocess": []}  # noqa: RUF012
    properties: dict[str, Any] = {"simulated": True}  # noqa: RUF012

    def __init__(self) -> None:
        self._qpu = None

    def available(self) -> Availability:
        return Availability(True, "offline simulator (dwave-hybrid Kerberos, MockDWaveSampler)")

    def run(self, bqm, params: dict[str, Any], *, seed, initial_states) -> dimod.SampleSet:
        """Run Kerberos offline with the mock QPU; the charge is Leap's minimum for the size.

        Parameters
        ----------
        bqm : dimod.BinaryQuadraticModel
            The problem.
        params : dict
            Kerberos parameters (``max_iter``, ``max_time``, ...).
        seed : int or None
            Seeds numpy's global RNG, which dwave-hybrid draws from.
        initial_states : samples-like or None
            Kerberos' initial sample (the first state).

        Returns
        -------
        dimod.SampleSet
            Kerberos' result; info has a simulated ``timing`` (``charge_time``, ``run_time``).
        """
        reduction = reduce(bqm, params.pop("preprocess", "roof-duality"))
        if reduction.rest is None:
            return reduction.complete(None, {"timing": {}, "simulated": True})
        rest = self._sample_rest(reduction.rest, params, seed, reduction.states(initial_states))
        return reduction.complete(rest)

    def sample_block(
        self, rests: list[dimod.BinaryQuadraticModel], params: dict[str, Any], seeds, states
    ) -> tuple[list[dimod.SampleSet], dict[str, float]]:
        """Kerberos on each rest (what runs here), charged what Leap bills for the block."""
        from shared.solvers.meters.hybrid import hybrid_charge_seconds

        out = [
            self._sample_rest(rest, dict(params), seed, state)
            for rest, seed, state in zip(rests, seeds, states, strict=True)
        ]
        charge = hybrid_charge_seconds(sum(rest.num_variables for rest in rests), params)
        return out, {"charge_time": charge, "run_time": charge}

    def _sample_rest(self, bqm, params: dict[str, Any], seed, initial_states) -> dimod.SampleSet:
        from hybrid.reference.kerberos import KerberosSampler

        from shared.solvers.meters.hybrid import hybrid_charge_seconds

        if self._qpu is None:
            self._qpu = mock_qpu()
        if seed is not None:
            np.random.seed(seed % 2**32)  # dwave-hybrid's samplers draw from numpy's global RNG
        init = None
        if initial_states is not None:
            init = dimod.SampleSet.from_samples_bqm(initial_states, bqm)
        sampleset = KerberosSampler().sample(bqm, init_sample=init, qpu_sampler=self._qpu, **params)
        charge = hybrid_charge_seconds(bqm.num_variables, params)
        sampleset.info.clear()
        sampleset.info.update(
            {
                "timing": {"charge_time": charge, "run_time": charge},
                "simulated": True,
                "warm_start": initial_states is not None,
                "note": "offline Kerberos: charge_time is what Leap's hybrid solver would bill for "
                "this problem size (its minimum time limit), not a measurement",
            }
        )
        return sampleset
