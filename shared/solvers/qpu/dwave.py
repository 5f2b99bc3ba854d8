"""``qpu`` and ``qpu-sim``: a D-Wave base sampler in ``FixedEmbeddingComposite``, the Ocean way.

The two differ only in the base sampler: ``DWaveSampler`` (token, solver, region and endpoint
from :class:`shared.config.Settings`) or ``MockDWaveSampler`` on a Pegasus P16 graph, which runs
steepest descent on the embedded problem offline. Everything else is shared: the embedding comes
from :mod:`shared.solvers.qpu.embedding_cache` (found once per bundle structure), chain strength is
uniform torque compensation with the paper's prefactor 1.414, chains are resolved by majority
vote, and the sample set is resolved inside the call. D-Wave reports microseconds; we report
seconds. The mock's own timing is a fixed demonstration value, so ``qpu-sim`` reports instead
what D-Wave's published timing model says an Advantage QPU would take for the same embedding and
parameters (:func:`shared.solvers.meters.qpu.qpu_access_seconds`), marked ``simulated``; that is
what the service charges for it.

The API token never leaves ``Settings``: it is passed to ``DWaveSampler`` and scrubbed from every
message we raise or log (:mod:`shared.solvers.qpu.leap`).
"""

from __future__ import annotations

import contextlib
import logging
import threading
from typing import Any

import dimod
import numpy as np

from shared.solvers.base import Availability, SolverError
from shared.solvers.composites import (
    EMBEDDING_INFO,
    EmbeddingCacheComposite,
    Reduction,
    reduce,
)
from shared.solvers.meters.qpu import qpu_access_seconds
from shared.solvers.params import DEFAULT_NUM_READS  # noqa: F401 (one default, re-exported)
from shared.solvers.qpu import leap
from shared.solvers.qpu.bundle_shapes import auto_width_key, shape_bqm
from shared.solvers.qpu.embedding_cache import EmbeddingCache, default_cache
from shared.solvers.qpu.packing import PackedCalls
from shared.solvers.qpu.qpu_settings import chain_strength, reverse_anneal
from shared.solvers.qpu.structure_keys import graph_fingerprint
from shared.solvers.sampler import Sampler

log = logging.getLogger(__name__)

MOCK_TOPOLOGY = ("pegasus", [16])
#: ``timing_solver`` not looked up yet.
_UNKNOWN = object()


def _seconds(timing: dict[str, Any]) -> dict[str, float]:
    """D-Wave's microsecond timing fields in seconds."""
    return {key: float(value) * 1e-6 for key, value in timing.items() if _is_number(value)}


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


