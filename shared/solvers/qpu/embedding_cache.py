"""Minor embeddings of bundle graphs onto a QPU graph, found once and reused.

Finding an embedding is the slow part of using a QPU: minorminer needed 58 s for one
full-resolution Tsukuba row (domain-wall, Pegasus P16) and found none in 300 s for the one-hot
row. All bundles of a level have the same graph (same width, height and labels; only the biases
differ), so the cache key is the *structure*: a hash of the sorted edge list and the variable
count, plus a fingerprint of the target graph. Lookups go to an in-process dict first, then to a
store that several processes share:

* :class:`DirectoryStore` (default): one JSON file per key under ``Settings.data_dir/embeddings``;
* ``workers.embedding_store.RedisEmbeddingStore`` in the service (``shared`` never imports redis).

A store is anything with ``get(key) -> str | None`` and ``set(key, value: str) -> None``.

Next to each embedding the cache keeps its *size* (qubits, chains, longest chain) under a key made
of the solver's name and the structure digest, so that QPU time can be estimated from the real
embedding before any sampler (or network connection) exists, e.g. in the API at submit time.
The keys are :mod:`shared.solvers.qpu.structure_keys`' and the search
:mod:`shared.solvers.qpu.embedding_search`'; this module keeps what the search found.
"""

from __future__ import annotations

import json
import logging
import os
import tempfile
import threading
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Protocol

import dimod

from shared.activity import report
from shared.config import Settings, get_settings
from shared.solvers.errors import SolverError
from shared.solvers.qpu.embedding_search import Embedding, find_embedding, is_valid_on
from shared.solvers.qpu.structure_keys import (  # noqa: F401 (re-exported: the cache's keys)
    graph_fingerprint,
    size_key,
    structure_digest,
    structure_edges,
    structure_key,
)

log = logging.getLogger(__name__)

#: Seconds minorminer may search when a caller gives no timeout (the setting's default).
DEFAULT_TIMEOUT: float = Settings.model_fields["embedding_timeout"].default


@dataclass(frozen=True)
class EmbeddingSize:
    """What the QPU time model needs to know of an embedding: qubits used and chains."""

    qubits: int
    chains: int
    longest_chain: int

    @classmethod
    def of(cls, embedding: Embedding) -> EmbeddingSize:
        """The size of ``embedding``: total qubits, number of chains and the longest chain.

        Parameters
        ----------
        embedding : dict of int to list of int
            Variable -> its chain of physical qubits.

        Returns
        -------
        EmbeddingSize
            Qubits summed over the chains; ``longest_chain`` 0 for an empty embedding.
        """
        lengths = [len(chain) for chain in embedding.values()]
        return cls(qubits=sum(lengths), chains=len(lengths), longest_chain=max(lengths, default=0))


class EmbeddingStore(Protocol):
    """Shared key-value storage for embeddings serialised as JSON text."""

    def get(self, key: str) -> str | None:
        """The value stored under ``key``.

        Parameters
        ----------
        key : str
            A cache key (structure key, ``size-...``, ``width-...`` or ``nofit-...``).

        Returns
        -------
        str or None
            The stored JSON text, None when nothing is stored under the key.
        """
        ...

    def set(self, key: str, value: str) -> None:
        """Store ``value`` under ``key``, replacing any earlier value.

        Parameters
        ----------
        key : str
            The cache key to write.
        value : str
            JSON text (an embedding, a size, a width or a failure marker).
        """
        ...


class DirectoryStore:
    """One ``<key>.json`` file per embedding; writes are atomic (temp file + rename), so
    concurrent writers of the same key are harmless (both embeddings are valid)."""

    def __init__(self, directory: str | Path) -> None:
        self.directory = Path(directory)

    def get(self, key: str) -> str | None:
        """The text of ``<directory>/<key>.json``.

        Parameters
        ----------
        key : str
            File stem under the store's directory (a structure, ``size-``, ``width-`` or
            ``nofit-`` key).

        Returns
        -------
        str or None
            The file's contents (read as text); None when the file does not exist, i.e.
            no process has stored ``key`` yet.
        """
        path = self.directory / f"{key}.json"
        try:
            return path.read_text()
        except FileNotFoundError:
            return None

    def set(self, key: str, value: str) -> None:
        """Write ``<directory>/<key>.json`` atomically (mode 0644: other users' workers read it).

        Parameters
        ----------
        key : str
            File stem; the directory is created when missing.
        value : str
            Text written to the file.
        """
        self.directory.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(dir=self.directory, suffix=".tmp")
        with os.fdopen(handle, "w") as stream:
            stream.write(value)
        os.chmod(temporary, 0o644)  # mkstemp creates 0600; other workers may run as others
        os.replace(temporary, self.directory / f"{key}.json")


def _encode(embedding: Embedding) -> str:
    return json.dumps({str(v): [int(q) for q in chain] for v, chain in embedding.items()})


def _decode(text: str) -> Embedding:
    return {int(v): list(chain) for v, chain in json.loads(text).items()}


