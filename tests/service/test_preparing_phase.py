"""A level being prepared says what it is doing in the job's status (``Progress.phase``): with an
empty embedding cache, ``qpu-sim`` (Ocean's MockDWaveSampler, Advantage P16) plans its first
level and the status read *while* the tile shape's embedding search runs (a hook inside the
search, no timing) names that search; planned again with the cache filled, it says "cached"."""

from __future__ import annotations

import pytest

from shared.config import MatchConfig
from shared.disparity_range import RangeEstimate
from shared.pyramid import plan
from shared.solvers import registry
from shared.solvers.qpu import embedding_cache, tile_embedding
from shared.synthetic import make_scene
from workers import orchestration
from workers.app import make_celery
from workers.records import JobRecord, new_job_id, now
from workers.store import JobStore

pytestmark = pytest.mark.service

#: One level of 5 candidates whose host leaves tiles to send (a 64-variable 4x4 tile shape).
SCENE = {"height": 12, "width": 24, "max_disparity": 4, "seed": 2}


def started(store: JobStore) -> str:
    """A qpu-sim job started in process, its first level waiting to be planned."""
    scene = make_scene(SCENE["height"], SCENE["width"], SCENE["max_disparity"], SCENE["seed"])
    config = MatchConfig(solver="qpu-sim", max_disparity=4, seed=2)
    record = JobRecord(
        id=new_job_id(),
        config=config,
        width=SCENE["width"],
        height=SCENE["height"],
        created_at=now(),
        disparity_range=RangeEstimate(4, "given").as_dict(),
        levels_total=len(plan(config, 4)),
    )
    store.create(record, {"left": scene.left, "right": scene.right})
    orchestration.start_job(make_celery(store.settings, with_tasks=False), store, record.id)
    return record.id


def test_the_status_names_the_embedding_search_while_it_runs(settings, tmp_path, monkeypatch):
    store = JobStore.from_settings(settings)
    cache = embedding_cache.EmbeddingCache(embedding_cache.DirectoryStore(tmp_path))
    monkeypatch.setattr(embedding_cache, "_default_cache", cache)  # empty: nothing embedded yet
    monkeypatch.setattr(registry, "_INSTANCES", {})  # a qpu-sim adapter on that cache
    monkeypatch.setattr(orchestration, "send_plan", lambda *args: None)  # planned here instead
    search = tile_embedding.translated_copies
    seen: list[str | None] = []

    def watched(*args, progress, **kwargs):
        def hook(text: str) -> None:
            progress(text)
            seen.append(store.progress(store.get(job_id)).phase)  # the status, as the API shows

        return search(*args, progress=hook, **kwargs)

    monkeypatch.setattr(tile_embedding, "translated_copies", watched)
    job_id = started(store)
    before = store.progress(store.get(job_id))
    assert before.level == 1 and before.bundles_total == 0
    assert before.phase is not None and "settling" in before.phase  # the host's step came first
    orchestration.plan_level(store, job_id, 0)
    assert seen, "the embedding search ran"
    assert all(phase and phase.startswith("embedding a 64-variable tile shape into Pegasus P16")
               for phase in seen), seen  # fmt: skip
    assert "tries" in seen[0] and "sublattice" in seen[0]
    assert cache.computed > 0

    searches = len(seen)
    again = started(store)  # the same shape, its embedding now in the cache
    orchestration.plan_level(store, again, 0)
    assert store.progress(store.get(again)).phase == "embedding a 64-variable tile shape: cached"
    assert len(seen) == searches  # no search the second time
