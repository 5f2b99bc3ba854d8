"""The compiled census + gradient volume (shared/volume_kernels.py) is OpenCV's bit for bit."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared import data_terms, fused_volume, kernels, level_inputs, pipeline, threads
from shared.config import MatchConfig
from shared.data_terms import (
    VolumeBlock,
    ad_census_volume,
    bin_minimum,
    binned_cost_volume,
    census_gradient_volume,
    gather_window,
    window_costs,
    window_minimum,
)
from shared.inference import grid_views
from shared.pipeline import run_pipeline
from shared.synthetic import make_scene
from shared.volume_kernels import census_aggregate, gradient_exponents


def both(left, right, block, out=None):
    """The volume by OpenCV and NumPy, then by the compiled kernels."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(data_terms, "FUSED_VOLUME_BYTES", 2**62)
        reference = census_gradient_volume(left, right, block)
        patch.setattr(data_terms, "FUSED_VOLUME_BYTES", 0)
        patch.setattr(data_terms, "FUSED_VIEW_BYTES", 0)
        return reference, census_gradient_volume(left, right, block, out)


@st.composite
def views_and_block(draw):
    """Random views (few grey levels too: many equal costs, zero gradients), colour or grey,
    and any block of their rows."""
    seed, levels = draw(st.integers(0, 2**16)), draw(st.sampled_from([2, 5, 256]))
    height, width = draw(st.integers(6, 40)), draw(st.integers(8, 60))
    shape = (height, width, 3) if draw(st.booleans()) else (height, width)
    rng = np.random.default_rng(seed)
    left = (rng.integers(0, levels, shape) / (levels - 1)).astype(np.float32)
    right = (rng.integers(0, levels, shape) / (levels - 1)).astype(np.float32)
    start = draw(st.integers(0, height - 1))
    stop = draw(st.integers(start + 1, height))
    return left, right, VolumeBlock(draw(st.integers(0, 20)), start, stop)


@settings(max_examples=25, deadline=None)
@given(views=views_and_block())
def test_the_compiled_volume_is_opencvs_bit_for_bit(views):
    reference, fused = both(*views)
    assert fused.dtype == np.float32
    np.testing.assert_array_equal(fused, reference)


@settings(max_examples=25, deadline=None)
@given(views=views_and_block())
def test_the_compiled_ad_census_volume_is_opencvs_bit_for_bit(views):
    """The AD-census volume (the views' check, ``--data-term ad-census``) by the census kernel
    with OpenCV's colour differences as its other term: OpenCV's volume, into a buffer too."""
    left, right, block = views
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(kernels, "ready", lambda *chosen: False)
        reference = ad_census_volume(left, right, block)
    built = []
    census_aggregate = kernels.census_aggregate

    def recorded(*arguments):
        built.append(arguments[5])  # the chunk's first disparity
        return census_aggregate(*arguments)

    buffer = np.full((block.max_disparity + 1, block.rows + 3, left.shape[1]), np.nan, np.float32)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(kernels, "ready", lambda *chosen: True)
        patch.setattr(kernels, "census_aggregate", recorded)
        fused = ad_census_volume(left, right, block, buffer[:, : block.rows])
    assert built and np.shares_memory(fused, buffer)
    np.testing.assert_array_equal(fused, reference)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**16),
    height=st.integers(5, 20),
    width=st.integers(1, 40),
    levels=st.sampled_from([2, 3, 256]),
)
def test_the_compiled_census_codes_are_numpys(seed, height, width, levels):
    """Every neighbour's bit in NumPy's order, ties (few grey levels) and rows narrower than
    the window (edge columns replicated) included."""
    rng = np.random.default_rng(seed)
    gray = (rng.integers(0, levels, (height, width)) * (255 / (levels - 1))).astype(np.float32)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(kernels, "ready", lambda *chosen: True)  # the kernel (compiled or jit)
        codes = data_terms.census(gray)
        patch.setattr(kernels, "ready", lambda *chosen: False)
        reference = data_terms.census(gray)
    assert codes.dtype == reference.dtype == np.uint32
    np.testing.assert_array_equal(codes, reference)