class EmbeddingCache:
    """In-process dict in front of a shared store; ``lookup`` reports where a hit came from."""

    def __init__(self, store: EmbeddingStore | None = None) -> None:
        self._store = store
        self._memory: dict[str, Embedding] = {}
        #: Structures that found no embedding in this process: fail fast instead of searching
        #: again for every bundle of the level (not persisted: a longer timeout may succeed).
        self._failures: dict[str, str] = {}
        self._sizes: dict[str, EmbeddingSize] = {}
        #: Disjoint copies of a shape per key (``shared.solvers.qpu.packing.copies``).
        self.copies: dict[str, list[Embedding]] = {}
        self._lock = threading.Lock()
        #: Embeddings this process computed (not found in memory or the store), for reports.
        self.computed = 0

    @property
    def store(self) -> EmbeddingStore:
        if self._store is None:
            self._store = DirectoryStore(get_settings().data_dir / "embeddings")
        return self._store

    def lookup(
        self,
        bqm: dimod.BinaryQuadraticModel,
        target_edges: list[tuple[int, int]],
        target: str,
        timeout: float | None = None,
        seed: int = 0,
        solver: str | None = None,
        remember_failure: bool = True,
    ) -> tuple[Embedding, str, str]:
        """(embedding, source, key); source is ``"memory"``, ``"store"`` or ``"computed"``.

        With ``solver`` (the adapter's name) the embedding's size is also recorded for
        :meth:`known_size` the first time this process meets the structure.

        Parameters
        ----------
        bqm : dimod.BinaryQuadraticModel
            The bundle's QUBO on the variables 0..n-1; only its graph matters.
        target_edges : list of (int, int)
            The QPU graph's working couplers.
        target : str
            Name of the target graph in the key (topology and edge fingerprint).
        timeout : float, optional
            Seconds minorminer may search on a miss; default ``Settings.embedding_timeout``'s
            default (an adapter passes its own setting: ``EmbeddingCacheComposite.timeout``).
        seed : int, default 0
            minorminer's random seed.
        solver : str, optional
            Solver name under which the embedding's size is recorded; None records nothing.
        remember_failure : bool, default True
            Whether a failed search makes later lookups of the key in this process fail at once.

        Returns
        -------
        embedding : dict of int to list of int
            Variable -> chain of qubits.
        source : str
            ``"memory"``, ``"store"`` or ``"computed"``.
        key : str
            The structure's cache key.

        Raises
        ------
        SolverError
            When no embedding is found (or an earlier search of the key failed in this process).
        """
        digest = structure_digest(bqm)
        key = f"{target}-{digest}"
        with self._lock:
            if key in self._memory:
                return self._memory[key], "memory", key
            if key in self._failures:
                raise SolverError(self._failures[key])
        stored = self.store.get(key)
        if stored is not None:
            embedding = _decode(stored)
            if is_valid_on(embedding, bqm, target_edges):
                with self._lock:
                    self._memory[key] = embedding
                self._record_size(solver, digest, embedding)
                return embedding, "store", key
            log.warning("embedding %s in the store does not fit the target; recomputing", key)
        timeout = DEFAULT_TIMEOUT if timeout is None else timeout
        try:
            embedding = find_embedding(bqm, target_edges, timeout, seed)
        except SolverError as error:
            if remember_failure:
                with self._lock:
                    self._failures[key] = str(error)
            raise
        self.store.set(key, _encode(embedding))
        with self._lock:
            self._memory[key] = embedding
            self.computed += 1
        self._record_size(solver, digest, embedding)
        return embedding, "computed", key

    def remember(
        self,
        bqm: dimod.BinaryQuadraticModel,
        target: str,
        embedding: Embedding,
        solver: str | None = None,
        computed: bool = False,
    ) -> None:
        """Make ``embedding`` the one :meth:`lookup` returns for ``bqm``'s structure on
        ``target`` (found elsewhere, e.g. the first of a shape's translated copies), stored and
        its size recorded.

        Parameters
        ----------
        bqm : dimod.BinaryQuadraticModel
            A bundle of the shape.
        target : str
            Name of the target graph in the key.
        embedding : dict of int to list of int
            A valid embedding of the structure on the target.
        solver : str, optional
            Solver name under which its size is recorded.
        computed : bool
            Whether this process searched for it (counted in :attr:`computed`).
        """
        digest = structure_digest(bqm)
        key = f"{target}-{digest}"
        with self._lock:
            if self._memory.get(key) == embedding:
                return
            self._memory[key] = embedding
            self._failures.pop(key, None)
            self.computed += int(computed)
        if self.store.get(key) != _encode(embedding):
            self.store.set(key, _encode(embedding))
        self._record_size(solver, digest, embedding)

    def _record_size(self, solver: str | None, digest: str, embedding: Embedding) -> None:
        if solver is None:
            return
        size = EmbeddingSize.of(embedding)
        key = size_key(solver, digest)
        with self._lock:
            if self._sizes.get(key) == size:
                return
            self._sizes[key] = size
        self.store.set(key, json.dumps(asdict(size)))

    def known_size(self, solver: str, digest: str) -> EmbeddingSize | None:
        """The size of ``solver``'s embedding of a structure, if one was ever found (by any
        process sharing the store); None before the first bundle of that structure.

        Parameters
        ----------
        solver : str
            Registry name of the embedding solver.
        digest : str
            :func:`structure_digest` of the bundle shape.

        Returns
        -------
        EmbeddingSize or None
            The recorded size; None when unknown or the stored record is malformed.
        """
        key = size_key(solver, digest)
        with self._lock:
            if key in self._sizes:
                return self._sizes[key]
        stored = self.store.get(key)
        if stored is None:
            return None
        try:
            size = EmbeddingSize(**json.loads(stored))
        except (TypeError, ValueError):
            log.warning("ignoring a malformed embedding size under %s", key)
            return None
        with self._lock:
            self._sizes[key] = size
        return size

    def record_width(self, key: str, width: int | None) -> None:
        """Keep what ``--bundle-width auto`` chose for a level shape (None: whole rows), so that
        estimates made before any job runs can count the segments.

        Parameters
        ----------
        key : str
            The level shape's key (``bundle_shapes.auto_width_key``).
        width : int or None
            The chosen segment width in pixels; None for whole rows.
        """
        self.store.set(f"width-{key}", json.dumps(width))

    def known_width(self, key: str) -> tuple[bool, int | None]:
        """(known, width) of :meth:`record_width`.

        Parameters
        ----------
        key : str
            The level shape's key, as given to :meth:`record_width`.

        Returns
        -------
        known : bool
            Whether a width was recorded (and parses).
        width : int or None
            The recorded width in pixels (None: whole rows, or unknown).
        """
        stored = self.store.get(f"width-{key}")
        if stored is None:
            return False, None
        try:
            return True, json.loads(stored)
        except ValueError:
            return False, None

    def widest(
        self,
        bqm_of_width: Callable[[int], dimod.BinaryQuadraticModel],
        row_width: int,
        narrowest: int,
        target_edges: list[tuple[int, int]],
        target: str,
        timeout: float,
        solver: str | None = None,
    ) -> int | None:
        """The widest bundle (None: the whole row of ``row_width``) whose structure
        ``bqm_of_width(w)`` embeds within ``timeout`` seconds, at least ``narrowest`` wide.

        Halving from the whole row until a width embeds, then bisection to within an eighth.
        Each width's verdict is kept in the store (an embedding found is the embedding every
        bundle of that shape then uses; a failure is kept per timeout), so the search runs once
        per (width, labels, encoding, target) across all processes sharing the store.

        Parameters
        ----------
        bqm_of_width : callable
            Width in pixels -> a bundle BQM of that width (its structure is what gets embedded).
        row_width : int
            Width of a whole row, pixels.
        narrowest : int
            Smallest acceptable segment width, pixels.
        target_edges : list of (int, int)
            The QPU graph's working couplers.
        target : str
            Name of the target graph in the cache keys.
        timeout : float
            Seconds each embedding search may take.
        solver : str, optional
            Solver name under which embedding sizes are recorded.

        Returns
        -------
        int or None
            The widest width that embeds, in pixels; None when the whole row does.

        Raises
        ------
        SolverError
            When not even a segment of ``narrowest`` pixels embeds.
        """

        def fits(width: int) -> bool:
            bqm = bqm_of_width(width)
            verdict = f"nofit-{structure_key(bqm, target)}-{timeout:g}"
            if self.store.get(verdict) is not None:
                return False
            report(f"finding the widest row segment that embeds: {width} of {row_width} px")
            try:
                self.lookup(
                    bqm, target_edges, target, timeout, solver=solver, remember_failure=False
                )
            except SolverError:
                self.store.set(verdict, "1")
                return False
            return True

        if fits(row_width):
            return None
        failed, width = row_width, row_width // 2
        while not fits(width):
            failed, width = width, width // 2
            if width < narrowest:
                raise SolverError(
                    f"no row segment of {narrowest} pixels or more embeds on the QPU graph within "
                    f"{timeout:g} s (QHSM_EMBEDDING_SEARCH_TIMEOUT): raise that timeout, lower "
                    "--bundle-margin, or use --encoding domain-wall"
                )
        fitted = width
        while failed - fitted > max(4, fitted // 8):
            middle = (fitted + failed) // 2
            if fits(middle):
                fitted = middle
            else:
                failed = middle
        return fitted


_default_cache: EmbeddingCache | None = None


def default_cache() -> EmbeddingCache:
    """The process-wide cache (directory store unless :func:`set_default_store` was called)."""
    global _default_cache
    if _default_cache is None:
        _default_cache = EmbeddingCache()
    return _default_cache


def set_default_store(store: EmbeddingStore) -> None:
    """Install a shared store (the service installs Redis at worker start-up).

    Parameters
    ----------
    store : EmbeddingStore
        Replaces the process-wide cache by a new, empty one in front of this store.
    """
    global _default_cache
    _default_cache = EmbeddingCache(store)
