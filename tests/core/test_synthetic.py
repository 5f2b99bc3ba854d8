"""Synthetic scenes: the ground truth really is the left view's disparity."""

from __future__ import annotations

import numpy as np

from shared.synthetic import make_scene


def test_left_pixels_reappear_in_the_right_view_at_their_disparity():
    scene = make_scene(40, 64, max_disparity=10, slanted=False, seed=3)
    height, width = scene.left.shape
    rows, cols = np.mgrid[:height, :width]
    target = cols - np.rint(scene.disparity).astype(int)
    inside = target >= 0
    residual = np.abs(scene.left[inside] - scene.right[rows[inside], target[inside]])
    # most pixels match exactly; the rest are occluded in the right view
    assert np.median(residual) < 1e-6
    assert np.mean(residual < 1e-3) > 0.8
    # the wrong view (x + d) does not match
    shifted = np.clip(cols + np.rint(scene.disparity).astype(int), 0, width - 1)
    assert np.median(np.abs(scene.left - scene.right[rows, shifted])) > 0.02


def test_scenes_are_reproducible_and_in_range():
    a, b = make_scene(seed=5), make_scene(seed=5)
    np.testing.assert_array_equal(a.left, b.left)
    assert a.left.dtype == np.float32 and a.left.min() >= 0 and a.left.max() <= 1
    assert a.disparity.min() >= 1 and a.disparity.max() <= 12
    slanted = make_scene(slanted=True, layers=0)
    assert np.all(np.diff(slanted.disparity, axis=1) > 0)  # disparity grows along x
