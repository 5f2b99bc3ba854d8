"""The accurate preset's parts: AD-census costs, the bin pyramid, both views, the automatic
disparity range, and the paper preset left exactly as it was."""

from __future__ import annotations

import dataclasses
import hashlib
import itertools

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from shared import filters, grid, kernels, level_inputs, pipeline, pyramid
from shared.config import MatchConfig, Preset
from shared.data_terms import VolumeBlock, ad_census_volume, bin_minimum, census, window_reach
from shared.disparity_range import estimate_max_disparity
from shared.finishing import finish_level
from shared.images import load_pair
from shared.inference import solve_level_in_process
from shared.metrics import evaluate
from shared.pipeline import match_views, plan_run, prepare_level, run_pipeline
from shared.synthetic import make_scene


def _extended(image: np.ndarray, y: int, x: int) -> np.ndarray:
    """The image extended by replicating its border rows and columns."""
    height, width = image.shape[:2]
    return image[min(max(y, 0), height - 1), min(max(x, 0), width - 1)]


def _census_code(gray: np.ndarray, y: int, x: int) -> int:
    code, centre = 0, _extended(gray, y, x)
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            if dy or dx:
                code = (code << 1) | int(_extended(gray, y + dy, x + dx) < centre)
    return code


def _naive_cost(left, right, y, x, d) -> float:
    """The AD-census formula of one pixel and disparity, written out (before aggregation)."""
    gray_left, gray_right = left.mean(axis=2), right.mean(axis=2)  # any gray works for census
    xr = max(x - d, 0)
    ad = np.mean(np.abs(_extended(left, y, x) - _extended(right, y, xr))) * 255.0
    hamming = bin(_census_code(gray_left, y, x) ^ _census_code(gray_right, y, xr)).count("1")
    return 0.5 * (1 - np.exp(-ad / 10.0)) + 0.5 * (1 - np.exp(-hamming / 30.0))


def test_ad_census_volume_is_the_formula_aggregated_over_5x5():
    rng = np.random.default_rng(3)
    left = rng.random((7, 9, 3)).astype(np.float32)
    right = rng.random((7, 9, 3)).astype(np.float32)
    # the library takes Rec. 709 luma for census; give it views whose gray is the channel mean
    left[:] = left.mean(axis=2, keepdims=True)
    right[:] = right.mean(axis=2, keepdims=True)
    volume = ad_census_volume(left, right, VolumeBlock(3, 0, 7))
    for y, x, d in [(0, 0, 0), (3, 4, 2), (6, 8, 3), (2, 1, 3), (5, 7, 1)]:
        expected = np.mean(
            [
                _naive_cost(left, right, y + dy, min(max(x + dx, 0), 8), d)
                for dy in range(-2, 3)
                for dx in range(-2, 3)
            ]
        )
        assert volume[d, y, x] == pytest.approx(expected, abs=1e-5)


def test_constant_images_cost_only_their_colour_difference():
    left = np.full((8, 10), 0.5, np.float32)
    right = np.full((8, 10), 0.3, np.float32)
    volume = ad_census_volume(left, right, VolumeBlock(4, 0, 8))
    assert np.allclose(volume, 0.5 * (1 - np.exp(-51.0 / 10.0)), atol=1e-5)  # H = 0


def test_census_bit_is_set_where_the_neighbour_is_darker():
    gray = np.zeros((5, 5), np.float32)
    gray[2, 2] = 1.0  # a bright centre: every neighbour is darker
    assert census(gray)[0, 2] == 2**24 - 1
    gray[2, 2] = 0.0
    assert census(gray)[0, 2] == 0


def test_cost_blocks_equal_the_whole_image_rows():
    scene = make_scene(30, 40, max_disparity=8, seed=1)
    whole = ad_census_volume(scene.left, scene.right, VolumeBlock(8, 0, 30))
    for start, stop in [(0, 1), (5, 12), (29, 30)]:
        np.testing.assert_array_equal(
            ad_census_volume(scene.left, scene.right, VolumeBlock(8, start, stop)),
            whole[:, start:stop],
        )