def test_the_compiled_volume_of_a_scene_fills_a_strided_buffer():
    """A scene, written into a block of a larger scratch buffer (as the blocks of a view are)."""
    scene = make_scene(160, 90, max_disparity=24, seed=5)
    block = VolumeBlock(24, 30, 70)
    scratch = np.full((25, 50, scene.left.shape[1]), np.nan, np.float32)
    reference, fused = both(scene.left, scene.right, block, scratch[:, : block.rows])
    assert np.shares_memory(fused, scratch)
    np.testing.assert_array_equal(fused, reference)


@settings(max_examples=15, deadline=None)
@given(
    seed=st.integers(0, 2**16),
    max_disparity=st.integers(1, 40),
    bin_width=st.integers(2, 9),
    scratch=st.booleans(),
)
def test_the_compiled_bins_are_the_bins_of_opencvs_volume(seed, max_disparity, bin_width, scratch):
    """Bins built straight by the kernels (into a full volume's scratch or a new array) are
    :func:`bin_minimum` of OpenCV's volume; the last bin may be narrower."""
    scene = make_scene(48, 20, max_disparity=max_disparity, seed=seed)
    block = VolumeBlock(max_disparity, 3, 17)
    reference, _ = both(scene.left, scene.right, block)
    shape = (max_disparity + 1, block.rows, scene.left.shape[1])
    buffer = np.empty(shape, np.float32) if scratch else None
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(data_terms, "FUSED_VOLUME_BYTES", 0)
        patch.setattr(data_terms, "FUSED_VIEW_BYTES", 0)
        binned = binned_cost_volume(
            "census-gradient", scene.left, scene.right, block, bin_width, buffer
        )
    np.testing.assert_array_equal(binned, bin_minimum(reference, bin_width))


@settings(max_examples=15, deadline=None)
@given(
    seed=st.integers(0, 2**16),
    max_disparity=st.integers(1, 40),
    bin_width=st.integers(1, 5),
    count=st.integers(1, 6),
    data=st.data(),
)
def test_the_window_costs_are_the_gathered_bins(seed, max_disparity, bin_width, count, data):
    """Each pixel's window of bins from the kernels (disparities outside every window skipped)
    is :func:`gather_window` of OpenCV's binned volume."""
    scene = make_scene(48, 20, max_disparity=max_disparity, seed=seed)
    block = VolumeBlock(max_disparity, 2, 15)
    bins = max_disparity // bin_width + 1
    count = min(count, bins)
    rng = np.random.default_rng(seed)
    top = data.draw(st.integers(0, bins - count))
    lowest = rng.integers(
        data.draw(st.integers(0, top)), top + 1, (block.rows, scene.left.shape[1])
    )
    lowest = lowest.astype(np.int32)
    reference = bin_minimum(both(scene.left, scene.right, block)[0], bin_width)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(data_terms, "FUSED_VOLUME_BYTES", 0)
        patch.setattr(data_terms, "FUSED_VIEW_BYTES", 0)
        costs = window_costs(
            "census-gradient", scene.left, scene.right, block, bin_width, lowest, count
        )
    assert costs is not None
    np.testing.assert_array_equal(costs, gather_window(reference, lowest, count, np.float32))


@settings(max_examples=20, deadline=None)
@given(
    seed=st.integers(0, 2**16),
    max_disparity=st.integers(1, 48),
    bin_width=st.integers(1, 4),
    count=st.integers(1, 6),
    tile=st.tuples(st.integers(1, 9), st.integers(1, 17)),
    smooth=st.booleans(),
)
def test_window_costs_built_tile_by_tile_are_the_blocks(
    seed, max_disparity, bin_width, count, tile, smooth
):
    """Tiles of any size (a single pixel, narrower than the aggregation's reach), each over its
    own windows' disparities, give the window costs of the whole block: windows that follow a
    smooth map (tiles with few disparities) or jump anywhere (tiles with all of them)."""
    scene = make_scene(56, 24, max_disparity=max_disparity, seed=seed)
    block = VolumeBlock(max_disparity, 3, 19)
    bins = max_disparity // bin_width + 1
    count = min(count, bins)
    rng = np.random.default_rng(seed)
    shape = (block.rows, scene.left.shape[1])
    if smooth:  # a slanted plane
        plane = np.add.outer(np.arange(shape[0]), np.arange(shape[1])) * (bins / sum(shape))
        lowest = np.minimum(plane.astype(np.int32), bins - count)
    else:
        lowest = rng.integers(0, bins - count + 1, shape).astype(np.int32)
    reference = bin_minimum(both(scene.left, scene.right, block)[0], bin_width)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(data_terms, "FUSED_VOLUME_BYTES", 0)
        patch.setattr(data_terms, "FUSED_VIEW_BYTES", 0)
        patch.setattr(fused_volume, "TILE_ROWS", tile[0])
        patch.setattr(fused_volume, "TILE_COLUMNS", tile[1])
        costs = window_costs(
            "census-gradient", scene.left, scene.right, block, bin_width, lowest, count
        )
    assert costs is not None
    np.testing.assert_array_equal(costs, gather_window(reference, lowest, count, np.float32))


