"""What the service checks of an uploaded pair before matching it: the order and rectification of
the views (a warning that says what to do), and the scale of a ground truth given without one."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from shared import kernels
from shared.disparity_range import (
    ViewsWarning,
    quick_match,
    resolve_max_disparity,
    views_warning,
)
from shared.filters import lowest
from shared.ground_truth import CONVENTIONAL_SCALES, ScaleNotInferredError, infer_gt_scale


@pytest.mark.parametrize("compiled", [True, False], ids=["kernel", "numpy"])
@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    shape=st.tuples(st.integers(1, 9), st.integers(1, 5), st.integers(1, 6)),
    levels=st.integers(1, 4),
    seed=st.integers(0, 2**16),
)
def test_lowest_is_numpys_first_argmin_and_minimum(monkeypatch, compiled, shape, levels, seed):
    """The views' check's reduction over disparities: numpy's argmin (the first of ties: few
    cost levels make many) and min, and the runner-up outside +-1 of the argmin; by the kernel
    and by the NumPy loop alike."""
    monkeypatch.setattr(kernels, "ready", lambda *chosen: compiled)
    volume = np.random.default_rng(seed).integers(0, levels, shape).astype(np.float32)
    index, minimum = lowest(volume)
    assert np.array_equal(index, volume.argmin(axis=0))
    assert np.array_equal(minimum, volume.min(axis=0))
    near = np.abs(np.arange(shape[0])[:, None, None] - index[None]) <= 1
    expected = np.where(near, np.inf, volume).min(axis=0)
    assert np.array_equal(lowest(volume, outside=index)[1], expected)


@pytest.fixture(scope="module")
def forward(scene):
    return quick_match(scene.left, scene.right)


def test_a_rectified_pair_in_order_gets_no_warning(scene, recwarn):
    estimate = resolve_max_disparity(scene.left, scene.right, "auto")
    assert estimate.warning == ""
    assert not [w for w in recwarn if issubclass(w.category, ViewsWarning)]
    assert resolve_max_disparity(scene.left, scene.right, 16).warning == ""


@pytest.mark.parametrize("max_disparity", ["auto", 16])
def test_swapped_views_are_named_with_what_to_do(scene, max_disparity):
    with pytest.warns(ViewsWarning, match="swapped") as caught:
        estimate = resolve_max_disparity(scene.right, scene.left, max_disparity)
    assert estimate.warning == str(caught[0].message)
    assert "pass the left view first" in estimate.warning


def test_views_that_are_not_rectified_are_named(scene):
    height, width = scene.left.shape[:2]
    rotated = cv2.warpAffine(
        scene.right, cv2.getRotationMatrix2D((width / 2, height / 2), 5, 1.0), (width, height)
    )
    assert views_warning(scene.left, rotated).startswith("the views do not look rectified")
    noise = np.random.default_rng(0).random(scene.left.shape).astype(np.float32)
    assert "rectify the pair first" in views_warning(scene.left, noise)


def test_one_image_twice_is_named(scene):
    assert "same image" in views_warning(scene.left, scene.left.copy())


def test_the_middlebury_scenes_pass_as_given_and_are_caught_swapped(middlebury_dir):
    from shared.datasets import load_scene

    for name in ("tsukuba", "venus", "cones"):
        left, right = load_scene(middlebury_dir / name).load()
        assert views_warning(left, right) == "", name
        assert views_warning(right, left).startswith("the views look swapped"), name


@settings(max_examples=12, deadline=None)
@given(scale=st.sampled_from(CONVENTIONAL_SCALES))
def test_any_conventional_scale_is_inferred(scene, forward, scale):
    stored = scene.disparity * scale
    estimate = infer_gt_scale(scene.left, scene.right, stored, forward)
    assert estimate.scale == scale
    assert f"inferred {scale:g}" in estimate.note and "give the scale" in estimate.note


def test_an_unknown_border_and_unknown_pixels_do_not_matter(scene, forward):
    stored = scene.disparity * 16
    stored[:10] = 0
    stored[:, :10] = np.nan
    assert infer_gt_scale(scene.left, scene.right, stored, forward).scale == 16


def test_no_scale_is_guessed_where_none_fits(scene, forward):
    with pytest.raises(ScaleNotInferredError, match="no usual scale"):
        infer_gt_scale(scene.left, scene.right, scene.disparity * 13.5, forward)
    unrelated = np.random.default_rng(1).uniform(1, 255, scene.disparity.shape)
    with pytest.raises(ScaleNotInferredError, match="do not follow the disparities"):
        infer_gt_scale(scene.left, scene.right, unrelated, forward)
    with pytest.raises(ScaleNotInferredError, match="only 0 pixels"):
        infer_gt_scale(scene.left, scene.right, np.zeros_like(scene.disparity), forward)


def test_the_middlebury_scales_are_inferred(middlebury_dir):
    from shared.datasets import load_scene

    for name, scale in (("tsukuba", 16), ("venus", 8), ("cones", 4)):
        scene = load_scene(middlebury_dir / name)
        left, right = scene.load()
        assert infer_gt_scale(left, right, scene.ground_truth()).scale == scale, name