def test_a_bin_costs_the_least_of_its_disparities():
    volume = np.random.default_rng(0).random((11, 2, 3)).astype(np.float32)
    binned = bin_minimum(volume, 4)
    assert binned.shape == (3, 2, 3)
    np.testing.assert_array_equal(binned[2], volume[8:11].min(axis=0))


@settings(max_examples=50, deadline=None)
@given(volume_width=st.integers(1, 40), bins=st.integers(0, 3), finer=st.integers(0, 3))
def test_bins_of_bins_are_the_bins_of_the_volume(volume_width, bins, finer):
    """The coarse levels read their bins from a volume binned finer (``volume_bin_width``): a
    bin's minimum over its sub-bins' minima is the very value of its minimum over disparities."""
    volume = np.random.default_rng(volume_width).random((volume_width, 2, 3)).astype(np.float32)
    width = 2 ** (bins + finer)
    np.testing.assert_array_equal(
        bin_minimum(bin_minimum(volume, 2**finer), 2**bins), bin_minimum(volume, width)
    )


@pytest.mark.parametrize("block_bytes", [1, 25_000])  # rows 1 by 1; 5 blocks, the last shorter
def test_the_cached_bins_built_in_blocks_are_the_whole_views_bins(monkeypatch, block_bytes):
    """The coarse levels' cache is built a block of rows at a time, every block's volume in
    one buffer reused: the very bins of each whole view's volume."""
    scene = make_scene(24, 40, max_disparity=30, seed=2)
    config = MatchConfig(max_disparity=30)
    _, plans = plan_run(scene.left, scene.right, config)
    inputs = prepare_level(scene.left, scene.right, config, plans[0])
    monkeypatch.setattr(level_inputs, "VOLUME_BLOCK_BYTES", 2**40)
    whole = inputs.binned_view_volumes(config.data_term, 2)
    monkeypatch.setattr(level_inputs, "VOLUME_BLOCK_BYTES", block_bytes)
    assert len(inputs._volume_blocks(0, inputs.view_height)) > 1
    blocked = inputs.binned_view_volumes(config.data_term, 2)
    for view, expected in zip(blocked, whole, strict=True):
        np.testing.assert_array_equal(view, expected)


@pytest.mark.parametrize(("cache_bytes", "cached"), [(0, None), (150_000, 2), (2**30, 1)])
def test_the_map_is_the_same_whatever_volume_is_cached(monkeypatch, cache_bytes, cached):
    """Without a cache (costs per block at every level), with the volumes binned at a middle
    level's width (the coarser level reads them, the finer builds its own) or with the full
    volumes: the same map, bit for bit. (Bins 4, 2, 1; a bin of both views is 7,680 bytes.)"""
    scene = make_scene(24, 40, max_disparity=30, seed=2)
    config = MatchConfig(max_disparity=30)
    assert [plan.bin_width for plan in plan_run(scene.left, scene.right, config)[1]] == [4, 2, 1]
    monkeypatch.setattr(pipeline, "VOLUME_CACHE_BYTES", 0)
    reference = run_pipeline(scene.left, scene.right, config).disparity
    monkeypatch.setattr(pipeline, "VOLUME_CACHE_BYTES", cache_bytes)
    built = []
    original = pipeline._cached_volumes

    def recorded(*args):
        volumes, width = original(*args)
        built.append(None if volumes is None else width)
        return volumes, width

    monkeypatch.setattr(pipeline, "_cached_volumes", recorded)
    disparity = run_pipeline(scene.left, scene.right, config).disparity
    assert built == [cached]
    np.testing.assert_array_equal(disparity, reference)