@settings(max_examples=60, deadline=None)
@given(
    starts=st.lists(st.integers(0, 40), min_size=1, max_size=12),
    count=st.integers(1, 6),
    bin_width=st.integers(1, 4),
    max_disparity=st.integers(0, 200),
)
def test_a_tiles_disparities_are_the_union_of_its_windows(starts, count, bin_width, max_disparity):
    """The runs a tile's kernels go over hold every disparity of every pixel's window (up to the
    range's end) and no other, as ascending runs of whole bins with gaps between them."""
    last_bin = max_disparity // bin_width
    lowest = np.minimum(np.array(starts), max(0, last_bin - count + 1))
    runs = fused_volume.needed_runs(lowest.reshape(1, -1), count, bin_width, max_disparity)
    expected = {
        d
        for start in lowest.tolist()
        for b in range(start, start + count)
        for d in range(b * bin_width, (b + 1) * bin_width)
        if d <= max_disparity
    }
    covered = [d for first, last in runs for d in range(first, last + 1)]
    assert covered == sorted(expected)  # each once, ascending
    assert all(later[0] > earlier[1] + 1 for earlier, later in itertools.pairwise(runs))
    assert all(first % bin_width == 0 for first, _ in runs)


def test_a_tile_across_a_depth_edge_skips_the_disparities_between_its_surfaces(monkeypatch):
    """Windows near 2 and near 30 (a foreground edge in the tile): the kernels build the
    windows' disparities only, and the costs are the gathered bins all the same."""
    scene = make_scene(40, 48, max_disparity=40, seed=5)
    block = VolumeBlock(40, 2, 14)
    lowest = np.where(np.arange(48) < 20, 2, 30)[None].repeat(block.rows, 0).astype(np.int32)
    built: list[int] = []
    census_window = kernels.census_window

    def recorded(left, right, terms, table, max_disparity, first, *rest):
        built.extend(range(first, first + terms.shape[0]))
        return census_window(left, right, terms, table, max_disparity, first, *rest)

    reference = bin_minimum(both(scene.left, scene.right, block)[0], 1)
    monkeypatch.setattr(data_terms, "FUSED_VOLUME_BYTES", 0)
    monkeypatch.setattr(data_terms, "FUSED_VIEW_BYTES", 0)
    monkeypatch.setattr(kernels, "census_window", recorded)
    costs = window_costs("census-gradient", scene.left, scene.right, block, 1, lowest, 4)
    assert costs is not None
    np.testing.assert_array_equal(costs, gather_window(reference, lowest, 4, np.float32))
    assert sorted(set(built)) == [2, 3, 4, 5, 30, 31, 32, 33]


def test_the_hamming_distance_is_the_count_of_differing_bits():
    """Codes differing in 0, 1, ... 24 and 32 bits (a zero gradient term: cost = table[H])."""
    distances = np.array([0, 1, 2, 3, 7, 12, 24, 32])
    left = np.zeros((5, len(distances)), np.uint32)
    right = np.zeros((5, len(distances)), np.uint32)
    right[:] = (np.uint64(1) << distances.astype(np.uint64)) - np.uint64(1)
    table = np.arange(256, dtype=np.float32) / 256 + np.float32(0.5)
    terms = np.zeros((1, 5, len(distances)), np.float32)
    volume = np.empty((1, 1, len(distances)), np.float32)
    census_aggregate(left, right, terms, table, 0, 0, 1, volume)
    # the box mean of a row of distinct costs: its 5 columns around (edges replicated)
    costs = np.pad(table[distances].astype(np.float64), 2, mode="edge")
    expected = np.convolve(costs, np.ones(5), mode="valid") * 5 / 25
    np.testing.assert_allclose(volume[0, 0], expected, rtol=1e-6)


