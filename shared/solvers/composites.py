"""Composites around dimod samplers: what the pipeline adds to any sampler, in one place each
(each a :class:`ChildComposite`: one child, its parameters and properties passed on).

* :class:`SolverComposite`: a child sampler as a registered solver: the registry's default
  parameters, warm starts as ``initial_states`` (tiled over the reads) when the child takes them,
  and the sample set's info (reads, warm start) as the pipeline reports it. ``tabu``,
  ``steepest-descent``, ``sa`` and every ``dimod:`` sampler are this composite.
* :class:`RoofDualityComposite`: fixes the variables that roof duality (dwave-preprocessing)
  proves to take the same value in every optimum, samples only the rest, and completes every
  sample. The reduction is vectorised (:func:`fix_variables`).
* :class:`EmbeddingCacheComposite`: ``FixedEmbeddingComposite`` with the embedding of the BQM's
  structure from our store (:mod:`shared.solvers.qpu.embedding_cache`: found once per structure and
  target, shared between workers), for QPU targets.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import dimod
import numpy as np

from shared.solvers.base import SolverError
from shared.solvers.sampler import Sampler

#: What :class:`EmbeddingCacheComposite` adds to a sample set's info.
EMBEDDING_INFO = (
    "embedding_cache",
    "embedding_cache_hit",
    "embedding_key",
    "qubits",
    "chains",
    "longest_chain",
)
#: Exact reductions :class:`RoofDualityComposite` may apply before sampling.
PREPROCESSORS = ("roof-duality", "none")


class ChildComposite(dimod.ComposedSampler):
    """A composite around one child sampler, in dimod's manner: the child as its only child, the
    child's parameters plus :attr:`added_parameters`, the child's properties as
    ``child_properties``."""

    #: The parameters the composite takes on top of the child's.
    added_parameters: tuple[str, ...] = ()

    def __init__(self, child: Any) -> None:
        self._child = child

    @property
    def children(self) -> list[dimod.Sampler]:
        return [self._child]

    @property
    def parameters(self) -> dict[str, list]:
        return {**self._child.parameters, **{name: [] for name in self.added_parameters}}

    @property
    def properties(self) -> dict[str, Any]:
        return {"child_properties": self._child.properties.copy()}


class SolverComposite(Sampler, ChildComposite):
    """A child ``dimod.Sampler`` run as a registered solver.

    Parameters
    ----------
    child
        The sampler that does the work.
    warm_overrides
        Parameters that replace the given ones when the call has a warm start (e.g.
        ``num_reads=1`` for steepest descent: one descent from the given state).
    """

    def __init__(self, child: dimod.Sampler, warm_overrides: dict[str, Any] | None = None):
        super().__init__(child)
        self.warm_overrides = dict(warm_overrides or {})

    @property
    def parameters(self) -> dict[str, list]:
        child = self._child.parameters
        return {**child, "seed": child.get("seed", []), "initial_states": []}

    def configure(self, params: dict[str, Any], warm: bool) -> tuple[dict[str, Any], dict]:
        """The child's parameters for a call with ``params`` (defaults filled in; with a warm
        start or not), and what to report about that choice in the sample set's info.

        Parameters
        ----------
        params : dict
            Parameters of the call, defaults filled in.
        warm : bool
            Whether the call has a warm start the child takes.

        Returns
        -------
        settings : dict
            The child's parameters (``warm_overrides`` applied when warm).
        report : dict
            Extra info for the sample set (empty here).
        """
        settings = dict(params)
        if warm:
            settings.update(self.warm_overrides)
        return settings, {}

    def run(self, bqm, params: dict[str, Any], *, seed, initial_states) -> dimod.SampleSet:
        """Sample ``bqm`` with the child: seed and warm start passed when the child takes them.

        Parameters
        ----------
        bqm : dimod.BinaryQuadraticModel
            The bundle's QUBO.
        params : dict
            Solver parameters with the defaults, for :meth:`configure`.
        seed : int or None
            Passed when the child has a ``seed`` parameter.
        initial_states : samples-like or None
            Warm start; tiled over the reads when the child has ``initial_states_generator``.

        Returns
        -------
        dimod.SampleSet
            The child's samples, info with ``num_reads`` and ``warm_start``.
        """
        child = self._child.parameters
        warm = initial_states is not None and "initial_states" in child
        settings, report = self.configure(params, warm)
        unknown = sorted(set(settings) - set(child))
        if unknown:  # dimod samplers only warn, and then ignore them: a typo would go unseen
            raise SolverError(
                f"{self.name}: unknown parameters {', '.join(unknown)}; it takes "
                f"{', '.join(sorted(set(child) - {'seed', 'initial_states'}))}"
            )
        if seed is not None and "seed" in child:
            settings["seed"] = seed
        if warm:
            settings["initial_states"] = initial_states
            if "initial_states_generator" in child:
                settings.setdefault("initial_states_generator", "tile")
        sampleset = self._child.sample(bqm, **settings)
        sampleset.resolve()
        sampleset.info.update(report)
        sampleset.info.setdefault("num_reads", len(sampleset))
        sampleset.info.setdefault("warm_start", warm)
        return sampleset


def fix_variables(
    bqm: dimod.BinaryQuadraticModel, fixed: dict[int, int]
) -> tuple[dimod.BinaryQuadraticModel, np.ndarray]:
    """The BQM on the free variables, relabelled 0..m-1, and their original numbers.

    Vectorised equivalent of ``bqm.fix_variables`` (dimod's is quadratic in the number of
    variables and took 0.9 s on a full-resolution row).

    Parameters
    ----------
    bqm
        A BQM on the variables 0..n-1.
    fixed
        Variable -> value (0 or 1) of the fixed variables.

    Returns
    -------
    tuple
        The reduced BINARY BQM and the original numbers of its variables 0..m-1.
    """
    n = bqm.num_variables
    vectors = bqm.binary.to_numpy_vectors(variable_order=range(n))
    linear, (rows, cols, quadratic), offset = vectors[0], vectors[1], vectors[2]
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


@dataclass(frozen=True)
class Reduction:
    """A bundle after the exact classical step: what roof duality fixed and the BQM left.

    ``rest`` is the BQM on the free variables relabelled 0..m-1 (None when nothing is left:
    the bundle is solved on the host), ``free`` their numbers in the bundle."""

    bqm: dimod.BinaryQuadraticModel
    fixed: dict[int, int]
    rest: dimod.BinaryQuadraticModel | None
    free: np.ndarray
    preprocess: str

    @property
    def info(self) -> dict[str, Any]:
        """What a sample set reports about the reduction (per-level counts add these up;
        ``fixed_variables``, the bundle's variables roof duality fixed, give the pipeline's
        provenance map its :attr:`shared.provenance_map.Stage.ROOF_DUALITY` pixels)."""
        n = self.bqm.num_variables
        return {
            "preprocess": self.preprocess,
            "fixed_fraction": len(self.fixed) / max(n, 1),
            "variables": n,
            "residual_variables": int(self.free.size),
            "fixed_variables": sorted(int(v) for v in self.fixed),
        }

    def states(self, initial_states: Any) -> Any:
        """A warm start over the bundle's variables, restricted to the free ones."""
        if initial_states is None:
            return None
        states, _ = dimod.as_samples(initial_states)
        return states[:, self.free], list(range(self.free.size))

    def complete(self, sampleset: dimod.SampleSet | None, info: dict | None = None):
        """Every sample of ``sampleset`` (on ``rest``; None: nothing was left) with the fixed
        values filled in, as a BINARY sample set on the bundle's variables 0..n-1.

        Parameters
        ----------
        sampleset : dimod.SampleSet or None
            The child's samples of ``rest``.
        info : dict, optional
            Info of the result (default: the child's, plus :attr:`info`).

        Returns
        -------
        dimod.SampleSet
            Energies are the bundle's: ``rest`` carries the fixed part in its offset, and
            keeping them (not recomputing) keeps which of two near-equal reads is best.
        """
        n = self.bqm.num_variables
        samples = np.zeros((1, n), dtype=np.int8)
        if self.fixed:
            samples[:, list(self.fixed)] = list(self.fixed.values())
        variables = list(range(n))
        if sampleset is None:
            return dimod.SampleSet.from_samples(
                (samples, variables),
                vartype=dimod.BINARY,
                energy=self.bqm.energies((samples, variables)),
                info={**self.info, **(info or {})},
            )
        sampleset.resolve()
        order = np.fromiter(sampleset.variables, dtype=np.int64, count=self.free.size)
        record = sampleset.record
        samples = np.repeat(samples, len(record), axis=0)
        samples[:, self.free[order]] = record.sample
        return dimod.SampleSet.from_samples(
            (samples, variables),
            vartype=dimod.BINARY,
            energy=record.energy,
            info={**sampleset.info, **self.info, **(info or {})},
            num_occurrences=record.num_occurrences,
        )


