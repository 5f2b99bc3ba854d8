"""The bin pyramid's coarse levels on a downsampled grid (``coarse_grid``): the levels' grids,
their pooled costs, the coarse labels handed to the finer windows, and the option off."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
from hypothesis import given
from hypothesis import settings as settings_
from hypothesis import strategies as st

from shared import pyramid
from shared.coarse_grid import pool, pooled_costs
from shared.config import MatchConfig
from shared.data_terms import bin_minimum
from shared.pipeline import fine_views, match_views, plan_run, prepare_level, run_pipeline
from shared.synthetic import make_scene


@given(width=st.sampled_from([1, 2, 4, 8, 16, 32, 64]), cap=st.integers(1, 16))
def test_a_levels_cells_stay_within_a_quarter_of_its_bin(width, cap):
    factor = pyramid.grid_factor(width, cap)
    assert 1 <= factor <= cap
    assert factor == 1 or 4 * factor <= width
    assert factor == min(cap, max(1, width // 4))


def test_the_plan_downsamples_the_coarse_levels_and_divides_their_smoothness():
    plain = pyramid.plan(MatchConfig(coarse_grid=1), 106)
    plans = pyramid.plan(MatchConfig(coarse_grid=4), 106)
    assert [p.bin_width for p in plans] == [16, 8, 4, 2, 1]
    assert [p.downsample for p in plans] == [4, 2, 1, 1, 1]
    for before, after in zip(plain, plans, strict=True):
        factor = after.downsample
        assert after.mrf.slope == pytest.approx(before.mrf.slope / factor)
        assert after.mrf.truncation == pytest.approx(before.mrf.truncation / factor)
        assert (after.candidates, after.max_label) == (before.candidates, before.max_label)
    assert plans[-3:] == plain[-3:]


@settings_(max_examples=30, deadline=None)
@given(
    bins=st.integers(1, 9),
    factor=st.sampled_from([2, 3, 4]),
    cells=st.tuples(st.integers(1, 5), st.integers(1, 5)),
    seed=st.integers(0, 2**16),
)
def test_pooling_averages_each_block_of_every_bin(bins, factor, cells, seed):
    height, width = cells
    costs = np.random.default_rng(seed).random((bins, height * factor, width * factor))
    pooled = pool(costs.astype(np.float32), (height, width))
    means = costs.reshape(bins, height, factor, width, factor).mean(axis=(2, 4))
    assert pooled.shape == (bins, height, width) and pooled.dtype == np.float32
    np.testing.assert_allclose(pooled, means, rtol=1e-5, atol=1e-6)


@settings_(max_examples=30, deadline=None)
@given(
    bins=st.integers(1, 23),
    ratio=st.integers(1, 8),
    factor=st.sampled_from([1, 2, 3]),
    seed=st.integers(0, 2**16),
)
def test_pooling_wider_bins_a_few_at_a_time_is_pooling_their_minima(bins, ratio, factor, seed):
    """:func:`pool` with a ratio (the cache's bins, the level's own never held whole) gives the
    floats of pooling :func:`bin_minimum` of the whole volume: chunks of
    :data:`POOL_PLANES` wider bins, a narrower last bin."""
    costs = np.random.default_rng(seed).random((bins, 3 * factor, 5 * factor), np.float32)
    expected = pool(bin_minimum(costs, ratio), (3, 5))
    np.testing.assert_array_equal(pool(costs, (3, 5), ratio), expected)


@pytest.fixture(scope="module")
def scene():
    return make_scene(40, 61, max_disparity=24, slanted=False, layers=1, seed=4)


def test_a_coarse_levels_grid_and_costs(scene):
    config = MatchConfig(max_disparity=40, coarse_grid=2)
    left, right = match_views(scene.left, scene.right, config)
    plans = plan_run(left, right, config)[1]
    assert [p.downsample for p in plans] == [2, 1, 1, 1]  # widths 8, 4, 2, 1
    level = prepare_level(left, right, config, plans[0])
    height, width = pyramid.level_shape(left.shape[:2], 2)
    assert level.shape == (2 * height, width) and level.views == 2
    assert level.pooled is not None and level.pooled.shape == (2, 6, height, width)
    grid = level.grid(config, 0, height)  # the exact solver's grid is the pooled costs'
    assert grid.unary.shape[:2] == (height, width)
    expected = pooled_costs(
        fine_views(left, right, config, plans[0]), plans[0], "census-gradient", (height, width)
    )
    np.testing.assert_array_equal(level.pooled, expected)


def test_the_pooled_costs_are_the_same_from_cached_volumes(scene):
    config = MatchConfig(max_disparity=40, coarse_grid=2)
    left, right = match_views(scene.left, scene.right, config)
    plans = plan_run(left, right, config)[1]
    fine = fine_views(left, right, config, plans[0])
    built = pooled_costs(fine, plans[0], config.data_term, (20, 30))
    full = fine.level_bin_costs(config.data_term)  # width 8 from the cached width-1 volumes
    fine.volumes = [
        np.repeat(v, 8, axis=0)[: plans[0].max_disparity + 1] for v in full
    ]  # every disparity of a bin at the bin's cost: its bins are the very values
    fine.volume_bin_width = 1
    np.testing.assert_array_equal(pooled_costs(fine, plans[0], config.data_term, (20, 30)), built)


def test_the_first_full_resolution_level_takes_the_runs_stacked_views(scene):
    """Below a coarse grid the first full-resolution level's images are the run's own stacked
    views (no second copy of them), the very values :func:`level_views` builds."""
    from shared.pipeline import level_views

    config = MatchConfig(max_disparity=40, coarse_grid=2)
    left, right = match_views(scene.left, scene.right, config)
    plans = plan_run(left, right, config)[1]
    fine = fine_views(left, right, config, plans[0])
    coarse = prepare_level(left, right, config, plans[0], fine=fine)
    assert coarse.plan.downsample > 1 and plans[1].downsample == 1
    coarse_map = np.zeros(coarse.shape, np.float32)
    finer = prepare_level(left, right, config, plans[1], coarse_map, coarse, fine)
    assert finer.left is fine.left and finer.right is fine.right and finer.views == fine.views
    built = level_views(left, right, config, plans[1])
    np.testing.assert_array_equal(finer.left, built[0])
    np.testing.assert_array_equal(finer.right, built[1])


def test_the_coarse_labels_centre_the_finer_windows_view_by_view(scene):
    config = MatchConfig(max_disparity=40, coarse_grid=2)
    left, right = match_views(scene.left, scene.right, config)
    plans = plan_run(left, right, config)[1]
    coarse = prepare_level(left, right, config, plans[0])
    rows, cols = coarse.shape
    rng = np.random.default_rng(0)
    coarse_map = rng.integers(0, plans[0].max_label + 1, (rows, cols)).astype(np.float32)
    finer = prepare_level(left, right, config, plans[1], coarse_map, coarse)
    height = left.shape[0]
    assert finer.shape == (2 * height, left.shape[1]) and finer.pooled is None
    view_rows = rows // 2
    for view in range(2):
        mine = finer.first[view * height : (view + 1) * height]
        source = coarse_map[view * view_rows : (view + 1) * view_rows]
        # every fine pixel's window holds both children of a coarse bin of its own view
        ys = np.minimum(np.arange(height) * view_rows // height, view_rows - 1)
        xs = np.minimum(np.arange(left.shape[1]) * cols // left.shape[1], cols - 1)
        children = 2 * source[np.ix_(ys, xs)].astype(np.int32)
        top = np.minimum(children + 1, plans[1].max_label)  # the last bin has one child
        assert ((mine <= children) & (top < mine + plans[1].candidates)).all()
    upsampled = pyramid.upsample_labels(coarse_map, 2, (height, left.shape[1]))
    assert set(np.unique(upsampled)) <= set(np.unique(coarse_map))


def test_the_views_do_not_mix_when_upsampled():
    stacked = np.concatenate([np.full((3, 4), 1.0), np.full((3, 4), 5.0)]).astype(np.float32)
    up = pyramid.upsample_labels(stacked, 2, (7, 9))
    assert up.shape == (14, 9) and (up[:7] == 1).all() and (up[7:] == 5).all()


def test_the_accurate_preset_runs_its_coarse_levels_at_up_to_a_quarter_the_paper_never():
    assert MatchConfig().coarse_grid == 4
    assert MatchConfig(preset="paper").coarse_grid == 1
    assert MatchConfig(coarse_grid=2).coarse_grid == 2
    paper = pyramid.plan(MatchConfig(preset="paper"), 20)
    assert [p.downsample for p in paper] == [4, 2, 1]  # its image pyramid, as it was


def _digest(disparity: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(disparity, np.float32).tobytes()).hexdigest()[:16]


def test_the_option_changes_nothing_where_no_bin_is_wider_than_two(scene):
    """Widths 4, 2 and 1 (a 24 px range) keep the full grid whatever the cap: the very map."""
    base = run_pipeline(scene.left, scene.right, MatchConfig(max_disparity=24, coarse_grid=1))
    capped = run_pipeline(scene.left, scene.right, MatchConfig(max_disparity=24, coarse_grid=8))
    assert [level.downsample for level in capped.levels] == [1, 1, 1]
    assert _digest(capped.disparity) == _digest(base.disparity)


def test_the_default_map_on_a_coarse_grid_is_pinned(scene):
    """The accurate preset's map where its coarse level runs at half size (40 px: widths 8, 4,
    2, 1), pinned when coarse_grid 4 became its default (every level on the full grid, as
    before: d228d16d961c7448); the older digests' scenes (ranges <= 8 px) keep every level
    full size."""
    result = run_pipeline(scene.left, scene.right, MatchConfig(max_disparity=40))
    assert [level.downsample for level in result.levels] == [2, 1, 1, 1]
    assert _digest(result.disparity) == "b4e13c445a466b11"
    full = run_pipeline(scene.left, scene.right, MatchConfig(max_disparity=40, coarse_grid=1))
    assert _digest(full.disparity) == "d228d16d961c7448"


@pytest.mark.parametrize("solver", ["exact", "sa", "steepest-descent"])
def test_every_solver_works_on_a_coarse_grid_and_reports_its_levels(scene, solver):
    config = MatchConfig(max_disparity=40, coarse_grid=2, solver=solver, seed=1)
    result = run_pipeline(scene.left, scene.right, config)
    coarse = result.levels[0]
    assert (coarse.downsample, coarse.height, coarse.width) == (2, 20, 30)
    assert result.disparity.shape == scene.left.shape[:2]
    for level in result.levels:
        assert np.isfinite(level.energy) and level.lower_bound is not None
        assert level.gap is not None and level.lower_bound <= level.energy + 1e-6
    nonocc = scene.disparity > 0
    bad = np.abs(result.disparity - scene.disparity)[nonocc] > 1
    assert bad.mean() < 0.15


def test_second_bins_on_a_coarse_grid_read_the_pooled_coarser_bins():
    from shared.hypotheses import with_second_bins

    scene = make_scene(40, 97, max_disparity=64, slanted=False, layers=2, seed=1)
    config = MatchConfig(max_disparity=64, second_bins=3, second_bins_radius=2)
    left, right = match_views(scene.left, scene.right, config)
    plans = plan_run(left, right, config)[1]
    assert [p.downsample for p in plans] == [4, 2, 1, 1, 1]  # widths 16, 8, 4, 2, 1
    coarse = prepare_level(left, right, config, plans[0])
    previous = np.full(coarse.shape, 2.0, dtype=np.float32)
    level = prepare_level(left, right, config, plans[1], previous, coarse)
    assert level.candidates.shape == (*level.shape, plans[1].candidates + 2)
    fine = fine_views(left, right, config, plans[1])
    wider = plans[1].model_copy(update={"bin_width": 16})
    pooled = list(pooled_costs(fine, wider, config.data_term, (level.view_height, level.shape[1])))
    window = level.candidates[:, :, :-2]
    plain = prepare_level(left, right, config.model_copy(update={"second_bins": 0}), plans[1],
                          previous, coarse)  # fmt: skip
    assert (window == plain.candidate_labels()).all()
    upsampled = pyramid.upsample_labels(previous, 2, (level.view_height, level.shape[1]))
    expected = with_second_bins(plain, upsampled, config.data_term, 2, pooled)
    np.testing.assert_array_equal(level.candidates, expected)
    own = with_second_bins(plain, upsampled, config.data_term, 2)  # the level's own views' bins
    assert not np.array_equal(own, expected)  # so the level did not build its own