def test_the_gradient_exponent_reads_the_right_view_shifted():
    left = np.arange(6, dtype=np.float32)[None].repeat(2, 0)
    right = np.zeros((2, 6 + 2), np.float32)  # two padded columns: disparities 0..2
    out = np.empty((3, 2, 6), np.float32)
    gradient_exponents(left, left, right, right, 2, 0, out)
    np.testing.assert_array_equal(out[1], np.float32(-0.1) * (2 * left))


@given(
    rows=st.integers(1, 8),
    largest=st.integers(8, 10),
    max_disparity=st.integers(0, 5),
    width=st.integers(1, 7),
)
def test_a_shorter_blocks_volume_in_the_scratch_is_what_the_compiled_kernels_take(
    rows, largest, max_disparity, width
):
    """A view's last block of rows is often shorter than the scratch buffer's: its volume must
    still be contiguous, or the compiled kernels pass it to numba (its import and JIT)."""
    scratch = np.empty((max_disparity + 1, largest, width), np.float32)
    volume = VolumeBlock(max_disparity, 5, 5 + rows).within(scratch)
    assert volume.shape == (max_disparity + 1, rows, width)
    assert np.shares_memory(volume, scratch)
    assert kernels._fits(volume, (np.dtype(np.float32), 3))
    assert VolumeBlock(max_disparity, 0, rows).within(None) is None


@pytest.mark.parametrize(
    ("rows", "width", "ready", "fused"),
    [
        (4, 100, True, False),  # a small block: OpenCV, numba loaded or not
        (400, 1000, True, True),  # a large block, the kernels compiled or numba loaded
        (400, 1000, False, False),  # the same before numba is loaded: no wait for its import
        (2000, 2000, False, True),  # a view volume beyond FUSED_VIEW_BYTES: worth the import
    ],
)
def test_the_kernels_take_large_blocks_without_waiting_for_numba(
    monkeypatch, rows, width, ready, fused
):
    monkeypatch.setattr(data_terms.kernels, "ready", lambda *chosen: ready)
    view = np.empty((rows, width), np.float32)
    assert data_terms._fused(VolumeBlock(128, 0, min(rows, 64)), view) is fused


def test_the_map_is_the_same_with_the_kernels_and_the_costs_in_two_threads(monkeypatch):
    """Costs per block at every level (no cache), several blocks per view, grids one at a time
    (their blocks dealt to two threads) and the compiled kernels: main's map bit for bit."""
    scene = make_scene(24, 40, max_disparity=30, seed=2)
    config = MatchConfig(max_disparity=30)
    monkeypatch.setattr(pipeline, "VOLUME_CACHE_BYTES", 0)
    monkeypatch.setattr(data_terms, "FUSED_VOLUME_BYTES", 2**62)
    reference = run_pipeline(scene.left, scene.right, config).disparity
    monkeypatch.setattr(data_terms, "FUSED_VOLUME_BYTES", 0)
    monkeypatch.setattr(data_terms, "FUSED_VIEW_BYTES", 0)
    monkeypatch.setattr(level_inputs, "VOLUME_BLOCK_BYTES", 25_000)
    monkeypatch.setattr(grid_views, "GRID_STATE_BYTES", 0)
    monkeypatch.setattr(grid_views, "threads", lambda: 2)
    monkeypatch.setattr(threads, "threads", lambda: 2)
    dealt = []
    original = level_inputs.LevelInputs._candidate_costs

    def recorded(self, *args):
        dealt.append(args[-1])
        return original(self, *args)

    monkeypatch.setattr(level_inputs.LevelInputs, "_candidate_costs", recorded)
    disparity = run_pipeline(scene.left, scene.right, config).disparity
    assert dealt and set(dealt) == {2}
    np.testing.assert_array_equal(disparity, reference)


