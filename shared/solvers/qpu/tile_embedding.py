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

The sublattice's embedding (the search that costs the tries) depends on the shape and the
defect-free sublattice only, so it is kept in the embedding store under :func:`tile_key` and
every chip of the family reuses it, whatever its broken qubits: :func:`warm` computes them ahead
of time for the known chips (``qhsm embeddings warm``), and a worker then only translates.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from typing import Any

import dimod

from shared.solvers.qpu.embedding_search import Embedding
from shared.solvers.qpu.structure_keys import structure_digest, structure_edges

log = logging.getLogger(__name__)

#: minorminer's ``random_seed`` for every tile search: the embedding depends on the shape and the
#: chip only, whichever worker finds it.
SEED = 0

#: Sublattice sizes tried above minorminer's lower bound before giving up (each failure costs
#: ``tries`` minorminer tries; a larger tile gives fewer copies than one embedding on the chip).
EXTRA_SIZES = 3

#: The chips whose tile embeddings :func:`warm` computes ahead of time: Advantage (Pegasus P16)
#: and Advantage2 (Zephyr Z12, Z15), as (family, m, t).
KNOWN_CHIPS = {"P16": ("pegasus", 16, 12), "Z12": ("zephyr", 12, 4), "Z15": ("zephyr", 15, 4)}


def tile_key(family: str, size: int, t: int, digest: str, tries: int) -> str:
    """Store key of a shape's embedding into the defect-free ``family`` sublattice ``m = size``
    (the same on every chip of the family: no graph fingerprint in it)."""
    return f"sublattice-{family}{size}t{t}-{digest}-seed{SEED}-tries{tries}"


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
    store: Any = None,
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
    store : EmbeddingStore, optional
        Where the sublattice embeddings are kept (:func:`tile_key`; a failure too: the search
        is deterministic).

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
        key = tile_key(family, size, t, structure_digest(bqm), tries)
        kept = None if store is None else store.get(key)
        if kept is not None:
            first = {int(v): chain for v, chain in json.loads(kept).items()}
        else:
            first = minorminer.find_embedding(source, tile, random_seed=SEED, tries=tries)
            if store is not None:
                store.set(key, json.dumps(first))
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


def warm(
    store: Any,
    shapes: list[dimod.BinaryQuadraticModel],
    tries: int,
    chips: dict[str, tuple[str, int, int]] = KNOWN_CHIPS,
    progress: Callable[[str], None] | None = None,
    limit: int = 64,
) -> list[tuple[str, int, int]]:
    """Compute each shape's sublattice embedding on each chip's family into ``store`` ahead of
    time (``qhsm embeddings warm``): a worker meeting the shape on any chip of the family then
    only translates it (:func:`translated_copies` finds it under :func:`tile_key`).

    Parameters
    ----------
    store : EmbeddingStore
        The embedding store workers read (``get`` / ``set``).
    shapes : list of dimod.BinaryQuadraticModel
        A bundle of each shape, on the variables 0..n-1.
    tries : int
        minorminer's tries per sublattice size, as the workers use (``embedding_tries``).
    chips : dict, optional
        Name -> (family, m, t); default :data:`KNOWN_CHIPS`.
    progress : callable, optional
        Told what is being done, in words.
    limit : int, optional
        Copies counted at most.

    Returns
    -------
    list of (str, int, int)
        Per chip and shape: the chip's name, the shape's variables and the copies found on the
        defect-free chip (0: no sublattice takes it within the tries).
    """
    import dwave.graphs as graphs

    found = []
    for name, (family, m, t) in chips.items():
        chip = graphs.pegasus_graph(m) if family == "pegasus" else graphs.zephyr_graph(m, t)
        shape = [m] if family == "pegasus" else [m, t]
        properties = {"topology": {"type": family, "shape": shape}}
        for bqm in shapes:
            copies = translated_copies(
                bqm, properties, list(chip.nodes), list(chip.edges), tries=tries, limit=limit,
                progress=progress, store=store,
            )  # fmt: skip
            found.append((name, bqm.num_variables, len(copies)))
    return found
