"""Keys of QUBO structures: a bundle's graph as a digest independent of its biases, a target
graph's fingerprint, and the store keys of embeddings and their sizes built from them.

All bundles of a level share one graph, so embeddings are found, stored and looked up by these
keys (:mod:`shared.solvers.qpu.embedding_cache`), and the estimates find an embedding's size by them
before any sampler exists (:mod:`shared.solvers.qpu.bundle_shapes`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Hashable, Iterable

import dimod
import numpy as np


def structure_edges(bqm: dimod.BinaryQuadraticModel) -> np.ndarray:
    """Sorted (u < v) edge array (m, 2) of a BQM whose variables are integers.

    Parameters
    ----------
    bqm : dimod.BinaryQuadraticModel
        A BQM on the variables 0..n-1.

    Returns
    -------
    numpy.ndarray
        int64 array of shape (m, 2), one row per coupling, sorted by (u, v); (0, 2) when there is
        none.
    """
    _, (rows, cols, _), *_ = bqm.to_numpy_vectors(variable_order=range(bqm.num_variables))
    edges = np.stack([np.minimum(rows, cols), np.maximum(rows, cols)], axis=1).astype(np.int64)
    if edges.size == 0:
        return edges.reshape(0, 2)
    return edges[np.lexsort((edges[:, 1], edges[:, 0]))]


def graph_fingerprint(edges: Iterable[tuple[Hashable, Hashable]]) -> str:
    """A short hash of a target graph's edge list (its working qubits and couplers).

    Parameters
    ----------
    edges : iterable of (node, node)
        The target graph's couplers as pairs of qubit numbers, in any order or orientation.

    Returns
    -------
    str
        The first 16 hex digits of the SHA-256 of the sorted, oriented edge array.
    """
    pairs = (tuple(sorted(edge)) for edge in edges)  # type: ignore[type-var]
    array = np.array(sorted(pairs), dtype=np.int64)
    return hashlib.sha256(array.tobytes()).hexdigest()[:16]


def structure_digest(bqm: dimod.BinaryQuadraticModel) -> str:
    """A hash of the BQM's graph (variable count and edges), independent of its biases.

    Parameters
    ----------
    bqm : dimod.BinaryQuadraticModel
        A bundle's QUBO on the variables 0..n-1.

    Returns
    -------
    str
        32 hex digits of the SHA-256 of the variable count and :func:`structure_edges`.
    """
    digest = hashlib.sha256()
    digest.update(np.int64(bqm.num_variables).tobytes())
    digest.update(structure_edges(bqm).tobytes())
    return digest.hexdigest()[:32]


def structure_key(bqm: dimod.BinaryQuadraticModel, target: str) -> str:
    """Cache key of the BQM's graph on ``target`` (a target name plus its fingerprint).

    Parameters
    ----------
    bqm : dimod.BinaryQuadraticModel
        The BQM whose graph is to be embedded.
    target : str
        The target graph's name in cache keys (topology and :func:`graph_fingerprint`).

    Returns
    -------
    str
        ``"<target>-<structure digest>"``.
    """
    return f"{target}-{structure_digest(bqm)}"


def size_key(solver: str, digest: str) -> str:
    """Store key of the size of ``solver``'s embedding of the structure ``digest``.

    Parameters
    ----------
    solver : str
        Registry name of the solver that embedded the structure.
    digest : str
        The structure's :func:`structure_digest`.

    Returns
    -------
    str
        ``"size-<solver>-<digest>"``.
    """
    return f"size-{solver}-{digest}"