def test_a_cache_only_coarse_grids_read_may_be_larger_and_goes_before_their_last_solve(
    monkeypatch,
):
    """With no room for a cache the finer levels would read, the bins of 8 that only the two
    coarse-grid levels (16 and 8, on grids of a quarter and a half) read are cached under
    ``COARSE_VOLUME_CACHE_BYTES`` and released once the last of them has pooled them, before
    its solve: the map of a run without any cache, bit for bit."""
    scene = make_scene(40, 240, max_disparity=106, seed=3)
    config = MatchConfig(max_disparity=106)
    plans = plan_run(scene.left, scene.right, config)[1]
    assert [(plan.bin_width, plan.downsample) for plan in plans][:3] == [(16, 4), (8, 2), (4, 1)]
    monkeypatch.setattr(pipeline, "VOLUME_CACHE_BYTES", 0)
    monkeypatch.setattr(pipeline, "COARSE_VOLUME_CACHE_BYTES", 0)
    reference = run_pipeline(scene.left, scene.right, config).disparity
    monkeypatch.setattr(pipeline, "COARSE_VOLUME_CACHE_BYTES", 2**30)
    built, held = [], []
    original = pipeline._cached_volumes

    def recorded(*args):
        volumes, width = original(*args)
        built.append(None if volumes is None else width)
        return volumes, width

    def solve(inputs, config, **options):
        held.append((inputs.plan.bin_width, inputs.volumes is not None))
        return solve_level_in_process(inputs, config, **options)

    monkeypatch.setattr(pipeline, "_cached_volumes", recorded)
    disparity = run_pipeline(scene.left, scene.right, config, solve).disparity
    assert built == [8]
    assert held == [(16, True), (8, False), (4, False), (2, False), (1, False)]
    np.testing.assert_array_equal(disparity, reference)


