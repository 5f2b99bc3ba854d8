"""The pipeline end to end on synthetic scenes with known ground truth, both presets."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from pydantic import ValidationError

from shared.assembly import BundleResult, assemble
from shared.config import LevelConfig, MatchConfig, Preset, Regularizer
from shared.disparity_range import ViewsWarning
from shared.energy import mrf_energy
from shared.inference import solve_bundles, solve_level_in_process
from shared.metrics import evaluate
from shared.pipeline import match_views, plan_run, prepare_level, run_pipeline


def _scores(scene, **overrides):
    config = MatchConfig(**{"max_disparity": 16, **overrides})
    result = run_pipeline(scene.left, scene.right, config)
    return result, evaluate(result.disparity, scene.disparity)


def _level(scene, config, index, previous=None):
    left, right = match_views(scene.left, scene.right, config)
    _, plans = plan_run(left, right, config)
    return prepare_level(left, right, config, plans[index], previous)


def test_default_pipeline_recovers_the_synthetic_ground_truth(scene):
    result, scores = _scores(scene)
    assert result.disparity.shape == scene.left.shape
    assert result.disparity.dtype == np.float32
    # The paper's preset misses these thresholds on the same scene (next test).
    assert scores.bpp < 4.0
    assert scores.rmse < 1.5
    assert [level.bin_width for level in result.levels] == [4, 2, 1]
    assert [level.downsample for level in result.levels] == [1, 1, 1]  # coarse_grid 4: w / 4
    # grid inference with exact: one bundle per view (its whole grid), with a lower bound
    assert [level.bundles for level in result.levels] == [2] * 3
    assert all(level.lower_bound <= level.energy for level in result.levels)


def test_the_paper_preset_keeps_its_image_pyramid_and_misses_the_accurate_threshold(scene):
    result, scores = _scores(scene, preset=Preset.PAPER)
    assert [level.downsample for level in result.levels] == [4, 2, 1]
    assert [level.bundles for level in result.levels] == [24, 48, 96]
    assert scores.bpp < 15.0 and scores.rmse < 2.5
    assert scores.bpp > 4.0


@pytest.mark.parametrize("preset", list(Preset))
def test_matching_the_wrong_view_fails_the_same_threshold(scene, preset):
    config = MatchConfig(max_disparity=16, preset=preset)
    with pytest.warns(ViewsWarning, match="swapped"):  # and it says so
        swapped = run_pipeline(scene.right, scene.left, config)
    assert evaluate(swapped.disparity, scene.disparity).bpp > 40.0
    assert "swapped" in swapped.disparity_range.warning


@pytest.mark.parametrize("preset", list(Preset))
def test_regularisation_and_filters_each_help(scene, preset):
    _, full = _scores(scene, preset=preset)
    off = {"median": False, "bilateral": False, "weighted_median": False, "lr_check": False}
    _, data_only = _scores(scene, preset=preset, regularizer=Regularizer.NONE, **off)
    assert full.bpp < data_only.bpp


@pytest.mark.parametrize("preset", list(Preset))
def test_level_energies_are_the_exact_row_optima(scene, preset):
    config = MatchConfig(max_disparity=16, preset=preset)
    inputs = _level(scene, config, 0)
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
    config = MatchConfig(max_disparity=16, preset=Preset.PAPER, solver="sa")  # warm starts
    coarse = np.full((24, 32), 3.0, dtype=np.float32)
    inputs = _level(scene, config, 1, coarse)
    np.testing.assert_array_equal(inputs.candidate_labels()[0, 0], [4, 5, 6, 7])
    assert np.all(inputs.initial_labels == 2)  # candidate 6 = 2 * 3


def test_finer_bins_follow_the_coarser_bin(scene):
    # bins of 4, 2, 1 px; tiles sent whole read the coarser labels around them
    config = MatchConfig(max_disparity=16, solver="sa", certify_tiles=False)
    coarse = np.full((2 * 96, 128), 2.0, dtype=np.float32)  # bin 2 of width 4: 8..11 px
    inputs = _level(scene, config, 1, coarse)
    np.testing.assert_array_equal(inputs.candidate_labels()[0, 0], [2, 3, 4, 5, 6, 7])
    assert np.all(inputs.initial_labels == 2)  # bin 4 of width 2 = 8..9 px


@pytest.mark.parametrize(
    "settings",
    [{}, {"preset": Preset.PAPER}, {"solver": "sa"}],  # grids, row chains, the host's settling
)
def test_a_level_whose_inference_reads_no_coarser_labels_gets_none(scene, settings):
    """Exact grids and row chains are solved from scratch and the residual design's tiles take
    the host's labels: their levels are prepared without the coarser level's labels."""
    config = MatchConfig(max_disparity=16, **settings)
    coarse = np.full((2 * 96 if config.lr_check else 96, 128), 2.0, dtype=np.float32)
    if config.preset is Preset.PAPER:
        coarse = np.full((24, 32), 3.0, dtype=np.float32)
    assert _level(scene, config, 1, coarse).initial_labels is None


def test_the_finest_level_refines_its_coarser_bin_by_one_disparity_either_side(scene):
    # bins of 4, 2, 1 px; the accurate preset's windows; QUBO rows warm-started
    config = MatchConfig(max_disparity=16, solver="sa", inference="rows")
    assert [plan.candidates for plan in plan_run(scene.left, scene.right, config)[1]] == [5, 6, 4]
    coarse = np.full((2 * 96, 128), 4.0, dtype=np.float32)  # bin 4 of width 2: 8..9 px
    inputs = _level(scene, config, 2, coarse)
    np.testing.assert_array_equal(inputs.candidate_labels()[0, 0], [7, 8, 9, 10])
    assert np.all(inputs.initial_labels == 1)  # 8 px, the lower child
    template = config.levels[0].model_copy(update={"finest_candidates": None})
    unset = MatchConfig(max_disparity=16, levels=[template])  # every finer level: candidates
    assert [plan.candidates for plan in plan_run(scene.left, scene.right, unset)[1]] == [5, 6, 6]


def test_assemble_refuses_missing_or_doubled_rows(scene):
    config = MatchConfig(max_disparity=16)
    inputs = _level(scene, config, 0)
    results = solve_bundles(inputs, config, [(0, 1), (1, 2)])
    with pytest.raises(ValueError, match="rows missing"):
        assemble(inputs, results)
    extra = BundleResult(0, 1, results[0].labels, 0.0, 0, 0.0)
    whole = solve_bundles(inputs, config, inputs.bundle_rows(1))
    with pytest.raises(ValueError, match="solved twice"):
        assemble(inputs, [*whole, extra])


def test_bundles_never_span_the_two_views(scene):
    config = MatchConfig(max_disparity=16, bundle_height=5, coarse_grid=1)  # 96 rows a view
    inputs = _level(scene, config, 0)
    rows = inputs.bundle_rows(5)
    assert all(stop <= 96 or start >= 96 for start, stop in rows)
    assert sum(stop - start for start, stop in rows) == 2 * 96


def test_bundle_results_do_not_depend_on_how_rows_are_grouped(scene):
    config = MatchConfig(max_disparity=16)
    inputs = _level(scene, config, 1)
    rows = inputs.bundle_rows(1)
    together = assemble(inputs, solve_bundles(inputs, config, rows))
    apart = assemble(
        inputs, [result for row in rows for result in solve_bundles(inputs, config, [row])]
    )
    np.testing.assert_array_equal(together.labels, apart.labels)
    assert together.energy == pytest.approx(apart.energy)


def test_single_level_configurations_work(scene):
    config = MatchConfig(
        max_disparity=16, preset=Preset.PAPER, levels=[LevelConfig(downsample=1, candidates=17)]
    )
    result = run_pipeline(scene.left, scene.right, config)
    assert len(result.levels) == 1 and result.disparity.shape == scene.left.shape


def test_invalid_configurations_are_refused():
    with pytest.raises(ValidationError, match="halve"):
        MatchConfig(
            preset=Preset.PAPER, levels=[LevelConfig(downsample=4), LevelConfig(downsample=1)]
        )
    with pytest.raises(ValidationError, match="bin pyramid"):
        MatchConfig(levels=[LevelConfig(downsample=2)])
    with pytest.raises(ValidationError, match="odd"):
        MatchConfig(median_size=4)
    with pytest.raises(ValidationError):
        MatchConfig(max_disparity=0)
    with pytest.raises(ValidationError):
        MatchConfig(max_disparity="wide")
    with pytest.raises(ValidationError, match="pyramid bins"):
        MatchConfig(preset=Preset.PAPER, subpixel=True)


def test_every_option_overrides_its_preset():
    config = MatchConfig(preset=Preset.PAPER, encoding="domain-wall", bilateral=False)
    assert config.encoding.value == "domain-wall" and not config.bilateral
    assert config.median_size == 7  # the rest still from the preset
    accurate = MatchConfig()
    assert accurate.preset is Preset.ACCURATE and accurate.encoding.value == "domain-wall"
    assert accurate.lr_check and accurate.weighted_median and not accurate.bilateral
    # a stored config reproduces its run: it holds concrete values, not the preset's name only
    assert MatchConfig(**accurate.model_dump()) == accurate


@pytest.mark.parametrize("preset", list(Preset))
def test_process_pool_gives_the_sequential_result(scene, preset):
    from shared.process_pool import ProcessPoolLevelSolver

    config = MatchConfig(
        max_disparity=16, preset=preset, solver="steepest-descent", encoding="domain-wall"
    )
    small = scene.left[:32, :48], scene.right[:32, :48]
    sequential = run_pipeline(*small, config)
    with ProcessPoolLevelSolver(2) as pool:
        parallel = run_pipeline(*small, config, pool)
    np.testing.assert_array_equal(sequential.disparity, parallel.disparity)
    assert [lv.energy for lv in sequential.levels] == [lv.energy for lv in parallel.levels]


def test_a_row_solver_never_starts_the_process_pool(scene):
    """The exact DP runs in this process: spawning idle children would only cost CPU."""
    from shared.process_pool import ProcessPoolLevelSolver

    config = MatchConfig(max_disparity=8, solver="exact")
    with ProcessPoolLevelSolver(2) as pool:
        run_pipeline(scene.left[:16, :24], scene.right[:16, :24], config, pool)
        assert pool._pool is None


def test_fast_median_equals_the_reference_median():
    from scipy import ndimage

    from shared.filters import median

    values = np.random.default_rng(0).integers(0, 60, (23, 31)).astype(np.float32)
    expected = ndimage.median_filter(values, size=7, mode="nearest")
    np.testing.assert_array_equal(median(values, 7), expected)
    fractional = values + 0.5
    np.testing.assert_array_equal(median(fractional, 7), expected + 0.5)


def _check_progress(events, result):
    """Per level, in order: bundles solved never go back and end at the level's bundles."""
    levels = len(result.levels)
    assert [event[0] for event in events] == sorted(event[0] for event in events)
    assert {event[0] for event in events} == set(range(1, levels + 1))
    for report in result.levels:
        mine = [event for event in events if event[0] == report.index + 1]
        assert all(event[1] == levels and event[3] == report.bundles for event in mine)
        done = [event[2] for event in mine]
        assert done == sorted(done) and done[0] == 0 and done[-1] == report.bundles
        assert len(done) > 3  # reported from inside the level, not only at its ends


