"""Pyramid geometry and candidate windows."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from shared import pyramid
from shared.config import MatchConfig, Preset


def test_coarsest_candidates_are_0_to_5_with_the_paper_defaults():
    candidates = pyramid.initial_candidates((3, 4), 6, pyramid.level_max_disparity(20, 4))
    assert candidates.shape == (3, 4, 6)
    np.testing.assert_array_equal(candidates[1, 2], np.arange(6))


def test_coarsest_candidates_spread_over_a_larger_range():
    values = pyramid.initial_candidates((1, 1), 6, 15)[0, 0]
    assert values[0] == 0 and values[-1] == 15 and np.all(np.diff(values) > 0)


def test_refined_window_is_2d_minus_2_to_2d_plus_1():
    coarse = np.array([[3.0, 5.0]])
    candidates = pyramid.refined_candidates(coarse, (2, 4), 4, max_disparity=20)
    np.testing.assert_array_equal(candidates[0, 0], [4, 5, 6, 7])
    np.testing.assert_array_equal(candidates[1, 3], [8, 9, 10, 11])


def test_refined_window_is_shifted_inside_the_range():
    coarse = np.array([[0.0, 10.0]])
    candidates = pyramid.refined_candidates(coarse, (1, 2), 4, max_disparity=20)
    np.testing.assert_array_equal(candidates[0, 0], [0, 1, 2, 3])
    np.testing.assert_array_equal(candidates[0, 1], [17, 18, 19, 20])


@given(
    coarse=st.lists(st.floats(0, 12), min_size=1, max_size=8),
    count=st.integers(2, 6),
    max_disparity=st.integers(6, 30),
)
@settings(max_examples=50, deadline=None)
def test_refined_windows_are_contiguous_and_in_range(coarse, count, max_disparity):
    coarse_map = np.array([coarse], dtype=np.float32)
    candidates = pyramid.refined_candidates(coarse_map, (2, 2 * len(coarse)), count, max_disparity)
    assert candidates.min() >= 0 and candidates.max() <= max_disparity
    assert np.all(np.diff(candidates, axis=2) == 1)


def test_downsampling_is_anti_aliased():
    stripes = np.tile(np.array([0.0, 1.0], dtype=np.float32), (8, 8))  # period-2 pattern
    small = pyramid.downsample(stripes, 2)
    assert small.shape == (4, 8)
    np.testing.assert_allclose(small, 0.5, atol=1e-6)  # averaging, not picking every 2nd px


def test_upsampled_disparity_is_in_the_finer_levels_pixels():
    coarse = np.full((2, 3), 4.0, dtype=np.float32)
    fine = pyramid.upsample_disparity(coarse, (4, 6))
    assert fine.shape == (4, 6) and np.all(fine == 8.0)


@given(
    targets=st.lists(
        st.one_of(st.integers(-5, 40).map(float), st.integers(-10, 80).map(lambda h: h / 2)),
        min_size=1,
        max_size=8,
    ),
    starts=st.lists(st.integers(0, 30), min_size=8, max_size=8),
    count=st.integers(1, 8),
)
@settings(max_examples=100, deadline=None)
def test_the_nearest_in_a_window_is_the_argmin_of_the_distances(targets, starts, count):
    """The warm start of a bin level, computed from each window's first label, is the argmin of
    the distances to every candidate (ties to the first), as for any candidate array."""
    target = np.array([targets], dtype=np.float32)
    start = np.array([starts[: len(targets)]], dtype=np.int32)
    candidates = start[:, :, None] + np.arange(count, dtype=np.int32)
    expected = np.abs(candidates - target[:, :, None]).argmin(axis=2)
    np.testing.assert_array_equal(pyramid.nearest_in_window(target, start, count), expected)


@given(
    coarse=st.lists(st.integers(0, 20), min_size=1, max_size=6),
    offsets=st.lists(st.integers(-6, 8), min_size=6, max_size=6),
)
@settings(max_examples=100, deadline=None)
def test_outside_the_coarse_bin_is_the_distance_to_its_nearer_child(coarse, offsets):
    """The coarse-to-fine prior's count: 0 on the coarser bin's two children (2c, 2c + 1),
    else the bins to the nearer of them."""
    coarse_bins = np.array([coarse], dtype=np.int32)
    labels = 2 * coarse_bins[:, :, None] + np.array(offsets, dtype=np.int32)
    expected = [
        [
            [min(abs(label - 2 * c), abs(label - 2 * c - 1)) for label in row]
            for c, row in zip(coarse, pixel, strict=True)
        ]
        for pixel in labels
    ]
    outside = pyramid.outside_coarse_bin(labels, coarse_bins)
    assert outside.dtype == np.int32
    np.testing.assert_array_equal(outside, expected)


def test_only_the_accurate_presets_coarse_levels_take_the_coarse_prior():
    """The prior is the bin pyramid's, on the coarse_levels coarsest levels (as coarse_slope);
    the finer levels and the paper's image pyramid take none."""
    config = MatchConfig()  # accurate
    plans = pyramid.plan(config, 106)
    template = config.levels[0]
    assert template.coarse_prior > 0 and len(plans) > template.coarse_levels
    for plan in plans:
        expected = template.coarse_prior if plan.index < template.coarse_levels else 0.0
        assert plan.mrf.coarse_prior == expected
    paper = MatchConfig(preset=Preset.PAPER)
    assert all(plan.mrf.coarse_prior == 0.0 for plan in pyramid.plan(paper, 15))


def test_the_prior_holds_nothing_near_a_change_of_the_coarser_bin():
    """prior_bins: the coarser bins, -1 within PRIOR_EDGE_RADIUS px of a change of bin (the
    coarser map is blocky there); each view on its own, so the seam of the stacked views is no
    edge."""
    radius = pyramid.PRIOR_EDGE_RADIUS
    view = np.full((12, 16), 3.0, dtype=np.float32)
    view[:, 8:] = 5.0  # a depth edge between columns 7 and 8
    other = np.full((12, 16), 7.0, dtype=np.float32)  # the other view: flat, another bin
    bins = pyramid.prior_bins(np.concatenate([view, other]), 2)
    near = np.zeros((12, 16), dtype=bool)
    near[:, 8 - radius : 8 + radius] = True
    np.testing.assert_array_equal(bins[:12][near], -1)
    np.testing.assert_array_equal(bins[:12][~near], np.rint(view[~near]))
    np.testing.assert_array_equal(bins[12:], 7)  # no edge at the seam
    labels = np.arange(20, dtype=np.int32)[None, None, :].repeat(12, 0).repeat(16, 1)
    outside = pyramid.outside_coarse_bin(labels, bins[:12])
    assert not outside[near].any() and outside[~near].any()
