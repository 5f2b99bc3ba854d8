"""One embedding per bundle shape: found before the fan-out, reused by every worker through the
shared (real Redis) store; ``--bundle-width auto``'s search kept in the same store (``redis_store``:
the session's Redis, conftest.py)."""

from __future__ import annotations

from dwave import graphs as dwave_graphs

from shared.assembly import assemble
from shared.config import LevelConfig, MatchConfig
from shared.inference import level_bundles, solve_bundles
from shared.pipeline import match_views, plan_run, prepare_level
from shared.solvers.meters.qpu_time import shape_bqm
from shared.solvers.qpu import embedding_cache
from shared.solvers.qpu.embedding_cache import EmbeddingCache
from shared.synthetic import make_scene


def test_auto_width_search_runs_once_per_shape_and_target(redis_store):
    _, store = redis_store
    target = list(dwave_graphs.chimera_graph(3).edges)  # 72 qubits: a 40-px row does not fit

    def bqm_of_width(width: int):
        return shape_bqm("domain-wall", 1, width, 4)

    first = EmbeddingCache(store)
    width = first.widest(bqm_of_width, 40, 5, target, "chimera3", timeout=2)
    assert width is not None and 5 <= width < 40
    assert first.computed >= 1
    # another process: same answer from the stored verdicts and embeddings, nothing computed
    second = EmbeddingCache(store)
    assert second.widest(bqm_of_width, 40, 5, target, "chimera3", timeout=2) == width
    assert second.computed == 0
    _, source, _ = second.lookup(bqm_of_width(width), target, "chimera3", timeout=2)
    assert source in {"memory", "store"}


def test_a_level_embeds_its_shape_once_across_workers(redis_store):
    client, store = redis_store
    scene = make_scene(16, 60, max_disparity=6, seed=2)
    config = MatchConfig(
        preset="paper",
        levels=[LevelConfig(downsample=1, candidates=3)],
        max_disparity=6,
        solver="qpu-sim",
        encoding="domain-wall",
        bundle_width=24,
        bundle_margin=6,
        solver_params={"num_reads": 5, "preprocess": "none"},
    )
    left, right = match_views(scene.left, scene.right, config)
    _, plans = plan_run(left, right, config)
    inputs = prepare_level(left, right, config, plans[0])

    embedding_cache.set_default_store(store)  # the control process
    bundles = level_bundles(inputs, config)
    assert {b.shape for b in bundles} == {(1, 24)}
    assert inputs.prepared["embeddings_computed"] == 1

    results = []
    for half in (bundles[::2], bundles[1::2]):  # two workers: fresh caches, the same Redis
        embedding_cache.set_default_store(store)
        results += solve_bundles(inputs, config, half)
        assert embedding_cache.default_cache().computed == 0
    solution = assemble(inputs, results, config)
    assert solution.info["embeddings_computed"] == 1
    assert solution.info["embeddings_reused"] == len(bundles)
    assert solution.info["bundle_shapes"] == ["1x24"]
    assert solution.info["qubits"] >= 24 * 2 and solution.info["longest_chain"] >= 1
    kinds = ("size-", "nofit-", "copies-", "sublattice-", "#generation")  # not embeddings
    stored = client.keys(store.prefix + "*")
    embeddings = [key for key in stored if not any(k in key for k in kinds)]
    assert len(embeddings) == 1
    # and its disjoint copies, found while planning, for packing bundles into QPU calls
    assert len([key for key in stored if "copies-count-" in key]) == 1