def reduce(bqm: dimod.BinaryQuadraticModel, preprocess: str = "roof-duality") -> Reduction:
    """Fix what roof duality (dwave-preprocessing; exact: a max-flow, milliseconds) proves to
    take the same value in every optimum of a BINARY BQM on the variables 0..n-1.

    Parameters
    ----------
    bqm : dimod.BinaryQuadraticModel
        The bundle's QUBO.
    preprocess : str, default "roof-duality"
        ``"roof-duality"`` or ``"none"`` (nothing fixed).

    Returns
    -------
    Reduction
        The fixed values and the BQM left (None when every variable is fixed).

    Raises
    ------
    SolverError
        For an unknown ``preprocess``.
    """
    if preprocess not in PREPROCESSORS:
        raise SolverError(
            f"unknown preprocess {preprocess!r}; choose from {', '.join(PREPROCESSORS)}"
        )
    fixed: dict[int, int] = {}
    if preprocess == "roof-duality":
        from dwave.preprocessing import roof_duality

        _, fixed = roof_duality(bqm, strict=True)
    if len(fixed) == bqm.num_variables:
        return Reduction(bqm, fixed, None, np.zeros(0, dtype=np.int64), preprocess)
    if not fixed:  # the bundle itself, on its own variables 0..n-1
        return Reduction(bqm, fixed, bqm, np.arange(bqm.num_variables), preprocess)
    rest, free = fix_variables(bqm, fixed)
    return Reduction(bqm, fixed, rest, free, preprocess)


