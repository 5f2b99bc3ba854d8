"""Tile copies across a QPU by translation (shared.solvers.qpu.tile_embedding, packing.copies):
deterministic for a seed and a budget in tries, the same on a busy machine, found once per chip."""

from __future__ import annotations

import subprocess
import sys

import pytest
from dwave.embedding import is_valid_embedding

from shared.solvers.qpu import tile_embedding
from shared.solvers.qpu.bundle_shapes import shape_bqm
from shared.solvers.qpu.embedding_cache import DirectoryStore, EmbeddingCache
from shared.solvers.qpu.packing import copies
from shared.solvers.qpu.structure_keys import structure_edges

pytest.importorskip("dwave.system.testing")
from dwave.system.testing import MockDWaveSampler

BQM = shape_bqm("domain-wall", 2, 2, 3)  # a 2x2 tile of 3 labels: 8 variables


@pytest.fixture(scope="module", params=[("pegasus", [4]), ("zephyr", [3, 2])])
def qpu(request):
    kind, shape = request.param
    return MockDWaveSampler(topology_type=kind, topology_shape=shape, parameter_warnings=False)


def _copies(qpu, tries=2):
    return tile_embedding.translated_copies(
        BQM, qpu.properties, list(qpu.nodelist), list(qpu.edgelist), tries=tries, limit=64
    )


def test_copies_are_disjoint_valid_embeddings_and_deterministic(qpu):
    found = _copies(qpu)
    assert len(found) >= 2
    edges = structure_edges(BQM).tolist()
    assert all(is_valid_embedding(e, edges, qpu.edgelist) for e in found)
    qubits = [q for e in found for chain in e.values() for q in chain]
    assert len(qubits) == len(set(qubits))
    assert _copies(qpu) == found


def test_the_search_is_bounded_by_tries_not_time(qpu, monkeypatch):
    """A CPU-bound process beside it changes nothing: minorminer gets a seed and tries, and
    no time limit."""
    import minorminer

    calls = []
    real = minorminer.find_embedding

    def spy(*args, **kwargs):
        calls.append(kwargs)
        return real(*args, **kwargs)

    quiet = _copies(qpu)
    monkeypatch.setattr(minorminer, "find_embedding", spy)
    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        busy = _copies(qpu)
    finally:
        hog.kill()
        hog.wait()
    assert busy == quiet
    assert calls and all("timeout" not in c and c["tries"] == 2 for c in calls)
    assert {c["random_seed"] for c in calls} == {tile_embedding.SEED}


def test_copies_are_found_once_per_chip_then_read_from_the_store(tmp_path, monkeypatch):
    qpu = MockDWaveSampler(topology_type="pegasus", topology_shape=[4], parameter_warnings=False)
    cache = EmbeddingCache(DirectoryStore(tmp_path))
    first, source = copies(cache, BQM, qpu, "p4", lambda: pytest.fail("no fallback"), limit=8)
    assert source == "computed" and len(first) >= 2 and cache.computed == 1
    # the first copy is the shape's embedding: lookup does not search
    assert cache.lookup(BQM, qpu.edgelist, "p4")[:2] == (first[0], "memory")

    def no_search(*args, **kwargs):
        raise AssertionError("searched again")

    monkeypatch.setattr(tile_embedding, "translated_copies", no_search)
    assert copies(cache, BQM, qpu, "p4", no_search, limit=8) == (first, "memory")
    fresh = EmbeddingCache(DirectoryStore(tmp_path))  # another worker, the same store
    assert copies(fresh, BQM, qpu, "p4", no_search, limit=8) == (first, "store")
    assert fresh.lookup(BQM, qpu.edgelist, "p4")[0] == first[0] and fresh.computed == 0
    # another chip graph (another target key) searches again
    with pytest.raises(AssertionError, match="searched again"):
        copies(fresh, BQM, qpu, "p4-other", no_search, limit=8)


def test_a_graph_without_a_lattice_gets_one_embedding_per_call(tmp_path):
    qpu = MockDWaveSampler(topology_type="chimera", topology_shape=[4, 4, 4])
    assert tile_embedding.lattice(qpu.properties) is None
    cache = EmbeddingCache(DirectoryStore(tmp_path))
    fallback = cache.lookup(BQM, qpu.edgelist, "c4")[0]
    assert copies(cache, BQM, qpu, "c4", lambda: fallback) == ([fallback], "computed")


def test_warmed_sublattice_embeddings_serve_any_chip_of_the_family_without_a_search(
    tmp_path, monkeypatch
):
    """``qhsm embeddings warm`` on defect-free chips; a chip of the same family with broken
    qubits then only translates (minorminer is never called) and gets the copies it would have
    found by searching."""
    import minorminer

    store = DirectoryStore(tmp_path)
    small = {"P4": ("pegasus", 4, 12), "Z3": ("zephyr", 3, 2)}
    warmed = tile_embedding.warm(store, [BQM], tries=2, chips=small)
    assert [(chip, variables) for chip, variables, _ in warmed] == [("P4", 8), ("Z3", 8)]
    assert all(found >= 2 for _, _, found in warmed)
    for family, shape in (("pegasus", [4]), ("zephyr", [3, 2])):
        qpu = MockDWaveSampler(topology_type=family, topology_shape=shape, parameter_warnings=False)
        broken = sorted(qpu.nodelist)[::37]  # a few dead qubits: another graph fingerprint
        nodes = [q for q in qpu.nodelist if q not in set(broken)]
        edges = [(u, v) for u, v in qpu.edgelist if u in set(nodes) and v in set(nodes)]
        searched = tile_embedding.translated_copies(
            BQM, qpu.properties, nodes, edges, tries=2, limit=64
        )
        with monkeypatch.context() as patch:
            patch.setattr(minorminer, "find_embedding", _no_search)
            served = tile_embedding.translated_copies(
                BQM, qpu.properties, nodes, edges, tries=2, limit=64, store=store
            )
        assert served == searched and len(served) >= 2
        source = structure_edges(BQM).tolist()
        assert all(is_valid_embedding(e, source, edges) for e in served)


def _no_search(*args, **kwargs):
    raise AssertionError("minorminer searched although the sublattice embedding was warmed")


def test_qhsm_embeddings_warm_fills_the_directory_store(tmp_path, monkeypatch, capsys):
    from shared.cli import main

    monkeypatch.setenv("QHSM_DATA_DIR", str(tmp_path))
    monkeypatch.delenv("QHSM_REDIS_URL", raising=False)
    monkeypatch.setattr(tile_embedding, "KNOWN_CHIPS", {"P6": ("pegasus", 6, 12)})
    assert main(["embeddings", "warm", "--chips", "Z99"]) == 1
    assert "--chips: unknown Z99; choose from P6" in capsys.readouterr().err
    assert main(["embeddings", "warm", "--candidates", "2"]) == 0  # 4x4 x 1 domain-wall bit
    printed = capsys.readouterr().out
    assert "P6: 16-variable tile shape," in printed and "directory embedding store" in printed
    assert any(p.name.startswith("sublattice-pegasus") for p in (tmp_path / "embeddings").iterdir())
