"""The job store against a real Redis: state changes, idempotent progress, level inputs."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import settings as settings_
from hypothesis import strategies as st

from shared.config import MatchConfig
from shared.pipeline import plan_run, prepare_level
from workers import orchestration
from workers.level_store import LevelInputsMissingError
from workers.records import (
    ChunkReport,
    JobRecord,
    JobState,
    LevelRecord,
    TransitionError,
    new_job_id,
    now,
)
from workers.store import JobStore, UploadsMissingError


@pytest.fixture
def store(settings) -> JobStore:
    return JobStore.from_settings(settings)


def new_job(store: JobStore, state: JobState = JobState.QUEUED) -> JobRecord:
    record = JobRecord(
        id=new_job_id(), state=state, config=MatchConfig(), width=8, height=4, created_at=now()
    )
    image = np.zeros((4, 8), np.float32)
    store.create(record, {"left": image, "right": image})
    return record


def test_a_finished_job_cannot_change_state_again(store):
    record = new_job(store)
    assert store.transition(record.id, JobState.CANCELLED, {JobState.QUEUED, JobState.RUNNING})
    assert store.transition(record.id, JobState.SUCCEEDED, {JobState.RUNNING}) is None
    assert not store.fail(record.id, "too late")
    final = store.get(record.id)
    assert final.state is JobState.CANCELLED and final.finished_at is not None
    assert 0 < store.redis.ttl(store.key("job", record.id)) <= store.ttl
    assert not store.redis.exists(store.key("job", record.id, "upload"))  # gone at the end


def test_a_write_outside_the_transition_table_is_refused(store):
    record = new_job(store)
    with pytest.raises(TransitionError, match="queued -> succeeded"):
        store.apply(record.id, lambda r: r.model_copy(update={"state": JobState.SUCCEEDED}))
    assert store.get(record.id).state is JobState.QUEUED


def test_a_chunk_reported_twice_counts_once(store):
    record = new_job(store, JobState.RUNNING)
    record = store.update(
        record.id, lambda r: r.model_copy(update={"level": 1, "bundles_total": 4})
    )
    chunk = ChunkReport(level=0, bundles=2, wall_time=0.5, timing={"qpu_access_time": 0.01})
    store.record_chunk(record.id, 0, chunk)
    store.record_chunk(record.id, 0, chunk)  # the same task solved again after a worker died
    store.record_chunk(record.id, 2, chunk)
    assert store.progress(record).bundles_done == 4
    assert store.usage(store.chunks(record.id)) == pytest.approx(
        {"solver_seconds": 1.0, "qpu_access_time": 0.02}
    )


def test_level_inputs_round_trip_and_expire_with_the_level(store, pair_arrays):
    record = new_job(store, JobState.RUNNING)
    left, right = pair_arrays
    config = MatchConfig(max_disparity=8)
    _, plans = plan_run(left, right, config)
    coarse = prepare_level(left, right, config, plans[0])
    fine = prepare_level(left, right, config, plans[1], np.full(coarse.shape, 2.0, np.float32))
    store.save_level(record.id, fine, started=123.0)
    loaded, started = store.load_level(record.id, 1)
    assert started == 123.0 and loaded.plan == fine.plan and loaded.views == fine.views == 2
    for name in ("left", "right", "candidates", "initial_labels", "first", "coarse_bins"):
        assert np.array_equal(getattr(loaded, name), getattr(fine, name))
    # the coarse-to-fine prior travels with the level: a worker's costs are the pipeline's
    assert fine.coarse_bins is not None and fine.plan.mrf.coarse_prior > 0
    assert np.array_equal(loaded.costs(config).unary, fine.costs(config).unary)
    # a bin level's windows are stored as each pixel's first candidate, not (rows, w, K)
    stored = store.redis.hkeys(store.key("job", record.id, "level", 1))
    assert b"first" in stored and b"candidates" not in stored
    store.drop_level(record.id, 1)
    with pytest.raises(LevelInputsMissingError):
        store.load_level(record.id, 1)


def test_a_coarse_grids_pooled_costs_travel_with_its_level(store, pair_arrays):
    record = new_job(store, JobState.RUNNING)
    left, right = pair_arrays
    config = MatchConfig(max_disparity=40, coarse_grid=2)  # widths 8, 4, 2, 1: the first at 1/2
    _, plans = plan_run(left, right, config)
    coarse = prepare_level(left, right, config, plans[0])
    assert coarse.pooled is not None and coarse.shape == (32, 24)
    store.save_level(record.id, coarse, started=1.0)
    loaded, _ = store.load_level(record.id, 0)
    assert loaded.pooled is not None and np.array_equal(loaded.pooled, coarse.pooled)
    assert np.array_equal(loaded.costs(config).unary, coarse.costs(config).unary)


def test_the_levels_of_a_bin_pyramid_share_one_copy_of_their_images(store, settings, pair_arrays):
    """A bin pyramid's levels all read the full-resolution views: they are written to Redis
    once per job, and each process reads them once (read-only, shared by the levels)."""
    record = new_job(store, JobState.RUNNING)
    left, right = pair_arrays
    config = MatchConfig(max_disparity=8)  # accurate preset: bin pyramid, 2 levels
    _, plans = plan_run(left, right, config)
    coarse = prepare_level(left, right, config, plans[0])
    fine = prepare_level(left, right, config, plans[1], np.full(coarse.shape, 2.0, np.float32))
    store.save_level(record.id, coarse, started=1.0)
    images = store.key("job", record.id, "level", "views", plans[0].downsample)
    written = store.redis.hgetall(images)
    store.redis.hset(images, "marker", b"kept")  # not written again by the next level
    store.save_level(record.id, fine, started=2.0)
    assert store.redis.hget(images, "marker") == b"kept"
    other = JobStore.from_settings(settings)  # another worker process
    first, _ = other.load_level(record.id, 0)
    second, _ = other.load_level(record.id, 1)
    assert second.left is first.left and not first.left.flags.writeable
    for name in ("left", "right"):
        assert np.array_equal(getattr(second, name), getattr(fine, name))
    assert len(written) >= 4  # headers and pieces of left and right
    store.fail(record.id, "done")  # a finished job's level keys (images too) are removed
    assert not store.redis.exists(images)


def test_a_repeated_fan_in_is_ignored(store):
    record = new_job(store, JobState.RUNNING)
    sizes = {"index": 0, "height": 4, "width": 8, "candidates": 3, "bundles": 1}
    level = LevelRecord(**sizes, energy=1.0, seconds=1.0, solver_seconds=1.0)
    assert store.apply(record.id, JobRecord.with_level, 0, level).changed
    # level 0's inputs are gone; a redelivered callback must neither fail nor redo the job
    orchestration.level_done(None, store, [{"bundles": []}], record.id, 0)
    assert store.get(record.id).state is JobState.RUNNING


def test_malformed_job_ids_are_refused(store):
    record = JobRecord(id="../../etc", config=MatchConfig(), width=8, height=4, created_at=now())
    with pytest.raises(ValueError, match="malformed job id"):
        store.create(record, {})
    assert store.get("../../etc") is None


def test_uploads_live_in_redis_bit_exact_bounded_and_expiring(store, settings, tmp_path):
    """Workers need Redis and nothing else (issue 22): the uploads of a job are in Redis,
    in pieces of at most MAX_VALUE_BYTES, read back bit-exact, expiring; nothing
    is written to the data directory; at the end the views go and the ground truth stays
    with the result."""
    from workers.arrays import MAX_VALUE_BYTES

    rng = np.random.default_rng(5)
    left = rng.random((700, 900, 3), dtype=np.float32)  # no integer form: 7.6 MB, two pieces
    right = np.roll(left, 3, axis=1)
    truth = rng.integers(0, 256, (700, 900)).astype(np.float32)
    before = sorted(settings.data_dir.rglob("*")) if settings.data_dir.exists() else []
    record = JobRecord(
        id=new_job_id(), config=MatchConfig(), width=900, height=700, created_at=now()
    )
    store.create(record, {"left": left, "right": right, "ground_truth": truth})
    for name, array in {"left": left, "right": right, "ground_truth": truth}.items():
        loaded = store.load_upload(record.id, name)
        assert loaded.dtype == array.dtype and loaded.tobytes() == array.tobytes(), name
    upload = store.key("job", record.id, "upload")
    sizes = [len(value) for value in store.redis.hvals(upload)]
    assert len(sizes) > 4 and max(sizes) <= MAX_VALUE_BYTES
    assert 0 < store.redis.ttl(upload) <= store.view_ttl
    after = sorted(settings.data_dir.rglob("*")) if settings.data_dir.exists() else []
    assert after == before  # nothing on disk
    store.transition(record.id, JobState.CANCELLED, {JobState.QUEUED})
    assert not store.redis.exists(upload)
    with pytest.raises(UploadsMissingError, match="submit it again"):
        store.load_upload(record.id, "left")
    assert np.array_equal(store.load_ground_truth(record.id), truth)  # the error map's
    assert 0 < store.redis.ttl(store.key("job", record.id, "view", "ground_truth")) <= store.ttl


def test_a_large_levels_inputs_are_written_in_bounded_pieces(store):
    """A 1000x600 colour level used to be one 33 MB write (one record of Redis's append-only
    file); now no value is above MAX_VALUE_BYTES, and the level reads back exactly."""
    from shared import pyramid
    from shared.level_inputs import LevelInputs
    from workers.arrays import MAX_VALUE_BYTES

    record = new_job(store, JobState.RUNNING)
    rng = np.random.default_rng(0)
    left = rng.random((1200, 1000, 3), dtype=np.float32)  # both views stacked
    candidates = rng.integers(0, 60, (1200, 1000, 6)).astype(np.int64)
    plan = pyramid.plan(MatchConfig(), 60)[-1]
    inputs = LevelInputs(
        plan=plan, views=2, left=left, right=left[::-1], candidates=candidates,
        initial_labels=candidates[..., 0].astype(np.int32),
    )  # fmt: skip
    store.save_level(record.id, inputs, started=1.0)
    level = store.key("job", record.id, "level", inputs.plan.index)
    images = store.key("job", record.id, "level", "views", plan.downsample)
    for key in (level, images):
        sizes = [store.redis.hstrlen(key, field) for field in store.redis.hkeys(key)]
        assert max(sizes) <= MAX_VALUE_BYTES
    loaded, _ = store.load_level(record.id, inputs.plan.index)
    for name in ("left", "right", "candidates", "initial_labels"):
        ours, theirs = getattr(loaded, name), getattr(inputs, name)
        assert ours.dtype == theirs.dtype and np.array_equal(ours, theirs), name
    store.fail(record.id, "x" * 100_000)
    assert len(store.get(record.id).error) < 2100  # a record's messages are bounded too


@settings_(max_examples=200, deadline=None)
@given(
    values=st.lists(
        st.one_of(
            st.floats(width=32, allow_nan=True, allow_infinity=True),
            st.integers(0, 255).map(lambda k: np.float32(k) / np.float32(255.0)),
            st.integers(0, 65535).map(lambda k: np.float32(k) / np.float32(65535.0)),
            st.integers(0, 65535).map(float),
        ),
        min_size=1,
        max_size=64,
    ),
    kind=st.sampled_from(["float32", "float64", "uint16", "int32"]),
)
def test_stored_arrays_come_back_bit_for_bit(values, kind):
    """Whatever the array (image-like or not, NaN, -0.0, inf, any dtype), what array_fields
    stores reads back identical, in integer form or not."""
    from workers.arrays import array_fields, array_from

    if kind in ("uint16", "int32"):
        values = [v for v in values if np.isfinite(v) and 0 <= v <= 65535] or [0.0]
    array = np.array(values, dtype=np.float32).astype(kind).reshape(-1, 1)
    for images in (False, True):
        fields = {
            key.encode(): value for key, value in array_fields("a", array, images=images).items()
        }
        back = array_from(fields, "a")
        assert back.dtype == array.dtype and back.shape == array.shape
        assert back.tobytes() == array.tobytes()