class RoofDualityComposite(ChildComposite):
    """Roof-duality fixing (:func:`reduce`) before the child samples the rest.

    Fixes most variables of domain-wall rows whose smoothness is convex (submodular rows); with
    the accurate preset's truncated smoothness about 59 %, 29 % and 19 % of Tsukuba's at its
    three levels (docs/benchmarks.md). BINARY BQMs on the variables 0..n-1 (the codecs'
    bundles). ``preprocess="none"`` fixes nothing. Given ``initial_states`` (when the child takes
    them) are restricted to the free variables.
    """

    added_parameters = ("preprocess",)

    def sample(
        self,
        bqm: dimod.BinaryQuadraticModel,
        *,
        preprocess: str = "roof-duality",
        initial_states: Any = None,
        **params: Any,
    ) -> dimod.SampleSet:
        """Fix what roof duality proves, sample the rest with the child and complete every sample.

        Parameters
        ----------
        bqm : dimod.BinaryQuadraticModel
            BINARY BQM on the variables 0..n-1.
        preprocess : str, default "roof-duality"
            ``"roof-duality"`` or ``"none"``.
        initial_states : samples-like, optional
            Warm start over all n variables; its free columns go to the child.
        **params
            The child's parameters.

        Returns
        -------
        dimod.SampleSet
            BINARY samples on 0..n-1; info has ``preprocess``, ``fixed_fraction``,
            ``variables`` and ``residual_variables``.
        """
        reduction = reduce(bqm, preprocess)
        if reduction.rest is None:
            return reduction.complete(None)
        if initial_states is not None:
            params["initial_states"] = reduction.states(initial_states)
        return reduction.complete(self._child.sample(reduction.rest, **params))