class _EmbeddedQPU(Sampler):
    """The shared code path; subclasses supply the base sampler. The work is done by
    :class:`~shared.solvers.composites.EmbeddingCacheComposite` on the base sampler; this adds
    the paper's chain strength, majority-vote chains, warm starts as reverse anneals and the
    timing in seconds."""

    simulated: bool
    parameters: dict[str, list] = {  # noqa: RUF012 (dimod's interface; others go to SAPI)
        "num_reads": [],
        "chain_strength": [],
        "annealing_time": [],
        "anneal_schedule": [],
        "seed": [],
        "initial_states": [],
        "preprocess": [],
        "bundles_per_call": [],
    }

    def __init__(self, cache: EmbeddingCache | None = None) -> None:
        self._cache = cache
        self._sampler: Any = None
        self._target = ""
        self._composite: EmbeddingCacheComposite | None = None
        self._lock = threading.Lock()
        self._timing_solver: Any = _UNKNOWN

    @property
    def properties(self) -> dict[str, Any]:
        return {"simulated": self.simulated}

    @property
    def cache(self) -> EmbeddingCache:
        return self._cache if self._cache is not None else default_cache()

    def _make_sampler(self):
        raise NotImplementedError

    def _secret(self) -> str | None:
        return None

    def _seed_sampler(self, sampler, seed: int | None) -> None:
        """Make a simulated sampler reproducible per bundle (a real QPU takes no seed)."""

    def sampler(self):
        """The base sampler, built once (DWaveSampler fetches the solver's graph on creation)."""
        with self._lock:
            if self._sampler is None:
                sampler = self._build_sampler()
                topology = sampler.properties.get("topology", {})
                shape = "x".join(map(str, topology.get("shape", [])))
                self._target = (
                    f"{topology.get('type', 'graph')}{shape}-{graph_fingerprint(sampler.edgelist)}"
                )
                self._sampler = sampler
            return self._sampler

    def _build_sampler(self):
        """:meth:`_make_sampler`, its errors as ours (planning builds it outside any solve: an
        unreachable endpoint is then a transient error, a refused token a final one)."""
        with self.translating():
            return self._make_sampler()

    def timing_solver(self) -> Any:
        """The cloud solver whose ``problem_timing_data`` the estimates use (``LiveTiming``);
        None for the simulator, or when it cannot be reached (no token, no network: the offline
        model will do). Looked up once."""
        if self._timing_solver is _UNKNOWN:
            cloud = None
            if not self.simulated:
                try:
                    cloud = getattr(self.sampler(), "solver", None)
                except Exception:
                    cloud = None
            if not callable(getattr(cloud, "estimate_qpu_access_time", None)):
                cloud = None
            self._timing_solver = cloud
        return self._timing_solver

    def composite(self) -> EmbeddingCacheComposite:
        """The base sampler inside the cached-embedding composite, kept while the base sampler,
        cache and target stay the same (it holds one ``FixedEmbeddingComposite`` per
        embedding)."""
        base, cache = self.sampler(), self.cache
        kept = self._composite
        if kept is None or (kept.children[0], kept.cache, kept.target) != (
            base,
            cache,
            self._target,
        ):
            kept = self._composite = EmbeddingCacheComposite(
                base, cache, self._target, self.name, self.settings.embedding_timeout
            )
        return kept

    def run(self, bqm, params: dict[str, Any], *, seed, initial_states) -> dimod.SampleSet:
        """Classical first: what roof duality fixes is solved on the host (a bundle with
        nothing left never reaches the QPU and is charged nothing); the rest is sampled on the
        QPU through the bundle shape's embedding restricted to it (:meth:`sample_residual`)."""
        reduction = reduce(bqm, params.pop("preprocess", "roof-duality"))
        params.pop("bundles_per_call", None)  # one bundle here
        if reduction.rest is None:
            return reduction.complete(None, {"timing": {}, "simulated": self.simulated})
        sampleset = self.sample_residual(
            reduction, params, seed=seed, initial_states=reduction.states(initial_states)
        )
        return reduction.complete(sampleset)

    def sample_residual(
        self, reduction: Reduction, params: dict[str, Any], *, seed, initial_states
    ) -> dimod.SampleSet:
        """Sample ``reduction.rest`` on the QPU: the paper's chain strength, majority vote, a
        warm start as a reverse anneal, the timing in seconds."""
        from dwave.embedding.chain_breaks import majority_vote

        composite = self.composite()
        bqm = reduction.rest
        assert bqm is not None
        strength = float(params.pop("chain_strength", None) or chain_strength(bqm))
        settings = params
        if initial_states is not None:
            states, labels = dimod.as_samples(initial_states)
            reverse_anneal(settings, dict(zip(labels, states[0].tolist(), strict=True)))
        # The mock's seed is sampler state, so simulated calls are serialised.
        with self._lock if self.simulated else contextlib.nullcontext():
            self._seed_sampler(composite.children[0], seed)
            sampleset = composite.sample(
                bqm,
                reduction,
                chain_strength=strength,
                chain_break_method=majority_vote,
                **settings,
            )
        best = sampleset.first
        record = sampleset.record
        breaks = np.asarray(record.chain_break_fraction, dtype=float)
        weights = np.asarray(record.num_occurrences, dtype=float)
        info = sampleset.info
        timing = self._timing(info, info["qubits"], settings)
        for key in [key for key in info if key not in EMBEDDING_INFO]:
            del info[key]  # D-Wave's own timing (microseconds) and problem metadata
        sampleset.info.update(
            timing=timing,
            chain_strength=strength,
            chain_break_fraction=float(best.chain_break_fraction),
            mean_chain_break_fraction=float(np.average(breaks, weights=weights)),
            num_reads=int(weights.sum()),
            qpu_access_time=timing.get("qpu_access_time", 0.0),
            simulated=self.simulated,
            warm_start=initial_states is not None,
        )
        if self.simulated:
            sampleset.info["note"] = (
                "offline MockDWaveSampler: qpu_access_time is the Advantage timing model's value "
                "for this embedding and these parameters, not a measurement"
            )
        return sampleset

    def _timing(self, info: dict, qubits: int, settings: dict[str, Any]) -> dict[str, float]:
        """The QPU's own timing, in seconds."""
        return _seconds(info.get("timing", {}))

    def translate(self, error: Exception) -> SolverError:
        """Ocean's exceptions as our typed errors, with the token scrubbed from the text."""
        return leap.translate(self.name, error, self.settings, self._secret())


