"""Heidari et al. (min-cut per row, checked against the row DP) and the filled StereoSGBM anchor
(its settings: tests/bench/test_bench_generalisation.py)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.baselines import (
    heidari,
    heidari_config,
    linear_slopes,
    minimum_cut_rows,
    sgbm,
)
from shared.config import LevelConfig, Regularizer
from shared.energy import Costs, level_costs, mrf_energy
from shared.filters import fill_from_background
from shared.metrics import evaluate
from shared.pyramid import initial_candidates
from shared.solvers.exact import solve_chains


def _linear_costs(seed: int, height: int, width: int, labels: int, slope_scale: float) -> Costs:
    rng = np.random.default_rng(seed)
    slopes = slope_scale * rng.random((height, width - 1))
    distance = np.abs(np.subtract.outer(np.arange(labels), np.arange(labels)))
    return Costs(
        candidates=np.broadcast_to(np.arange(labels, dtype=np.int32), (height, width, labels)),
        unary=rng.random((height, width, labels)),
        pair_h=slopes[:, :, None, None] * distance,
        pair_v=np.zeros((height - 1, width, labels, labels)),
    )


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    height=st.integers(1, 3),
    width=st.integers(1, 9),
    labels=st.integers(1, 7),
    slope_scale=st.sampled_from([0.0, 0.01, 0.3, 5.0]),
)
def test_min_cut_reaches_the_row_dp_optimum(seed, height, width, labels, slope_scale):
    costs = _linear_costs(seed, height, width, labels, slope_scale)
    cut = minimum_cut_rows(costs)
    assert cut.shape == (height, width)
    assert cut.min() >= 0 and cut.max() < labels
    for row in range(height):
        rows = costs.rows(row, row + 1)
        best = mrf_energy(rows, solve_chains(rows))
        assert mrf_energy(rows, cut[row : row + 1]) == pytest.approx(best, rel=1e-9, abs=1e-12)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), max_disparity=st.integers(1, 6))
def test_heidari_on_image_rows_matches_the_dp_and_its_own_pipeline_config(seed, max_disparity):
    rng = np.random.default_rng(seed)
    left, right = rng.random((2, 4, 10)).astype(np.float32)
    result = heidari(left, right, max_disparity)  # cross-checks every row against the DP
    assert result.info["dp_max_relative_gap"] <= 1e-9
    config = heidari_config(max_disparity)
    level = config.levels[0]
    candidates = initial_candidates(left.shape, level.candidates, max_disparity)
    costs = level_costs(left, right, candidates, level, config.regularizer)
    dp = solve_chains(costs)
    dp_energy = sum(mrf_energy(costs.rows(r, r + 1), dp[r : r + 1]) for r in range(4))
    assert result.info["energy"] == pytest.approx(dp_energy, rel=1e-9)
    assert set(np.unique(result.disparity)) <= set(range(max_disparity + 1))


def test_heidari_config_is_one_full_resolution_linear_level():
    config = heidari_config(20)
    assert [(lv.downsample, lv.candidates) for lv in config.levels] == [(1, 21)]
    assert config.regularizer is Regularizer.LINEAR
    assert not config.median and not config.bilateral


def test_min_cut_refuses_costs_it_cannot_represent():
    truncated = level_costs(
        np.random.default_rng(0).random((2, 6), dtype=np.float32),
        np.random.default_rng(1).random((2, 6), dtype=np.float32),
        initial_candidates((2, 6), 5, 4),
        LevelConfig(candidates=5, slope=1.0, truncation=1.5),
        Regularizer.TRUNCATED,
    )
    with pytest.raises(ValueError, match="linear"):
        linear_slopes(truncated)
    shifted = Costs(truncated.candidates + 1, truncated.unary, truncated.pair_h, truncated.pair_v)
    with pytest.raises(ValueError, match="candidates"):
        minimum_cut_rows(shifted)


def test_fill_takes_the_farther_neighbour_along_the_row():
    disparity = np.array([[0, 5, 0, 0, 2, 0], [7, 7, 7, 7, 7, 7]], np.float32)
    valid = np.array([[0, 1, 0, 0, 1, 0], [0, 0, 0, 0, 0, 0]], bool)
    filled = fill_from_background(disparity, valid, empty=0.0)
    np.testing.assert_array_equal(filled[0], [5, 5, 2, 2, 2, 2])
    np.testing.assert_array_equal(filled[1], 0)  # no valid pixel in the row: the empty value
    np.testing.assert_array_equal(fill_from_background(disparity, valid)[1], 7)  # or untouched


def test_sgbm_fills_every_pixel_and_matches_a_synthetic_scene(scene):
    result = sgbm(scene.left, scene.right, 16)
    assert np.isfinite(result.disparity).all()
    # OpenCV's search range (0..31 here), not clipped to the range asked for
    assert result.disparity.min() >= 0 and result.disparity.max() < result.info["num_disparities"]
    assert 0 < result.info["invalid_fraction"] < 0.5
    scores = evaluate(result.disparity, scene.ground_truth_values(), border=4)
    assert scores.bpp < 25