@settings(max_examples=60, deadline=None)
@given(
    planes=st.integers(1, 30),
    bin_width=st.integers(1, 6),
    rows=st.integers(1, 5),
    top=st.integers(0, 3),
    data=st.data(),
)
def test_the_windows_minima_are_the_gathered_bins(planes, bin_width, rows, top, data):
    """The windows' costs straight from a cached volume are :func:`gather_window` of its
    :func:`bin_minimum`, bit for bit, for any block of its rows, a narrower last bin and ties
    (costs in quarters) included."""
    kernels.window_minima.jit()  # ready without a compiled module too (numba loaded)
    seed = data.draw(st.integers(0, 2**16))
    rng = np.random.default_rng(seed)
    width, bins = 7, -(-planes // bin_width)
    count = data.draw(st.integers(1, bins))
    volume = (rng.integers(0, 8, (planes, top + rows + 2, width)) / 4).astype(np.float32)
    lowest = rng.integers(0, bins - count + 1, (rows, width)).astype(np.int32)
    expected = gather_window(bin_minimum(volume[:, top : top + rows], bin_width), lowest, count)
    costs = window_minimum(volume, top, lowest, count, bin_width)
    assert costs is not None and costs.dtype == np.float64
    assert costs.tobytes() == expected.tobytes()


def test_windows_outside_the_bins_are_refused_and_other_volumes_left_to_the_caller(monkeypatch):
    kernels.window_minima.jit()  # ready without a compiled module too (numba loaded)
    volume = np.zeros((9, 4, 5), np.float32)  # 3 bins of 3
    lowest = np.zeros((4, 5), np.int32)
    assert window_minimum(volume, 0, lowest, 3, 3) is not None
    with pytest.raises(IndexError, match="outside the 3 bins"):
        window_minimum(volume, 0, lowest + 1, 3, 3)
    with pytest.raises(IndexError):
        window_minimum(volume, 0, lowest - 1, 1, 3)
    assert window_minimum(volume.astype(np.float64), 0, lowest, 3, 3) is None
    assert window_minimum(volume, 1, lowest, 3, 3) is None  # rows beyond the volume's
    assert window_minimum(volume, 0, lowest[:, :4].copy(), 3, 3) is None  # another width
    monkeypatch.setattr(kernels, "ready", lambda *chosen: False)
    assert window_minimum(volume, 0, lowest, 3, 3) is None


def test_the_map_is_the_same_with_the_windows_read_straight_from_the_cached_volumes(monkeypatch):
    """The accurate default keeps the views' volumes (a small pair): its bin levels' costs read
    straight from them by the kernel (no binned copy, :meth:`LevelInputs.prepare_costs` builds
    none) give the map of the binned volumes' gathers."""
    kernels.window_minima.jit()  # ready without a compiled module too (numba loaded)
    scene = make_scene(40, 64, max_disparity=30, seed=3)
    config = MatchConfig(max_disparity=30)
    calls = []

    def recorded(*args):
        costs = window_minimum(*args)
        if costs is not None:  # read by the kernel
            calls.append(args[4])
        return costs

    monkeypatch.setattr(level_inputs, "window_minimum", recorded)
    binned = []
    original = level_inputs.LevelInputs.binned_volumes
    monkeypatch.setattr(
        level_inputs.LevelInputs,
        "binned_volumes",
        lambda self: binned.append(self.plan.bin_width) or original(self),
    )
    direct = run_pipeline(scene.left, scene.right, config)
    assert {1, 2, 4} <= set(calls)  # the bin levels below the coarse grid read the volumes
    assert not binned  # and none bins them
    ready = kernels.ready
    monkeypatch.setattr(
        kernels, "ready", lambda *chosen: kernels.window_minima not in chosen and ready(*chosen)
    )
    calls.clear()
    gathered = run_pipeline(scene.left, scene.right, config)
    assert not calls and binned
    np.testing.assert_array_equal(direct.disparity, gathered.disparity)
    for ours, theirs in zip(direct.levels, gathered.levels, strict=True):
        assert ours.energy == theirs.energy and ours.lower_bound == theirs.lower_bound