class _SegmentsOnGraph(PackedCalls, _EmbeddedQPU):
    """What planning a level asks of a QPU solver (``LevelInference.plan``): the widest
    row segment that embeds on its graph, and each bundle shape's embedding, found once."""

    def widest_bundle(
        self, *, encoding: str, candidates: int, height: int, row_width: int, margin: int
    ) -> int | None:
        """``--bundle-width auto``: the widest row segment whose QUBO embeds on this solver's
        graph (None: whole rows), found once per shape and target and kept in the embedding
        cache together with that shape's embedding, which every such bundle then reuses."""
        base = self.sampler()
        width = self.cache.widest(
            lambda width: shape_bqm(str(encoding), height, width, candidates),
            row_width=row_width,
            narrowest=2 * margin + 1,
            target_edges=base.edgelist,
            target=self._target,
            timeout=self.settings.embedding_search_timeout,
            solver=self.name,
        )
        key = auto_width_key(self.name, str(encoding), height, candidates, row_width, margin)
        self.cache.record_width(key, width)
        return width

    def embed_shapes(
        self, *, encoding: str, candidates: int, shapes: list[tuple[int, int]]
    ) -> None:
        """Embed each bundle shape (rows, columns) of a level once, with its disjoint copies
        (:func:`~shared.solvers.qpu.packing.copies`), before its bundles fan out, so that no two
        workers compute the same embedding at the same time."""
        with self.translating():
            for height, width in shapes:
                self.shape_copies(shape_bqm(str(encoding), height, width, candidates))


class QPUSolver(_SegmentsOnGraph):
    """``qpu``: a D-Wave Advantage QPU through Leap (needs ``DWAVE_API_TOKEN``; the token,
    solver, region and endpoint from ``Settings`` by :mod:`~shared.solvers.qpu.leap`).

    Parameters: ``num_reads`` (default 500), ``annealing_time`` (us), ``chain_strength``
    (overrides torque compensation), ``anneal_schedule`` (for warm starts), and any other
    ``DWaveSampler`` parameter.
    """

    name = "qpu"
    simulated = False

    def available(self) -> Availability:
        return leap.available(self.settings)

    def _secret(self) -> str | None:
        return leap.secret(self.settings)

    def _make_sampler(self):
        from dwave.system import DWaveSampler

        settings = self.settings
        solver = settings.dwave_solver
        return leap.connect(
            self.name, DWaveSampler, settings, **({"solver": solver} if solver else {})
        )


class SimulatedQPUSolver(_SegmentsOnGraph):
    """``qpu-sim``: the ``qpu`` code path on ``MockDWaveSampler`` (Pegasus P16), offline.

    The mock runs steepest descent per read on the embedded problem; ``annealing_time`` and
    warm-start (reverse anneal) parameters are accepted but have no effect there. ``num_reads``
    defaults to 100, not 500 (:class:`~shared.solvers.params.SimulatedQPUParams` says why).
    """

    name = "qpu-sim"
    simulated = True

    def available(self) -> Availability:
        return Availability(True, "offline simulator (MockDWaveSampler, Pegasus P16)")

    def _seed_sampler(self, sampler, seed: int | None) -> None:
        sampler.substitute_kwargs["seed"] = None if seed is None else seed % 2**32

    def _timing(self, info: dict, qubits: int, settings: dict[str, Any]) -> dict[str, float]:
        """What a real QPU would take for this embedding and these parameters (the model the
        estimates use), instead of the mock's fixed demonstration timing."""
        try:
            return {"qpu_access_time": qpu_access_seconds(qubits, settings)}
        except ValueError as error:  # what SAPI would refuse, e.g. a schedule and a time
            raise SolverError(f"{self.name}: invalid sampling parameters: {error}") from None

    def _make_sampler(self):
        return mock_qpu()


def mock_qpu():
    """The offline QPU of ``qpu-sim`` and ``hybrid-sim``: dwave-system's ``MockDWaveSampler`` on
    :data:`MOCK_TOPOLOGY`, sampling with its default substitute (dwave-samplers'
    ``SteepestDescentSampler``: one descent from a random state per read), parameter warnings
    off (we pass QPU parameters such as ``annealing_time`` that it accepts but does not
    simulate). A reverse anneal's ``initial_state`` (a warm start) is the first read's start:
    the mock's stand-in for an anneal that begins at the given state.

    Returns
    -------
    MockDWaveSampler
        A structured sampler with a QPU's properties; seeded per call through
        ``substitute_kwargs["seed"]``.
    """
    from dwave.system.testing import MockDWaveSampler

    class WarmMock(MockDWaveSampler):
        def sample(self, bqm, **kwargs):
            state = kwargs.get("initial_state")
            if not state:
                return super().sample(bqm, **kwargs)
            qubits = list(state)
            self.substitute_kwargs.update(
                initial_states=([list(state.values())], qubits),
                initial_states_generator="random",
            )
            try:
                return super().sample(bqm, **kwargs)
            finally:
                self.substitute_kwargs.pop("initial_states")
                self.substitute_kwargs.pop("initial_states_generator")

    topology_type, shape = MOCK_TOPOLOGY
    return WarmMock(topology_type=topology_type, topology_shape=shape, parameter_warnings=False)
