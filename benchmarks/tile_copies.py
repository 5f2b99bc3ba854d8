"""Disjoint copies of the residual design's 4x4 tile shape on Advantage-like chips, and the time
to find them: ``translate`` (shared.solvers.qpu.tile_embedding: one embedding into the smallest
sublattice within QHSM_EMBEDDING_TRIES tries, translated) against ``greedy`` (what
shared.solvers.qpu.packing did before: one embedding on the whole chip, then further ones on the
qubits left, QHSM_EMBEDDING_SEARCH_TIMEOUT seconds each, up to 8).

    PYTHONPATH=$PWD python benchmarks/tile_copies.py --method translate --chips P16 Z12 Z15 \
        --candidates 4 6
"""

from __future__ import annotations

import argparse
import time

import dwave.graphs as graphs

from shared.config import get_settings
from shared.solvers.qpu.bundle_shapes import shape_bqm
from shared.solvers.qpu.embedding_search import SolverError, find_embedding
from shared.solvers.qpu.tile_embedding import translated_copies

CHIPS = {
    "P16": ("pegasus", [16], lambda: graphs.pegasus_graph(16)),
    "Z12": ("zephyr", [12, 4], lambda: graphs.zephyr_graph(12, 4)),
    "Z15": ("zephyr", [15, 4], lambda: graphs.zephyr_graph(15, 4)),
}


def greedy(bqm, edges: list, limit: int = 8) -> int:
    """The former search: first on the whole chip, then greedily on what is left."""
    settings = get_settings()
    found = [find_embedding(bqm, edges, settings.embedding_timeout)]
    used = {q for chain in found[0].values() for q in chain}
    while len(found) < limit:
        free = [(u, v) for u, v in edges if u not in used and v not in used]
        try:
            more = find_embedding(bqm, free, settings.embedding_search_timeout, seed=len(found))
        except SolverError:
            break
        found.append(more)
        used.update(q for chain in more.values() for q in chain)
    return len(found)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--method", choices=("translate", "greedy"), default="translate")
    parser.add_argument("--chips", nargs="+", default=list(CHIPS), choices=list(CHIPS))
    parser.add_argument("--candidates", nargs="+", type=int, default=[4, 6])
    parser.add_argument("--encoding", default="domain-wall")
    args = parser.parse_args()
    print("| chip | encoding | labels | variables | method | copies | seconds |")
    print("|---|---|---|---|---|---|---|")
    for chip in args.chips:
        family, shape, build = CHIPS[chip]
        graph = build()
        edges = list(graph.edges)
        for candidates in args.candidates:
            bqm = shape_bqm(args.encoding, 4, 4, candidates)
            started = time.perf_counter()
            if args.method == "translate":
                properties = {"topology": {"type": family, "shape": shape}}
                tries = get_settings().embedding_tries
                found = translated_copies(bqm, properties, list(graph), edges, tries, limit=64)
                count = len(found)
            else:
                count = greedy(bqm, edges)
            seconds = time.perf_counter() - started
            print(f"| {chip} | {args.encoding} | {candidates} | {bqm.num_variables} | "
                  f"{args.method} | {count} | {seconds:.1f} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