@settings(max_examples=200, deadline=None)
@given(
    max_disparity=st.integers(1, 300),
    coarse_bins=st.integers(2, 16),
    candidates=st.integers(4, 8),
    data=st.data(),
)
def test_the_finer_window_holds_the_truth_when_the_coarser_bin_does(
    max_disparity, coarse_bins, candidates, data
):
    widths = pyramid.bin_widths(max_disparity, coarse_bins)
    assert widths[-1] == 1 and pyramid.bin_count(max_disparity, widths[0]) <= coarse_bins
    truth = data.draw(st.integers(0, max_disparity))
    for coarse, fine in itertools.pairwise(widths):
        count = min(candidates, pyramid.bin_count(max_disparity, fine))
        max_bin = pyramid.bin_count(max_disparity, fine) - 1
        window = pyramid.refined_bins(np.array([[truth // coarse]]), count, max_bin)[0, 0]
        assert truth // fine in window
        assert window.min() >= 0 and window.max() <= max_bin


def test_the_coarse_levels_costs_carry_the_prior_towards_the_coarser_bin():
    """On the coarse levels (``coarse_levels``) a pixel's costs are the data term plus
    ``coarse_prior`` per bin outside its coarser bin, on every path that reads them (the
    grid's and the bundles'); the finer levels keep the data term alone."""
    scene = make_scene(24, 40, max_disparity=60, seed=4)
    config = MatchConfig(max_disparity=60)
    left, right = match_views(scene.left, scene.right, config)
    plans = pyramid.plan(config, 60)
    template = config.levels[0]
    assert len(plans) > template.coarse_levels
    level_map = None
    for plan in plans:
        inputs = prepare_level(left, right, config, plan, level_map)
        if level_map is None or plan.index >= template.coarse_levels:
            assert inputs.coarse_bins is None
        else:
            upsampled = pyramid.upsample_labels(level_map, inputs.views, (inputs.view_height, 40))
            held = inputs.coarse_bins >= 0  # away from the coarser map's edges (prior_bins)
            assert held.any()
            np.testing.assert_array_equal(inputs.coarse_bins[held], np.rint(upsampled)[held])
            without = dataclasses.replace(inputs, coarse_bins=None)
            rows = slice(0, inputs.view_height)
            outside = pyramid.outside_coarse_bin(
                inputs.candidate_labels()[rows], inputs.coarse_bins[rows]
            )
            assert outside.max() > 0  # the windows reach beyond the coarser bins
            prior = outside.astype(np.float32) * np.float32(template.coarse_prior)
            grid = inputs.grid(config, 0, inputs.view_height)
            plain = without.grid(config, 0, inputs.view_height)
            np.testing.assert_array_equal(grid.unary, plain.unary + prior)
            bundle = inputs.costs(config, 0, inputs.view_height).unary
            plain_bundle = without.costs(config, 0, inputs.view_height).unary
            np.testing.assert_allclose(
                bundle - plain_bundle, prior.reshape(bundle.shape), atol=1e-12
            )
        solution = solve_level_in_process(inputs, config)
        level_map = finish_level(inputs, solution, config)


def test_a_flat_wall_keeps_its_coarser_bin_against_a_small_bias():
    """Why the prior: on a textureless wall every pixel's costs are flat but may share a small
    bias towards a wrong bin; summed over the wall that bias decides the optimum, which the
    level's minimiser finds (the smoothness is 0 inside a wall of one label). With the coarse
    prior, labels outside the coarser bin pay more than the bias, and the wall stays."""
    height, width, count = 12, 16, 6
    coarse_bins = np.full((height, width), 5, dtype=np.int32)
    first = pyramid.window_starts(coarse_bins, count, 40)  # labels 8 .. 13, children 10, 11
    unary = np.full((height, width, count), 0.2, dtype=np.float32)
    unary[:, :, 5] -= 0.005  # label 13: two bins outside, slightly cheaper everywhere
    level = MatchConfig().levels[0]
    guide = np.full((height, width), 0.5, dtype=np.float32)
    labels = first[:, :, None] + np.arange(count, dtype=np.int32)
    prior = pyramid.outside_coarse_bin(labels, coarse_bins).astype(np.float32)
    for weight, expected in ((0.0, {13}), (level.coarse_prior, {10, 11})):
        costs = unary + np.float32(weight) * prior
        mrf = grid.grid_mrf(costs, None, guide, level, MatchConfig().regularizer, first)
        result = grid.dual_decomposition(mrf, 40, 0.0)
        assert set(np.unique(first + result.labels)) <= expected


def test_occluded_strip_takes_the_background_disparity():
    scene = make_scene(64, 96, max_disparity=16, slanted=False, layers=1, seed=5)
    right_of_left = scene.disparity  # use the ground truths of both views
    valid = filters.left_right_check(right_of_left, scene.right_disparity, 1.0)
    occluded = ~valid
    assert occluded.any()
    corrupted = np.where(occluded, 99.0, right_of_left).astype(np.float32)
    filled = filters.fill_from_background(corrupted, valid)
    background = float(scene.disparity.min())
    # every occluded pixel (uncovered background beside the square) gets the background's value
    np.testing.assert_allclose(filled[occluded], background, atol=1.0)
    np.testing.assert_array_equal(filled[valid], right_of_left[valid])


def test_the_right_edge_within_the_windows_reach_is_never_confirmed():
    scene = make_scene(48, 80, max_disparity=8, seed=4)
    config = MatchConfig(max_disparity=8)
    validity = run_pipeline(scene.left, scene.right, config).validity
    reach = window_reach(config.data_term)
    assert reach > 0 and not validity[:, -reach:].any()
    assert validity[:, -reach - 8 : -reach].mean() > 0.5  # only the padding's columns


def test_the_mirrored_pair_gives_the_right_views_disparity():
    scene = make_scene(64, 96, max_disparity=12, seed=2)
    config = MatchConfig(max_disparity=12)
    left, right = match_views(scene.left, scene.right, config)
    _, plans = plan_run(left, right, config)
    level_map = None
    for plan in plans:
        inputs = prepare_level(left, right, config, plan, level_map)
        level_map = finish_level(inputs, solve_level_in_process(inputs, config), config)
    right_view = level_map[64:, ::-1]
    assert evaluate(right_view, scene.right_disparity).bpp < 5.0
    assert evaluate(level_map[:64], scene.disparity).bpp < 5.0


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("max_disparity", [8, 24, 60])
def test_auto_range_covers_the_scene_and_stays_near_it(seed, max_disparity):
    scene = make_scene(96, 160, max_disparity=max_disparity, seed=seed)
    true = float(scene.disparity.max())
    estimate = estimate_max_disparity(scene.left, scene.right)
    assert estimate.source == "auto"
    assert true <= estimate.max_disparity <= 1.5 * true + 4


def test_auto_range_on_the_middlebury_scenes(middlebury_dir):
    for name, true in [("tsukuba", 14), ("venus", 19.75), ("cones", 55)]:
        folder = middlebury_dir / name
        ext = "png" if name == "cones" else "ppm"
        left, right = load_pair(folder / f"left.{ext}", folder / f"right.{ext}")
        estimate = estimate_max_disparity(left, right).max_disparity
        assert true <= estimate <= 1.5 * true + 4, name


def _digest(disparity: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(disparity, np.float32).tobytes()).hexdigest()[:16]


#: Outputs of the paper's pipeline before the presets existed (commit 6e99293).
PAPER_DIGESTS = {"exact": "7aa3bf1a24006d5c", "sa": "c1c263020ca1f2ab"}


@pytest.mark.parametrize("solver", sorted(PAPER_DIGESTS))
def test_the_paper_preset_gives_the_output_it_gave_before_the_presets(solver):
    scene = make_scene(seed=0)
    config = MatchConfig(preset=Preset.PAPER, solver=solver, max_disparity=12, seed=3)
    result = run_pipeline(scene.left, scene.right, config)
    assert _digest(result.disparity) == PAPER_DIGESTS[solver]


def test_the_paper_preset_on_tsukuba_is_unchanged(tsukuba):
    left, right = load_pair(tsukuba.left, tsukuba.right)
    config = MatchConfig(preset=Preset.PAPER, max_disparity=20)
    assert _digest(run_pipeline(left, right, config).disparity) == "b33a223c855eb795"


def test_the_weighted_median_is_deterministic():
    rng = np.random.default_rng(0)
    disparity = rng.integers(0, 20, (60, 80)).astype(np.float32)
    guide = rng.random((60, 80, 3)).astype(np.float32)  # colour: quantised by k-means
    first = filters.weighted_median(disparity, guide, 9, 25.5)
    for _ in range(3):
        np.testing.assert_array_equal(filters.weighted_median(disparity, guide, 9, 25.5), first)


def test_the_weighted_median_uses_its_sigma():
    rng = np.random.default_rng(0)
    disparity = rng.integers(0, 20, (60, 80)).astype(np.float32)
    guide = rng.random((60, 80, 3)).astype(np.float32)
    wide = filters.weighted_median(disparity, guide, 9, 25.5)
    assert not np.array_equal(filters.weighted_median(disparity, guide, 9, 5.0), wide)


@settings(max_examples=150, deadline=None)
@given(
    seed=st.integers(0, 2**16),
    height=st.integers(1, 40),
    width=st.integers(1, 40),
    values=st.sampled_from(["few", "many", "every"]),
    offset=st.sampled_from([0, 37, -120]),
    colour=st.booleans(),
    levels=st.sampled_from([2, 4, 256]),
    radius=st.integers(1, 12),
    sigma=st.sampled_from([1.0, 5.0, 25.5, 100.0]),
)
@example(  # an exact tie: the 8-bit path without the shift to the least value gave 143, not 238
    seed=0, height=3, width=1, values="fixed", offset=0, colour=False, levels=2, radius=2,
    sigma=25.5,
)  # fmt: skip
def test_whole_disparities_take_opencvs_float_weighted_median(
    seed, height, width, values, offset, colour, levels, radius, sigma
):
    """Whole maps go to OpenCV as 8 bits above their least value: the very medians of its float
    path, ties (a cut that stops at the least rank), unused values and far-apart colours (zero
    weights) included."""
    rng = np.random.default_rng(seed)
    shape = (height, width)
    if values == "fixed":
        disparity = np.array([[242.0], [238.0], [143.0]], np.float32)
        guide = np.array([[0.0], [1.0], [1.0]], np.float32)
    else:
        if values == "few":
            disparity = rng.choice(rng.integers(0, 256, 3), shape)
        elif values == "many":
            disparity = rng.integers(0, 256, shape)
        else:  # all 256 (when they fit)
            disparity = rng.permutation(np.resize(np.arange(256), height * width)).reshape(shape)
        disparity = (disparity + offset).astype(np.float32)
        guide_shape = (*shape, 3) if colour else shape
        guide = (rng.integers(0, levels, guide_shape) / (levels - 1)).astype(np.float32)
    guide8 = np.clip(np.rint(guide * 255.0), 0, 255).astype(np.uint8)
    if guide8.ndim == 3 and len(np.unique(guide8.reshape(-1, 3) >> 2, axis=0)) == 1:
        guide8 = guide8[..., 0]  # one colour: OpenCV reads past its 1 x 1 k-means centres
    cv2.setRNGSeed(0)
    floats = cv2.ximgproc.weightedMedianFilter(guide8, disparity, radius, sigma=sigma)
    np.testing.assert_array_equal(filters.weighted_median(disparity, guide, radius, sigma), floats)


def test_fractional_or_wide_disparities_keep_the_float_weighted_median():
    rng = np.random.default_rng(1)
    guide = rng.random((30, 40, 3)).astype(np.float32)
    for disparity in (rng.random((30, 40)) * 20, rng.integers(0, 300, (30, 40)).astype(float)):
        disparity = disparity.astype(np.float32)
        cv2.setRNGSeed(0)
        floats = cv2.ximgproc.weightedMedianFilter(
            np.clip(np.rint(guide * 255.0), 0, 255).astype(np.uint8), disparity, 9, sigma=25.5
        )
        np.testing.assert_array_equal(filters.weighted_median(disparity, guide, 9, 25.5), floats)


def test_the_squared_difference_volume_matches_it_at_the_candidates():
    from shared.data_terms import squared_difference, squared_volume

    scene = make_scene(20, 30, max_disparity=6, seed=4)
    volume = squared_volume(scene.left, scene.right, VolumeBlock(6, 3, 9))
    candidates = np.broadcast_to(np.arange(7, dtype=np.int32), (6, 30, 7))
    expected = squared_difference(scene.left[3:9], scene.right[3:9], candidates)
    np.testing.assert_allclose(np.moveaxis(volume, 0, -1), expected)


def test_each_data_term_works_in_the_bin_pyramid(scene):
    """Coarse levels' labels are bins: the squared difference too takes a bin's best disparity."""
    config = MatchConfig(max_disparity=16, data_term="squared")
    result = run_pipeline(scene.left, scene.right, config)
    assert [level.bin_width for level in result.levels] == [4, 2, 1]
    assert evaluate(result.disparity, scene.disparity).bpp < 15.0


def test_subpixel_finds_the_vertex_of_a_parabolic_cost():
    truth = np.array([[2.3, 4.75, 1.5]], np.float32)
    d = np.arange(8, dtype=np.float32)[:, None, None]
    volume = (d - truth[None]) ** 2  # (D + 1, 1, 3): minimum at the true sub-pixel value
    refined = filters.subpixel(np.rint(truth), volume)
    np.testing.assert_allclose(refined, [[2.3, 4.75, 1.5]], atol=1e-5)


def test_subpixel_lowers_the_rmse_on_a_slanted_scene(scene):
    plain = run_pipeline(scene.left, scene.right, MatchConfig(max_disparity=16))
    refined = run_pipeline(scene.left, scene.right, MatchConfig(max_disparity=16, subpixel=True))
    assert (
        evaluate(refined.disparity, scene.disparity).rmse
        < evaluate(plain.disparity, scene.disparity).rmse
    )


@pytest.mark.parametrize("compiled", [True, False], ids=["kernel", "numpy"])
@settings(
    max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    labels=st.integers(1, 12),
    seed=st.integers(0, 2**16),
    scale=st.sampled_from([0.5, 1.0, 4.0]),
)
def test_the_cost_confidence_is_the_peak_ratio_over_every_far_disparity(
    monkeypatch, compiled, labels, seed, scale
):
    """Plane by plane, the confidence is the formula over the whole volume at once: c_alt the
    least cost more than 1 px from the rounded disparity (ties and zero costs included); its
    reduction by the kernel and by the NumPy loop alike."""
    monkeypatch.setattr(kernels, "ready", lambda *chosen: compiled)
    rng = np.random.default_rng(seed)
    volume = np.rint(rng.random((labels, 3, 4)) * 4).astype(np.float32)  # ties, zeros
    disparity = (rng.random((3, 4)) * (labels + 2) - 1) * scale
    chosen = np.clip(np.rint(disparity), 0, labels - 1).astype(np.intp)[None]
    own = np.take_along_axis(volume, chosen, axis=0)[0]
    far = np.abs(np.arange(labels)[:, None, None] - chosen) > 1
    others = np.where(far, volume, np.inf).min(axis=0)
    margin = np.where(np.isfinite(others), others - own, 0.0)
    expected = np.divide(margin, others, out=np.zeros_like(margin), where=others > 0)
    expected = np.clip(expected, 0, 1).astype(np.float32)
    np.testing.assert_array_equal(filters.cost_confidence(volume, disparity), expected)
    least = filters.least_costs(volume)  # taken beforehand, as the pipeline does
    np.testing.assert_array_equal(filters.cost_confidence(volume, disparity, least), expected)


@pytest.mark.parametrize("compiled", [True, False], ids=["kernel", "numpy"])
@settings(
    max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    planes=st.integers(1, 12),
    count=st.integers(1, 6),
    seed=st.integers(0, 2**16),
    dtype=st.sampled_from([np.float32, np.float64]),
)
def test_the_least_costs_are_a_stable_sort_s_first(
    monkeypatch, compiled, planes, count, seed, dtype
):
    """Each pixel's least costs ascending, of equal costs the lower disparity first (a stable
    sort's first ``count``), +inf past the volume's depth; kernel and NumPy loop alike."""
    monkeypatch.setattr(kernels, "ready", lambda *chosen: compiled)
    rng = np.random.default_rng(seed)
    volume = np.rint(rng.random((planes, 3, 4)) * 3).astype(dtype)  # many ties
    indices, values = filters.least_costs(volume, count)
    assert values.dtype == dtype and indices.shape == values.shape == (count, 3, 4)
    order = np.argsort(volume, axis=0, kind="stable")[:count]
    kept = min(count, planes)
    np.testing.assert_array_equal(indices[:kept], order)
    np.testing.assert_array_equal(values[:kept], np.take_along_axis(volume, order, axis=0))
    assert np.all(np.isinf(values[kept:]))


def test_the_runs_confidence_is_the_final_maps(scene):
    """The least costs taken beside the finish give the confidence computed afterwards."""
    config = MatchConfig(max_disparity=16)
    left, right = match_views(scene.left, scene.right, config)
    result = run_pipeline(scene.left, scene.right, config)
    assert result.confidence is not None and result.confidence.max() > 0
    plans = plan_run(left, right, config)[1]
    afresh = pipeline.confidence_map(
        result.disparity, result.validity, left, right, config, plans[-1], None
    )
    np.testing.assert_array_equal(result.confidence, afresh)
