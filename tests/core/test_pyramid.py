"""Pyramid geometry and candidate windows."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from shared import pyramid


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
