"""Middlebury conventions: scale, unknown ground truth, border, masks."""

from __future__ import annotations

import numpy as np
import pytest

from shared.metrics import Truth, evaluate, evaluate_regions


def test_rmse_and_bad_pixels_use_the_ground_truth_scale():
    gt_values = np.full((4, 4), 16.0 * 5)  # disparity 5 stored at scale 16
    disparity = np.full((4, 4), 5.0)
    disparity[0, 0] = 7.0  # one bad pixel, error 2
    disparity[1, 1] = 5.5  # error 0.5: not bad
    scores = evaluate(disparity, gt_values, scale=16)
    assert scores.pixels == 16
    assert scores.bpp == pytest.approx(100 / 16)
    assert scores.rmse == pytest.approx(np.sqrt((4 + 0.25) / 16))


def test_zero_ground_truth_border_and_mask_are_excluded():
    gt_values = np.full((6, 6), 10.0)
    gt_values[2, 2] = 0  # unknown
    disparity = np.full((6, 6), 10.0)
    disparity[0, :] = 0  # wrong, but in the border
    disparity[2, 2] = 99  # wrong, but unknown
    disparity[3, 3] = 0  # wrong, masked out
    mask = np.ones((6, 6), bool)
    mask[3, 3] = False
    scores = evaluate(disparity, gt_values, scale=1, border=1, mask=mask)
    assert scores.pixels == 16 - 2
    assert scores.bpp == 0 and scores.rmse == 0


def test_exactly_one_pixel_off_is_not_bad():
    scores = evaluate(np.array([[2.0, 3.0]]), np.array([[1.0, 1.0]]))
    assert scores.bpp == pytest.approx(50.0)


def test_error_map_is_nan_outside_the_evaluated_pixels():
    errors = Truth(np.array([[1, 0, 1], [1, 1, 1], [1, 1, 1.0]])).error_map(np.full((3, 3), 2.0))
    assert np.isnan(errors[0, 1]) and errors[0, 0] == pytest.approx(1.0)


def test_nothing_to_evaluate_is_an_error():
    with pytest.raises(ValueError, match="no pixel left"):
        evaluate(np.zeros((2, 2)), np.zeros((2, 2)))


def test_middlebury_and_kitti_measures():
    truth = np.array([[10.0, 10.0, 100.0, 100.0, 50.0, 50.0, 20.0, 20.0]])
    disparity = truth + np.array([[0.4, 0.6, 1.5, 3.5, 4.5, 0.0, -3.5, 0.0]])
    scores = evaluate(disparity, truth, threshold=3.0)
    assert scores.bad_0_5 == pytest.approx(100 * 5 / 8)  # 0.6, 1.5, 3.5, 4.5, 3.5
    assert scores.bad_1 == pytest.approx(100 * 4 / 8)
    assert scores.bad_2 == pytest.approx(100 * 3 / 8)
    assert scores.bad_4 == pytest.approx(100 * 1 / 8)
    # D1: > 3 px and > 5 %: 3.5 of 100 is 3.5 % (not an outlier), 4.5 of 50, 3.5 of 20 are
    assert scores.d1 == pytest.approx(100 * 2 / 8)
    assert scores.bpp == pytest.approx(100 * 3 / 8) and scores.threshold == 3.0
    assert scores.avgerr == pytest.approx((0.4 + 0.6 + 1.5 + 3.5 + 4.5 + 3.5) / 8)


def test_regions_are_scored_within_the_mask_and_empty_ones_left_out():
    truth = np.full((2, 4), 8.0)
    disparity = truth.copy()
    disparity[0, 0] = 0.0
    foreground = np.zeros((2, 4), bool)
    foreground[0, :2] = True
    scores = evaluate_regions(
        disparity, truth, {"fg": foreground, "bg": ~foreground, "none": None, "empty": truth < 0}
    )
    assert set(scores) == {"all", "fg", "bg"}
    assert (scores["fg"].d1, scores["bg"].d1, scores["all"].d1) == (50.0, 0.0, 12.5)
