"""``hybrid`` (Leap's hybrid BQM solver) and ``hybrid-sim`` (dwave-hybrid's Kerberos, offline).

Kerberos races tabu search, simulated annealing and QPU-solved subproblems (energy-impact
decomposition) and keeps the best; ``hybrid-sim`` gives it the offline ``MockDWaveSampler`` as
its QPU, so it runs anywhere and its QPU timing is not real. It is a stand-in for the workflow
shape, not for Leap's proprietary solver, and is always named as such. It reports (and is charged)
the ``charge_time`` Leap's hybrid solver would bill for a problem of its size
(:func:`shared.solvers.qpu_time.hybrid_charge_seconds`).
"""

from __future__ import annotations

from typing import Any

import dimod
import numpy as np

from shared.solvers.base import Availability, Sampler, SolverError
from shared.solvers.composites import reduce
from shared.solvers.dwave import LeapCloudSolver, mock_qpu


class LeapHybridSolver(LeapCloudSolver):
    """``hybrid``: ``LeapHybridSampler`` (needs ``DWAVE_API_TOKEN``); ``time_limit`` in seconds
    (Leap's minimum for the problem size when unset). Warm starts are not supported by Leap's
    BQM solver, so ``initial_states`` are ignored and reported as such. It decomposes problems
    itself: bundles are whole rows, with no QPU graph to embed on."""

    name = "hybrid"
    simulated = False
    parameters: dict[str, list] = {  # noqa: RUF012
        "time_limit": [],
        "initial_states": [],
        "preprocess": [],
    }

    def _make_sampler(self):
        from dwave.system import LeapHybridSampler

        return self._connect(LeapHybridSampler)

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
                self._sampler = self._make_sampler()
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

    def _check_size(self, bqm: dimod.BinaryQuadraticModel) -> None:
        """Refuse what the solver would refuse after a long upload (its size limits)."""
        limit = self._sampler.properties.get("maximum_number_of_variables")
        if limit is not None and bqm.num_variables > int(limit):
            raise SolverError(
                f"{self.name}: the problem is too large for the hybrid solver "
                f"({bqm.num_variables} variables, at most {limit} variables); use smaller "
                "bundles (--bundle-height) or --encoding domain-wall"
            )


class KerberosSolver(Sampler):
    """``hybrid-sim``: dwave-hybrid's Kerberos workflow with ``MockDWaveSampler`` as its QPU.

    Parameters: those of ``hybrid.reference.kerberos.Kerberos`` (``max_iter``, ``max_time``,
    ``convergence``, ``sa_sweeps``, ``tabu_timeout``, ``qpu_reads``, ``max_subproblem_size``);
    defaults in ``KerberosParams``. The first of ``initial_states`` is Kerberos' initial sample.
    """

    name = "hybrid-sim"
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

    def _sample_rest(self, bqm, params: dict[str, Any], seed, initial_states) -> dimod.SampleSet:
        from hybrid.reference.kerberos import KerberosSampler

        from shared.solvers.qpu_time import hybrid_charge_seconds

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