@pytest.mark.parametrize("solver", ["steepest-descent", "exact"])
def test_progress_reports_bundles_from_inside_each_level(scene, solver):
    from shared.process_pool import ProcessPoolLevelSolver

    # every level on the full grid: the coarse one at half size leaves too few tiles to report
    config = MatchConfig(max_disparity=16, solver=solver, encoding="domain-wall", coarse_grid=1)
    small = scene.left[:32, :48], scene.right[:32, :48]
    events: list[tuple[int, int, int, int]] = []
    result = run_pipeline(*small, config, progress=lambda *event: events.append(event))
    _check_progress(events, result)  # exact: per block of rows, here one block per view
    if solver == "exact":  # vectorised: the pool leaves it in this process
        return
    pooled: list[tuple[int, int, int, int]] = []
    with ProcessPoolLevelSolver(2) as pool:
        again = run_pipeline(*small, config, pool, progress=lambda *event: pooled.append(event))
    _check_progress(pooled, again)


def test_the_paper_preset_warns_beyond_the_range_its_pyramid_serves(scene):
    from shared.pyramid import RangeWarning, served_range

    assert served_range(MatchConfig(preset=Preset.PAPER)) == 23
    assert served_range(MatchConfig()) is None  # the bin pyramid serves any range
    with warnings.catch_warnings():
        warnings.simplefilter("error", RangeWarning)
        plan_run(scene.left, scene.right, MatchConfig(preset=Preset.PAPER, max_disparity=20))
    with pytest.warns(RangeWarning, match="exceeds the 23 px the paper preset's image pyramid"):
        plan_run(scene.left, scene.right, MatchConfig(preset=Preset.PAPER, max_disparity=40))


def test_views_that_fail_the_check_stop_the_run_unless_forced(scene):
    from shared.disparity_range import ViewsRefusedError

    config = MatchConfig(max_disparity=16)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(ViewsRefusedError, match=r"swapped.*stopped before the run"):
            run_pipeline(scene.right, scene.left, config, force=False)
