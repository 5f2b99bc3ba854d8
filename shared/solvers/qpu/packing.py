"""Many bundles per QPU call: disjoint copies of a bundle shape's embedding, and BQMs joined.

A bundle's embedding uses a few hundred to a thousand qubits of an Advantage QPU's 5,600, and a
QPU call costs its programming (~15 ms) before the first read, so one call per bundle pays that
15 ms again and again. :func:`copies` finds, once per bundle shape and target, further disjoint
embeddings of the shape next to the first one (minorminer on the qubits left, greedily, as
``minorminer.utils.parallel_embeddings.find_multiple_embeddings`` does) and keeps them in the
embedding store with the others; the QPU solvers then send up to that many bundles' rests (what
roof duality left, each on its copy restricted to its free variables) as one problem
(:func:`joined`), unembed each one's samples separately and share the call's access time by
qubits.
"""

from __future__ import annotations

import contextlib
import json
import logging
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import dimod
import numpy as np

from shared.activity import report
from shared.config import Settings
from shared.solvers.base import SolveResult, result_of
from shared.solvers.composites import Reduction, reduce
from shared.solvers.params import MAX_BUNDLES_PER_CALL
from shared.solvers.qpu.embedding_cache import EmbeddingCache
from shared.solvers.qpu.embedding_search import Embedding, is_valid_on
from shared.solvers.qpu.structure_keys import structure_digest

log = logging.getLogger(__name__)

#: Copies of one bundle shape per QPU call at most (a call's reads serve all of them): the
#: ``bundles_per_call`` parameter's default and bound.
MAX_COPIES: int = MAX_BUNDLES_PER_CALL


#: Qubits a copy is assumed to need, as a multiple of the assumed embedding's, before the
#: shape's copies on the chip were found: the 4x4 tile's translated copies on Advantage P16
#: (benchmarks/tile_copies.py) are 25 of 48 variables (chip / copies = 2.3 times the assumed
#: qubits) and 9 of 80 (3.9 times), so 4 never assumes more copies than are found.
PACKING_SLACK = 4


#: Copies of a shape kept at most (more than a call takes: the count found feeds the estimates).
STORED_COPIES = 64


def copies_key(target: str, digest: str) -> str:
    """Store key of a shape's disjoint embeddings on a target (translated tile copies)."""
    return f"copies-tiled-{target}-{digest}"


def copies(
    cache: EmbeddingCache,
    bqm: dimod.BinaryQuadraticModel,
    sampler: Any,
    target: str,
    first: Callable[[], Embedding],
    limit: int = MAX_COPIES,
    solver: str | None = None,
    progress: Callable[[str], None] | None = None,
    tries: int = Settings.model_fields["embedding_tries"].default,
) -> tuple[list[Embedding], str]:
    """Disjoint embeddings of ``bqm``'s structure on ``sampler``'s graph: found once per shape
    and target, then read from the store. On a Pegasus or Zephyr chip they are translations of
    one embedding into a small sublattice (:mod:`shared.solvers.qpu.tile_embedding`: a seed and a
    budget of ``Settings.embedding_tries`` tries, so the same on a busy machine); the first
    copy then becomes the shape's embedding in ``cache``. Otherwise (another graph, or no
    sublattice embeds the shape in its tries) only ``first()``: one bundle per call.

    Parameters
    ----------
    cache : EmbeddingCache
        Where they are kept (its store).
    bqm : dimod.BinaryQuadraticModel
        A bundle of the shape.
    sampler : dimod.Structured
        The QPU (or its mock): ``properties["topology"]``, ``nodelist``, ``edgelist``.
    target : str
        The target's name in keys (topology and graph fingerprint).
    first : callable
        The shape's own embedding when no copies are found (:meth:`EmbeddingCache.lookup`).
    limit : int
        Copies at most.
    solver : str, optional
        Solver name under which their number is recorded for the estimates.
    progress : callable, optional
        Told what the search is doing, in words (default: logged).
    tries : int
        Sublattices tried (the adapter's ``Settings.embedding_tries``).

    Returns
    -------
    copies : list of dict
        At least one; pairwise disjoint chains.
    source : str
        ``"memory"``, ``"store"`` or ``"computed"``.
    """
    from shared.solvers.qpu.tile_embedding import translated_copies

    digest = structure_digest(bqm)
    key = copies_key(target, digest)
    cached = f"embedding a {bqm.num_variables}-variable tile shape: cached"
    if key in cache.copies:
        report(cached)
        return cache.copies[key][:limit], "memory"
    stored = cache.store.get(key)
    if stored is not None:
        found = [{int(v): chain for v, chain in e.items()} for e in json.loads(stored)]
        # the target key holds the graph's fingerprint: checking the first copy finds a
        # stale record (another shape under the key) without rebuilding the graph per copy
        if found and is_valid_on(found[0], bqm, sampler.edgelist):
            cache.remember(bqm, target, found[0], solver)
            cache.copies[key] = found
            report(cached)
            return found[:limit], "store"

    def searching(text: str) -> None:  # logged, and shown in the job's status
        (progress or (lambda text: log.info("%s: %s", key, text)))(text)
        report(text)

    found = translated_copies(
        bqm, sampler.properties, list(sampler.nodelist), list(sampler.edgelist),
        tries=tries, limit=max(limit, STORED_COPIES), progress=searching,
        store=cache.store,
    )  # fmt: skip
    if found:
        cache.remember(bqm, target, found[0], solver, computed=True)
    else:
        log.warning(
            "%s: no sublattice of the QPU graph takes this shape within QHSM_EMBEDDING_TRIES="
            "%d tries; one bundle per QPU call (raise QHSM_EMBEDDING_TRIES, or use "
            "--encoding domain-wall for fewer variables)", key, tries,
        )  # fmt: skip
        searching(f"embedding a {bqm.num_variables}-variable shape on the whole QPU graph")
        found = [first()]
    log.info("%d disjoint embeddings of %s", len(found), key)
    cache.copies[key] = found
    cache.store.set(key, json.dumps(found))
    if solver is not None:
        cache.store.set(count_key(solver, digest), str(len(found)))
    return found[:limit], "computed"


