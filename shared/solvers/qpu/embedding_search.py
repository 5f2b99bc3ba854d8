"""Finding a minor embedding of a bundle's graph on a QPU graph (minorminer) and checking one.

The search is the slow part of using a QPU (:mod:`shared.solvers.qpu.embedding_cache` says how slow
and keeps what it finds); its failures are :class:`~shared.solvers.base.SolverError` messages
that say what to change.
"""

from __future__ import annotations

import logging
import time

import dimod

from shared.solvers.errors import SolverError
from shared.solvers.qpu.structure_keys import structure_edges

log = logging.getLogger(__name__)

#: Variable -> chain of qubits.
Embedding = dict[int, list[int]]


def is_valid_on(embedding: Embedding, bqm, target_edges) -> bool:
    """Whether ``embedding`` is a minor embedding of ``bqm``'s graph on ``target_edges`` (a
    stored one may be stale: another graph, another variable count)."""
    from dwave.embedding import is_valid_embedding

    if set(embedding) != set(bqm.variables):
        return False
    return is_valid_embedding(embedding, structure_edges(bqm).tolist(), target_edges)


def find_embedding(
    bqm: dimod.BinaryQuadraticModel,
    target_edges: list[tuple[int, int]],
    timeout: float,
    seed: int = 0,
) -> Embedding:
    """minorminer's heuristic embedding, or a :class:`SolverError` that says what to change.

    Parameters
    ----------
    bqm : dimod.BinaryQuadraticModel
        The BQM on the variables 0..n-1 whose graph is embedded.
    target_edges : list of (int, int)
        Couplers of the QPU graph.
    timeout : float
        minorminer's time limit, seconds.
    seed : int, default 0
        minorminer's ``random_seed``.

    Returns
    -------
    dict of int to list of int
        Variable -> chain of qubits, one chain per variable.

    Raises
    ------
    SolverError
        If the BQM has more variables than the target has qubits, or no embedding is found in time.
    """
    import minorminer
    import networkx as nx

    qubits = len({qubit for edge in target_edges for qubit in edge})
    if bqm.num_variables > qubits:
        raise SolverError(
            f"this bundle is too large for the QPU: {bqm.num_variables} variables, the QPU has "
            f"{qubits} qubits; use a smaller bundle height, --encoding domain-wall, or a "
            "coarser level"
        )
    source: nx.Graph = nx.Graph()
    source.add_nodes_from(range(bqm.num_variables))
    source.add_edges_from(structure_edges(bqm).tolist())
    started = time.perf_counter()
    embedding = minorminer.find_embedding(source, target_edges, timeout=timeout, random_seed=seed)
    seconds = time.perf_counter() - started
    if len(embedding) != bqm.num_variables:
        raise SolverError(
            f"no minor embedding of this bundle ({bqm.num_variables} variables, "
            f"{source.number_of_edges()} couplings) onto the QPU graph found within "
            f"{timeout:.0f} s (QHSM_EMBEDDING_TIMEOUT): use --encoding domain-wall (fewer "
            "variables and couplings than one-hot), a smaller bundle height, or a coarser level"
        )
    longest = max((len(chain) for chain in embedding.values()), default=0)
    log.info(
        "embedded %d variables in %.1f s (%d qubits, longest chain %d)",
        bqm.num_variables,
        seconds,
        sum(len(chain) for chain in embedding.values()),
        longest,
    )
    return {int(v): list(chain) for v, chain in embedding.items()}
