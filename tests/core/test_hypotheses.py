"""The bin pyramid's second hypothesis (``second_bins``): a wrong coarse bin can be undone."""

from __future__ import annotations

import numpy as np

from shared.config import MatchConfig
from shared.hypotheses import second_bins
from shared.pipeline import match_views, plan_run, prepare_level
from shared.synthetic import make_scene


def test_the_runner_up_is_never_a_neighbour_of_the_chosen_bin():
    costs = np.full((6, 3, 3), 1.0, dtype=np.float32)
    costs[2] = 0.0  # next to the chosen bin 1: its children are in the window already
    costs[4] = 0.5
    chosen = np.ones((3, 3), dtype=np.int32)
    assert (second_bins(costs, chosen, radius=0) == 4).all()


def test_the_runner_up_is_the_regions_not_one_noisy_pixels():
    costs = np.full((8, 5, 5), 1.0, dtype=np.float32)
    costs[5] = 0.5  # the region's runner-up
    costs[7, 2, 2] = 0.0  # one pixel's noise
    chosen = np.zeros((5, 5), dtype=np.int32)
    assert second_bins(costs, chosen, radius=0)[2, 2] == 7
    assert (second_bins(costs, chosen, radius=2) == 5).all()


def test_without_a_bin_two_away_the_chosen_one_stays():
    costs = np.zeros((3, 2, 2), dtype=np.float32)
    chosen = np.ones((2, 2), dtype=np.int32)
    assert (second_bins(costs, chosen, radius=1) == 1).all()


def test_a_wrong_coarse_bin_leaves_the_true_bins_among_the_finer_candidates():
    scene = make_scene(48, 64, max_disparity=24, slanted=False, layers=0, seed=3)
    truth = int(np.rint(scene.disparity[24, 32]))
    config = MatchConfig(max_disparity=24, lr_check=False, second_bins=1, second_bins_radius=4)
    left, right = match_views(scene.left, scene.right, config)
    plans = plan_run(left, right, config)[1]
    coarse, fine = plans[0], plans[1]
    wrong = (truth // coarse.bin_width + 3) % (coarse.max_label + 1)  # far from the truth
    previous = np.full(left.shape[:2], wrong, dtype=np.float32)
    window = prepare_level(
        left, right, config.model_copy(update={"second_bins": 0}), fine, previous
    )
    both = prepare_level(left, right, config, fine, previous)
    assert window.candidates is None  # a window level keeps its first candidates only
    assert both.count == window.count + 2
    assert (both.candidate_labels()[:, :, :-2] == window.candidate_labels()).all()
    inner = (slice(8, -8), slice(32, -8))  # away from the borders and the left edge's occlusion
    holds = (both.candidate_labels()[inner] == truth // fine.bin_width).any(axis=2)
    assert not (window.candidate_labels()[inner] == truth // fine.bin_width).any()
    assert holds.mean() > 0.9