class EmbeddingCacheComposite(ChildComposite):
    """dwave-system's ``FixedEmbeddingComposite`` on a structured child (a QPU or its mock),
    with the embedding looked up per BQM structure in an
    :class:`~shared.solvers.qpu.embedding_cache.EmbeddingCache` (computed and stored on a miss).

    Parameters
    ----------
    child
        A structured sampler (``DWaveSampler``, ``MockDWaveSampler``).
    cache
        Where embeddings are kept.
    target
        Name of the child's graph in the cache keys (topology and edge fingerprint).
    solver
        Solver name under which embedding sizes are recorded (for the QPU time estimates).
    timeout
        Seconds minorminer may search on a miss (None: the cache's default).
    """

    added_parameters = ("chain_strength", "chain_break_method")

    def __init__(
        self, child: Any, cache, target: str, solver: str, timeout: float | None = None
    ) -> None:
        super().__init__(child)
        self.cache, self.target, self.solver = cache, target, solver
        #: Seconds minorminer may search on a miss (the adapter's ``embedding_timeout``).
        self.timeout = timeout
        #: one FixedEmbeddingComposite per embedding: its chain structure is built once, not per
        #: bundle (that was ~10 % of a qpu-sim bundle's time)
        self._composites: dict[str, Any] = {}

    def embedding(self, bqm: dimod.BinaryQuadraticModel) -> tuple[dict, str, str]:
        """(embedding, where it came from, cache key) of ``bqm``'s structure. Seed 0, not the
        bundle's: the embedding depends on the structure only, whichever worker finds it.

        Parameters
        ----------
        bqm : dimod.BinaryQuadraticModel
            The bundle; only its structure is looked up.

        Returns
        -------
        tuple
            ``(embedding, source, key)`` of :meth:`EmbeddingCache.lookup`.
        """
        return self.cache.lookup(
            bqm, self._child.edgelist, self.target, self.timeout, seed=0, solver=self.solver
        )

    def sample(
        self, bqm: dimod.BinaryQuadraticModel, reduction: Reduction | None = None, **params: Any
    ) -> dimod.SampleSet:
        """Sample ``bqm`` on the child through the cached embedding of its structure.

        Parameters
        ----------
        bqm : dimod.BinaryQuadraticModel
            The bundle's QUBO, or the BQM left of it by ``reduction``.
        reduction : Reduction, optional
            When ``bqm`` is ``reduction.rest``: the bundle's embedding restricted to the free
            variables is used (a sub-structure of the bundle's, so its chains and couplers are
            there): one embedding per bundle shape whatever roof duality left.
        **params
            Parameters of ``FixedEmbeddingComposite`` and the child (``chain_strength``, ...).

        Returns
        -------
        dimod.SampleSet
            Unembedded samples; info has the :data:`EMBEDDING_INFO` fields.
        """
        from dwave.system import FixedEmbeddingComposite

        from shared.solvers.qpu.embedding_cache import EmbeddingSize

        if reduction is None or not reduction.fixed:
            embedding, source, key = self.embedding(bqm)
            composite = self._composites.get(key)
            if composite is None:
                composite = self._composites[key] = FixedEmbeddingComposite(self._child, embedding)
        else:
            whole, source, key = self.embedding(reduction.bqm)
            embedding = {i: whole[int(v)] for i, v in enumerate(reduction.free)}
            composite = FixedEmbeddingComposite(self._child, embedding)
        sampleset = composite.sample(bqm, return_embedding=False, **params)
        sampleset.resolve()
        size = EmbeddingSize.of(embedding)
        values = (source, source != "computed", key, size.qubits, size.chains, size.longest_chain)
        sampleset.info.update(zip(EMBEDDING_INFO, values, strict=True))
        return sampleset
