"""Disjoint copies of a small bundle shape across a Pegasus or Zephyr QPU, found by translation.

The residual design sends one small tile shape per level (:mod:`shared.settle`), so a QPU call
can hold many tiles if the shape has many disjoint embeddings. minorminer embeds the shape once
into a small fully yielded sublattice of the chip's own family (``dwave.graphs`` ``pegasus_graph``
/ ``zephyr_graph`` of ``m = size``), with a fixed seed and a budget in *tries*, then
``minorminer.utils.parallel_embeddings.find_sublattice_embeddings`` translates that one
embedding to every offset of the chip's unit-cell lattice where its qubits and couplers work and
are still free. The result depends on the seed, the tries and the graph only, never on how busy
the machine is; the smallest sublattice that embeds gives the most copies (4x4 tile, 5 labels,
Pegasus P16: 20 copies on ``m = 4``, 15 on 5, 12 on 6; docs/benchmarks.md).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

import dimod

from shared.solvers.embedding_search import Embedding
from shared.solvers.structure_keys import structure_edges

log = logging.getLogger(__name__)

#: minorminer's ``random_seed`` for every tile search: the embedding depends on the shape and the
#: chip only, whichever worker finds it.
SEED = 0

#: Sublattice sizes tried above minorminer's lower bound before giving up (each failure costs
#: ``tries`` minorminer tries; a larger tile gives fewer copies than one embedding on the chip).
EXTRA_SIZES = 3


def lattice(properties: dict[str, Any]) -> tuple[str, int, int] | None:
    """(family, m, t) of a QPU's ``topology`` property when it is Pegasus or Zephyr, else None
    (another graph: no unit-cell lattice to translate on).

    Parameters
    ----------
    properties : dict
        The structured sampler's properties (``topology``: ``type`` and ``shape``).

    Returns
    -------
    tuple or None
    """
    topology = properties.get("topology", {})
    family, shape = topology.get("type"), list(topology.get("shape", []))
    if family == "pegasus" and len(shape) == 1:
        return "pegasus", int(shape[0]), 12
    if family == "zephyr" and len(shape) == 2:
        return "zephyr", int(shape[0]), int(shape[1])
    return None


def chip_name(family: str, m: int) -> str:
    """``Pegasus P16``, ``Zephyr Z12``: a chip graph as D-Wave names it."""
    return f"{family.capitalize()} {family[0].upper()}{m}"


def _graph(family: str, m: int, t: int, nodes=None, edges=None) -> Any:
    import dwave.graphs as graphs

    if family == "pegasus":
        return graphs.pegasus_graph(m, node_list=nodes, edge_list=edges)
    return graphs.zephyr_graph(m, t, node_list=nodes, edge_list=edges)


def translated_copies(
    bqm: dimod.BinaryQuadraticModel,
    properties: dict[str, Any],
    nodes: list[int],
    edges: list[tuple[int, int]],
    tries: int,
    limit: int,
    progress: Callable[[str], None] | None = None,
) -> list[Embedding]:
    """Up to ``limit`` pairwise disjoint embeddings of ``bqm``'s graph on the chip, all
    translations of one embedding into the smallest sublattice that takes it; ``[]`` when the
    chip is not Pegasus/Zephyr, or no sublattice up to :data:`EXTRA_SIZES` above the lower bound
    (and below half the chip: one copy would be all) embeds the shape within ``tries``.

    Parameters
    ----------
    bqm : dimod.BinaryQuadraticModel
        A bundle of the shape, on the variables 0..n-1.
    properties : dict
        The QPU's properties (its ``topology``).
    nodes, edges : list
        The QPU's working qubits and couplers.
    tries : int
        minorminer's ``tries`` per sublattice size (seed :data:`SEED`).
    limit : int
        Copies at most.
    progress : callable, optional
        Told what is being tried, in words.

    Returns
    -------
    list of dict
        Variable -> chain of qubits, one dict per copy; deterministic for a graph.
    """
    import minorminer
    import networkx as nx
    from minorminer.utils.parallel_embeddings import (
        find_sublattice_embeddings,
        lattice_size_lower_bound,
    )

    shape = lattice(properties)
    if shape is None or bqm.num_variables == 0:
        return []
    family, m, t = shape
    source: nx.Graph = nx.Graph()
    source.add_nodes_from(range(bqm.num_variables))
    source.add_edges_from(structure_edges(bqm).tolist())
    chip = _graph(family, m, t, nodes, edges)
    lowest = max(2, int(lattice_size_lower_bound(source, T=chip) or 2))
    sizes = range(lowest, min(lowest + EXTRA_SIZES, (m + 1) // 2) + 1)
    for number, size in enumerate(sizes, 1):
        if progress is not None:
            progress(
                f"embedding a {bqm.num_variables}-variable tile shape into {chip_name(family, m)}: "
                f"sublattice m={size} ({number}/{len(sizes)}), {tries} tries"
            )
        tile = _graph(family, size, t)
        started = time.perf_counter()
        first = minorminer.find_embedding(source, tile, random_seed=SEED, tries=tries)
        if len(first) != bqm.num_variables:
            log.info("no embedding on %s m=%d in %d tries", family, size, tries)
            continue
        found = find_sublattice_embeddings(
            source, chip, tile=tile, tile_embedding=first, use_tile_embedding=True,
            one_to_iterable=True, max_num_emb=limit, use_filter=False,
        )  # fmt: skip
        log.info(
            "%d translated copies of a %d-variable shape on %s m=%d in %.1f s",
            len(found), bqm.num_variables, family, size, time.perf_counter() - started,
        )  # fmt: skip
        if found:
            return [{int(v): [int(q) for q in chain] for v, chain in e.items()} for e in found]
    return []