def count_key(solver: str, digest: str) -> str:
    """Store key of how many disjoint embeddings ``solver`` found of a structure."""
    return f"copies-count-{solver}-{digest}"


def known_copies(cache: EmbeddingCache | None, solver: str, digest: str) -> int | None:
    """How many disjoint embeddings of a structure ``solver`` found, if any run looked.

    Parameters
    ----------
    cache : EmbeddingCache or None
        Where they are kept.
    solver : str
        Solver name.
    digest : str
        The structure's digest.

    Returns
    -------
    int or None
    """
    if cache is None:
        return None
    try:
        stored = cache.store.get(count_key(solver, digest))
    except Exception:  # an unreachable store only costs us the better estimate
        return None
    return None if stored is None else int(stored)


def packed_copies(
    cache: EmbeddingCache | None,
    config: Any,
    shape: tuple[int, int],
    candidates: int,
    assume: bool = False,
) -> int:
    """Bundles of a shape per QPU call: the disjoint embeddings a run found
    (:func:`copies`), else 1 (on Tsukuba's ``auto`` widths the search found no second copy
    within its time limit, so packing is not assumed before it has been seen) or, with
    ``assume`` (the residual design's small tiles), as many as :data:`PACKING_SLACK` times the
    assumed qubits fit on the chip (at most the translated copies measured on Advantage).

    Parameters
    ----------
    cache : EmbeddingCache or None
        Where the number found is looked up.
    config : MatchConfig
        The run's solver and encoding.
    shape : (int, int)
        Bundle rows and columns.
    candidates : int
        Labels per pixel.
    assume : bool
        Assume copies fill the chip (:data:`PACKING_SLACK`) before a search was seen.

    Returns
    -------
    int
        At least 1.
    """
    from shared.encodings import get_codec
    from shared.solvers.meters.qpu import MAX_QUBITS, assumed_qubits
    from shared.solvers.qpu.bundle_shapes import bundle_digest

    per_pixel = get_codec(config.encoding).variables_per_pixel(candidates)
    variables = shape[0] * shape[1] * per_pixel
    if variables > MAX_QUBITS:
        return 1
    digest = bundle_digest(str(config.encoding), shape[0], shape[1], candidates)
    assumed = max(1, MAX_QUBITS // (PACKING_SLACK * assumed_qubits(variables))) if assume else 1
    found = known_copies(cache, config.solver, digest) or assumed
    return min(found, int(config.solver_params.get("bundles_per_call", MAX_COPIES)))


def joined(rests: list[dimod.BinaryQuadraticModel]) -> dimod.BinaryQuadraticModel:
    """The disjoint union of BINARY BQMs on 0..m_i-1: the i-th on the next m_i variables.

    Parameters
    ----------
    rests : list of dimod.BinaryQuadraticModel
        BQMs on the variables 0..m_i-1.

    Returns
    -------
    dimod.BinaryQuadraticModel
        BINARY, on 0..sum(m_i)-1; its energy is the sum of theirs.
    """
    linear, rows, cols, quadratic, offset, start = [], [], [], [], 0.0, 0
    for rest in rests:
        h, (r, c, q), o, *_ = rest.binary.to_numpy_vectors(variable_order=range(rest.num_variables))
        linear.append(h)
        rows.append(r + start)
        cols.append(c + start)
        quadratic.append(q)
        offset += float(o)
        start += rest.num_variables
    return dimod.BinaryQuadraticModel.from_numpy_vectors(
        np.concatenate(linear),
        (np.concatenate(rows), np.concatenate(cols), np.concatenate(quadratic)),
        offset,
        dimod.BINARY,
    )


def split(
    sampleset: dimod.SampleSet, rests: list[dimod.BinaryQuadraticModel]
) -> list[dimod.SampleSet]:
    """Each rest's samples out of a sample set of their :func:`joined` BQM.

    Parameters
    ----------
    sampleset : dimod.SampleSet
        Samples on 0..sum(m_i)-1.
    rests : list of dimod.BinaryQuadraticModel
        The joined BQMs, in order.

    Returns
    -------
    list of dimod.SampleSet
        One per rest, on its variables 0..m_i-1, energies its own.
    """
    position = {v: i for i, v in enumerate(sampleset.variables)}
    samples = sampleset.record.sample
    out, start = [], 0
    for rest in rests:
        columns = [position[v] for v in range(start, start + rest.num_variables)]
        out.append(
            dimod.SampleSet.from_samples_bqm((samples[:, columns], range(rest.num_variables)), rest)
        )
        start += rest.num_variables
    return out


class PackedCalls:
    """What the QPU solvers add for a task's bundles: :meth:`solve_batch` (``shared.inference.qubo``
    calls it with all of a task's bundles). Mixed into ``shared.solvers.qpu.dwave``'s QPU samplers,
    whose methods (``composite``, ``sampler``, ``_timing``, ...) it uses."""

    simulated: bool
    name: str
    cache: EmbeddingCache
    _target: str
    _lock: Any
    defaults: dict[str, Any]
    settings: Settings

    if TYPE_CHECKING:  # the QPU sampler's own (not defined here: they would shadow them)

        def composite(self) -> Any: ...
        def sampler(self) -> Any: ...
        def translating(self) -> Any: ...
        def _seed_sampler(self, sampler: Any, seed: int | None) -> None: ...
        def _timing(self, info: dict, qubits: int, settings: dict) -> dict[str, float]: ...

    def solve_batch(self, problems: list[tuple], **params: Any) -> list[SolveResult]:
        """Solve bundles ``(bqm, seed, warm start or None)`` with as few QPU calls as their
        shapes' disjoint embeddings allow (:mod:`shared.solvers.qpu.packing`): roof duality first on
        each; the rests of up to that many bundles of a shape in one call, each on its own copy
        restricted to its free variables; the call's access time shared by qubits.

        Parameters
        ----------
        problems : list of tuple
            Each bundle's QUBO on 0..n-1, seed and warm start (n values or None).
        **params
            Solver parameters over the defaults.

        Returns
        -------
        list of SolveResult
            One per bundle, in order; info has ``bundles_per_call``.
        """
        started = time.perf_counter()
        params = {**self.defaults, **params}
        preprocess = params.pop("preprocess", "roof-duality")
        per_call = int(params.pop("bundles_per_call", MAX_COPIES))
        with self.translating():
            reductions = [reduce(bqm, preprocess) for bqm, _, _ in problems]
            sets: list[dimod.SampleSet | None] = [None] * len(problems)
            groups: dict[str, list[int]] = {}
            for i, reduction in enumerate(reductions):
                if reduction.rest is not None:
                    groups.setdefault(structure_digest(reduction.bqm), []).append(i)
            for members in groups.values():
                found, source = self.shape_copies(reductions[members[0]].bqm)
                found = found[:per_call]
                for start in range(0, len(members), len(found)):
                    chunk = members[start : start + len(found)]
                    states = [reductions[i].states(_states(problems[i][2])) for i in chunk]
                    parts = self._sample_packed(
                        [reductions[i] for i in chunk], found[: len(chunk)], dict(params),
                        problems[chunk[0]][1],
                        states,
                    )  # fmt: skip
                    for i, part in zip(chunk, parts, strict=True):
                        part.info["embedding_cache"] = source
                        sets[i] = part
        each = (time.perf_counter() - started) / max(len(problems), 1)
        return [
            result_of(
                reduction.complete(sampleset)
                if sampleset is not None
                else reduction.complete(None, {"timing": {}, "simulated": self.simulated}),
                reduction.bqm,
                each,
            )
            for reduction, sampleset in zip(reductions, sets, strict=True)
        ]

    def shape_copies(
        self, bqm: dimod.BinaryQuadraticModel, progress: Callable[[str], None] | None = None
    ) -> tuple[list[Embedding], str]:
        """:func:`copies` of ``bqm``'s shape on this solver's QPU (the shape's own embedding
        when none are found).

        Parameters
        ----------
        bqm : dimod.BinaryQuadraticModel
            A bundle of the shape.
        progress : callable, optional
            Told what the search is doing, in words.

        Returns
        -------
        tuple
            The copies and where they came from (``"store"`` or ``"computed"``).
        """
        composite = self.composite()
        return copies(
            self.cache, bqm, self.sampler(), self._target,
            lambda: composite.embedding(bqm)[0], solver=self.name, progress=progress,
            tries=self.settings.embedding_tries,
        )  # fmt: skip

    def _sample_packed(
        self, reductions: list[Reduction], embeddings: list, params: dict[str, Any], seed, states
    ) -> list[dimod.SampleSet]:
        """One QPU call for the rests of ``reductions``, the i-th on ``embeddings[i]``."""
        from dwave.embedding.chain_breaks import majority_vote
        from dwave.system import FixedEmbeddingComposite

        from shared.solvers.qpu.qpu_settings import chain_strength, reverse_anneal

        rests = [r.rest for r in reductions if r.rest is not None]
        given = params.pop("chain_strength", None)
        embedding: dict[int, list[int]] = {}
        strengths: dict[int, float] = {}
        warm: dict[int, int] = {}
        qubits: list[int] = []
        longest: list[int] = []
        start = 0
        for reduction, rest, copy, state in zip(reductions, rests, embeddings, states, strict=True):
            strength = float(given or chain_strength(rest))
            for i, v in enumerate(reduction.free):
                embedding[start + i] = copy[int(v)]
                strengths[start + i] = strength
            if state is not None:
                warm.update({start + i: int(x) for i, x in enumerate(state[0][0])})
            qubits.append(sum(len(copy[int(v)]) for v in reduction.free))
            longest.append(max(len(copy[int(v)]) for v in reduction.free))
            start += rest.num_variables
        settings = params
        if warm:
            reverse_anneal(settings, warm)
        base = self.sampler()
        with self._lock if self.simulated else contextlib.nullcontext():
            self._seed_sampler(base, seed)
            sampleset = FixedEmbeddingComposite(base, embedding).sample(
                joined(rests), chain_strength=strengths, chain_break_method=majority_vote,
                return_embedding=False, **settings,
            )  # fmt: skip
            sampleset.resolve()
        timing = self._timing(sampleset.info, sum(qubits), settings)
        weights = np.asarray(sampleset.record.num_occurrences, dtype=float)
        breaks = float(np.average(sampleset.record.chain_break_fraction, weights=weights))
        parts = split(sampleset, rests)
        for part, used, chain, rest in zip(parts, qubits, longest, rests, strict=True):
            share = used / sum(qubits)
            part.info.update(
                timing={key: value * share for key, value in timing.items()},
                qpu_access_time=timing.get("qpu_access_time", 0.0) * share,
                qubits=used,
                chains=rest.num_variables,
                longest_chain=chain,
                bundles_per_call=len(rests),
                call_qubits=sum(qubits),
                mean_chain_break_fraction=breaks,
                num_reads=int(weights.sum()),
                simulated=self.simulated,
                warm_start=bool(warm),
            )
        return parts


def _states(initial_state) -> Any:
    """A bundle's warm start (n values or None) as samples-like on 0..n-1."""
    if initial_state is None:
        return None
    state = np.asarray(initial_state, dtype=np.int8).reshape(1, -1)
    return state, list(range(state.shape[1]))
