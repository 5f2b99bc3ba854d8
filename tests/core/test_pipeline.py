"""The pipeline end to end on synthetic scenes with known ground truth."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from shared.config import LevelConfig, MatchConfig, Regularizer
from shared.energy import mrf_energy
from shared.metrics import evaluate
from shared.pipeline import prepare_level, run_pipeline
from shared.solve import BundleResult, assemble, solve_bundles, solve_level_in_process


def _scores(scene, **overrides):
    result = run_pipeline(scene.left, scene.right, MatchConfig(max_disparity=16, **overrides))
    return result, evaluate(result.disparity, scene.disparity)


def test_default_pipeline_recovers_the_synthetic_ground_truth(scene):
    result, scores = _scores(scene)
    assert result.disparity.shape == scene.left.shape
    assert result.disparity.dtype == np.float32
    # A shuffled, shifted or wrong-view pipeline lands far above these (see the next test).
    assert scores.bpp < 15.0
    assert scores.rmse < 2.5
    assert [level.downsample for level in result.levels] == [4, 2, 1]
    assert [level.bundles for level in result.levels] == [24, 48, 96]


def test_matching_the_wrong_view_fails_the_same_threshold(scene):
    swapped = run_pipeline(scene.right, scene.left, MatchConfig(max_disparity=16))
    assert evaluate(swapped.disparity, scene.disparity).bpp > 40.0


def test_regularisation_and_filters_each_help(scene):
    _, full = _scores(scene)
    _, data_only = _scores(scene, regularizer=Regularizer.NONE, median=False, bilateral=False)
    assert full.bpp < data_only.bpp


def test_level_energies_are_the_exact_row_optima(scene):
    config = MatchConfig(max_disparity=16)
    inputs = prepare_level(scene.left, scene.right, config, 0)
    solution = solve_level_in_process(inputs, config)
    costs = inputs.costs(config)
    rng = np.random.default_rng(0)
    for _ in range(5):  # no random labelling beats the DP on its rows
        labels = rng.integers(0, costs.num_labels, costs.shape)
        other = sum(
            mrf_energy(costs.rows(r, r + 1), labels[r : r + 1]) for r in range(costs.shape[0])
        )
        assert solution.energy <= other


def test_finer_level_candidates_follow_the_coarser_estimate(scene):
    config = MatchConfig(max_disparity=16)
    coarse = np.full((24, 32), 3.0, dtype=np.float32)
    inputs = prepare_level(scene.left, scene.right, config, 1, coarse)
    np.testing.assert_array_equal(inputs.candidates[0, 0], [4, 5, 6, 7])
    assert np.all(inputs.initial_labels == 2)  # candidate 6 = 2 * 3


def test_assemble_refuses_missing_or_doubled_rows(scene):
    config = MatchConfig(max_disparity=16)
    inputs = prepare_level(scene.left, scene.right, config, 0)
    results = solve_bundles(inputs, config, [(0, 1), (1, 2)])
    with pytest.raises(ValueError, match="rows missing"):
        assemble(inputs, results)
    extra = BundleResult(0, 1, results[0].labels, 0.0, 0, 0.0)
    whole = solve_bundles(inputs, config, [(r, r + 1) for r in range(inputs.shape[0])])
    with pytest.raises(ValueError, match="solved twice"):
        assemble(inputs, [*whole, extra])


def test_bundle_results_do_not_depend_on_how_rows_are_grouped(scene):
    config = MatchConfig(max_disparity=16)
    inputs = prepare_level(scene.left, scene.right, config, 1)
    together = assemble(
        inputs, solve_bundles(inputs, config, [(r, r + 1) for r in range(inputs.shape[0])])
    )
    apart = assemble(
        inputs,
        [
            result
            for r in range(inputs.shape[0])
            for result in solve_bundles(inputs, config, [(r, r + 1)])
        ],
    )
    np.testing.assert_array_equal(together.labels, apart.labels)


def test_single_level_configurations_work(scene):
    config = MatchConfig(max_disparity=16, levels=[LevelConfig(downsample=1, candidates=17)])
    result = run_pipeline(scene.left, scene.right, config)
    assert len(result.levels) == 1 and result.disparity.shape == scene.left.shape


def test_invalid_configurations_are_refused():
    with pytest.raises(ValidationError, match="halve"):
        MatchConfig(levels=[LevelConfig(downsample=4), LevelConfig(downsample=1)])
    with pytest.raises(ValidationError, match="odd"):
        MatchConfig(median_size=4)
    with pytest.raises(ValidationError):
        MatchConfig(max_disparity=0)


def test_process_pool_gives_the_sequential_result(scene):
    from shared.solve import ProcessPoolLevelSolver

    config = MatchConfig(max_disparity=16, solver="steepest-descent", encoding="domain-wall")
    small = scene.left[:32, :48], scene.right[:32, :48]
    sequential = run_pipeline(*small, config)
    with ProcessPoolLevelSolver(2) as pool:
        parallel = run_pipeline(*small, config, pool)
    np.testing.assert_array_equal(sequential.disparity, parallel.disparity)
    assert [lv.energy for lv in sequential.levels] == [lv.energy for lv in parallel.levels]


def test_fast_median_equals_the_reference_median():
    from scipy import ndimage

    from shared.filters import median

    values = np.random.default_rng(0).integers(0, 60, (23, 31)).astype(np.float32)
    expected = ndimage.median_filter(values, size=7, mode="nearest")
    np.testing.assert_array_equal(median(values, 7), expected)
    fractional = values + 0.5
    np.testing.assert_array_equal(median(fractional, 7), expected + 0.5)
