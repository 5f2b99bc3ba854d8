"""The 2D grid MRF and its dual decomposition into row and column chains (``grid`` inference)."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import shared.level_inputs as level_inputs
from shared.config import Inference, LevelConfig, MatchConfig, Regularizer
from shared.encodings import get_codec
from shared.energy import mrf_costs, mrf_energy
from shared.grid import (
    GridMRF,
    _alternate_chains,
    boundary_unary,
    chain_primal,
    chain_sweeps,
    dual_decomposition,
    grid_mrf,
    solve_chains,
)
from shared.pipeline import plan_run, prepare_level, run_pipeline
from shared.synthetic import make_scene

LEVEL = LevelConfig(slope=0.2, truncation=0.4, edge_threshold=0.3, edge_factor=0.3)


def random_grid(seed: int, height: int, width: int, labels: int, windows: bool = True) -> GridMRF:
    """A random grid MRF: consecutive candidate windows (the bin pyramid) or arbitrary labels."""
    rng = np.random.default_rng(seed)
    unary = rng.random((height, width, labels)).astype(np.float32)
    if windows:
        first = rng.integers(0, 4, (height, width))
        candidates = first[:, :, None] + np.arange(labels)
    else:
        candidates = np.sort(rng.choice(12, (height, width, labels)), axis=2)
    guide = rng.random((height, width))
    return grid_mrf(unary, candidates, guide, LEVEL, Regularizer.TRUNCATED)


def brute_force(mrf: GridMRF) -> float:
    """The least energy of a tiny grid, by enumerating every labelling at once."""
    height, width, labels = mrf.unary.shape
    every = np.array(list(itertools.product(range(labels), repeat=height * width)))
    every = every.reshape(-1, height, width)
    rows, cols = np.ogrid[:height, :width]
    picked = mrf.candidates[rows, cols, every]
    energy = mrf.unary[rows, cols, every].astype(np.float64).sum(axis=(1, 2))
    energy += (mrf.weight_h * mrf.pair_cost(picked[:, :, :-1], picked[:, :, 1:])).sum(axis=(1, 2))
    energy += (mrf.weight_v * mrf.pair_cost(picked[:, :-1], picked[:, 1:])).sum(axis=(1, 2))
    return float(energy.min())


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31), shape=st.sampled_from([(2, 2), (2, 3), (3, 3)]))
def test_the_bound_never_exceeds_any_labelling_and_is_the_optimum_when_chains_agree(seed, shape):
    mrf = random_grid(seed, *shape, labels=3)
    optimum = brute_force(mrf)
    result = dual_decomposition(mrf, iterations=60)
    assert result.lower_bound <= optimum + 1e-4
    assert result.energy >= optimum - 1e-9
    assert result.energy == pytest.approx(mrf.energy(result.labels))
    if result.disagreeing == 0:
        assert result.energy == pytest.approx(optimum, abs=1e-6)


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    shape=st.sampled_from([(1, 1), (1, 6), (5, 1), (7, 9), (12, 16)]),
    labels=st.integers(1, 5),
    windows=st.booleans(),
    gap=st.sampled_from([0.0, 0.01]),
)
def test_a_spare_cores_column_chains_give_the_same_decomposition(seed, shape, labels, windows, gap):
    """With a core to spare the column chains and their energy run on a helper thread: every
    labelling, energy, bound and iteration count as on one thread."""
    import shared.grid as grid_module

    mrf = random_grid(seed, *shape, labels=labels, windows=windows)
    outcomes = {}
    for spare in (False, True):
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(grid_module, "spare_core", lambda spare=spare: spare)
            outcomes[spare] = dual_decomposition(mrf, iterations=25, gap=gap)
    alone, helped = outcomes[False], outcomes[True]
    np.testing.assert_array_equal(helped.labels, alone.labels)
    np.testing.assert_array_equal(helped.unsettled, alone.unsettled)
    assert (helped.energy, helped.lower_bound, helped.iterations, helped.disagreeing) == (
        alone.energy, alone.lower_bound, alone.iterations, alone.disagreeing,
    )  # fmt: skip


def test_the_last_view_running_lends_its_decomposition_the_other_core(monkeypatch):
    """Each view's grid holds a core while it is minimised; a grid alone (the views one at a
    time) finds the other core spare at every iteration; the map is the same either way."""
    import shared.grid as grid_module
    import shared.inference.grid_views as solve
    import shared.threads as threads_module

    held: list[int] = []
    spare_core = threads_module.spare_core
    monkeypatch.setattr(threads_module, "_budget", 2)
    monkeypatch.setattr(
        grid_module, "spare_core", lambda: held.append(threads_module._held) or spare_core()
    )
    scene = make_scene(24, 40, max_disparity=8, seed=2)
    config = MatchConfig(max_disparity=8)
    monkeypatch.setattr(solve, "GRID_STATE_BYTES", 0)  # one grid at a time
    alone = run_pipeline(scene.left, scene.right, config).disparity
    assert held and set(held) == {1}
    held.clear()
    monkeypatch.setattr(solve, "GRID_STATE_BYTES", 2**40)  # side by side
    np.testing.assert_array_equal(run_pipeline(scene.left, scene.right, config).disparity, alone)
    assert held and set(held) <= {1, 2}


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**31), tolerance=st.sampled_from([0.005, 0.02, 0.1]))
def test_a_gap_tolerance_stops_early_only_with_its_certificate(seed, tolerance):
    """Stopping at a gap is sound: the labelling returned is certified within it of the
    optimum (the bound holds), and otherwise every iteration ran or the chains agreed."""
    mrf = random_grid(seed, 12, 16, labels=5)
    full = dual_decomposition(mrf, iterations=30)
    early = dual_decomposition(mrf, iterations=30, gap=tolerance)
    assert early.iterations <= full.iterations
    assert early.lower_bound <= full.energy + 1e-6 and full.lower_bound <= early.energy + 1e-6
    if early.iterations < 30 and early.disagreeing:
        assert early.gap <= tolerance
    else:
        assert early.iterations == full.iterations and early.energy == full.energy


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31), windows=st.booleans(), length=st.integers(1, 6))
def test_a_column_chain_is_the_row_kernel_on_transposed_costs_and_the_optimum(
    seed, windows, length
):
    mrf = random_grid(seed, length, 1, labels=3, windows=windows)  # one column
    labels, energies = solve_chains(mrf, along_columns=True)
    as_row_labels, as_row_energies = solve_chains(mrf.transposed())
    optimum = brute_force(mrf)
    assert energies[0] == pytest.approx(optimum)
    assert as_row_energies[0] == pytest.approx(optimum)
    assert mrf.energy(labels) == pytest.approx(optimum)
    assert mrf.energy(np.ascontiguousarray(as_row_labels.T)) == pytest.approx(optimum)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31), along_columns=st.booleans())
def test_the_window_kernel_finds_the_optima_of_the_general_one(seed, along_columns):
    mrf = random_grid(seed, 5, 9, labels=4)
    assert mrf.first is not None  # consecutive windows: the O(K) distance transform
    general = replace(mrf, first=None)
    labels, energies = solve_chains(mrf, along_columns)
    expected_labels, expected = solve_chains(general, along_columns)
    np.testing.assert_allclose(energies, expected)
    assert mrf.energy(labels) == pytest.approx(general.energy(expected_labels))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31), windows=st.booleans(), vertical=st.booleans())
def test_neighbour_costs_written_into_a_used_buffer_are_a_fresh_arrays(seed, windows, vertical):
    """The dual decomposition's primal steps share one buffer: every element is rewritten, so
    what an earlier step left there (NaN here) never leaks into the next step's labels."""
    mrf = random_grid(seed, 4, 6, labels=3, windows=windows)
    labels = np.random.default_rng(seed).integers(0, 3, (4, 6)).astype(np.int32)
    used = np.full(mrf.unary.shape, np.nan, dtype=np.float32)
    written = mrf.neighbour_unary(labels, vertical, out=used)
    assert written is used
    assert np.array_equal(written, mrf.neighbour_unary(labels, vertical))
    turned = mrf.transposed(candidates=False)
    scratch = np.full(mrf.unary.size, np.nan, dtype=np.float32)
    assert np.array_equal(
        chain_primal(mrf, turned, labels, scratch), chain_primal(mrf, turned, labels)
    )


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31), windows=st.booleans(), row=st.sampled_from([1, 3]))
def test_a_half_sweep_sets_rows_to_their_best_labels_given_the_rows_around_them(seed, windows, row):
    """The odd rows share no edge, so their chains given the even rows are the exact minimum
    of E over them: after the sweep's row pass (even rows, then odd), no labelling of an odd
    row, the rest fixed, does better."""
    mrf = random_grid(seed, 5, 3, labels=3, windows=windows)
    start = np.random.default_rng(seed).integers(0, 3, (5, 3)).astype(np.int32)
    after = _alternate_chains(mrf, start.copy())
    energy = mrf.energy(after)
    for choice in itertools.product(range(3), repeat=3):
        other = after.copy()
        other[row] = choice
        assert energy <= mrf.energy(other) + 1e-6


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31), windows=st.booleans())
def test_chain_sweeps_never_raise_the_energy_and_reach_the_optimum_of_a_chain(seed, windows):
    mrf = random_grid(seed, 6, 7, labels=4, windows=windows)
    turned = mrf.transposed()
    labels = np.random.default_rng(seed).integers(0, 4, (6, 7)).astype(np.int32)
    energies = [mrf.energy(labels)]
    for _ in range(3):
        labels = chain_sweeps(mrf, turned, labels)
        energies.append(mrf.energy(labels))
    assert all(b <= a + 1e-6 for a, b in itertools.pairwise(energies))
    assert np.array_equal(chain_sweeps(mrf, turned, labels, sweeps=0), labels)
    row = random_grid(seed, 1, 5, labels=3, windows=windows)  # one chain: one sweep is exact
    swept = chain_sweeps(row, row.transposed(), np.zeros((1, 5), np.int32))
    assert row.energy(swept) == pytest.approx(brute_force(row))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31))
def test_the_compact_energy_is_the_cost_arrays_energy(seed):
    rng = np.random.default_rng(seed)
    mrf = random_grid(seed, 4, 5, labels=3, windows=False)
    guide = rng.random((4, 5))
    mrf = grid_mrf(mrf.unary, mrf.candidates, guide, LEVEL, Regularizer.TRUNCATED)
    costs = mrf_costs(
        mrf.unary.astype(np.float64), mrf.candidates, guide, LEVEL, Regularizer.TRUNCATED
    )
    labels = rng.integers(0, 3, (4, 5)).astype(np.int32)
    assert mrf.energy(labels) == pytest.approx(mrf_energy(costs, labels))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), encoding=st.sampled_from(["one-hot", "domain-wall"]))
def test_a_tile_bqm_is_the_grid_energy_restricted_to_the_tile_plus_its_boundary(seed, encoding):
    rng = np.random.default_rng(seed)
    guide = rng.random((5, 7))
    mrf = random_grid(seed, 5, 7, labels=3)
    mrf = grid_mrf(mrf.unary, mrf.candidates, guide, LEVEL, Regularizer.TRUNCATED)
    labels = rng.integers(0, 3, (5, 7)).astype(np.int32)
    rows, columns = slice(1, 3), slice(2, 6)
    tile = mrf_costs(
        mrf.unary[rows, columns].astype(np.float64),
        mrf.candidates[rows, columns],
        guide[rows, columns],
        LEVEL,
        Regularizer.TRUNCATED,
    )
    boundary = boundary_unary(mrf, labels, rows, columns)
    codec = get_codec(encoding)
    tile = replace(tile, unary=tile.unary + boundary)
    bqm = codec.encode(tile, "local")
    inside = labels[rows, columns]
    sample = codec.encode_labels(inside, 3)
    # the whole grid's energy changes with the tile's labels exactly as the tile BQM's does
    other = labels.copy()
    other[rows, columns] = rng.integers(0, 3, inside.shape)
    other_sample = codec.encode_labels(other[rows, columns], 3)
    grid_change = mrf.energy(other) - mrf.energy(labels)
    bqm_change = bqm.energy(other_sample) - bqm.energy(sample)
    assert bqm_change == pytest.approx(grid_change, abs=1e-6)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31), shape=st.sampled_from([(1, 5), (4, 1), (6, 7), (9, 12)]))
def test_a_window_grid_without_its_candidates_is_the_same_grid(seed, shape):
    """A window grid need not keep its (h, w, K) candidates (they are ``first`` + 0..K-1): its
    energy, labels, tiles, boundary costs and dual decomposition are those of the grid that
    keeps them."""
    kept = random_grid(seed, *shape, labels=3)
    assert kept.first is not None and kept.candidates is not None
    bare = replace(kept, candidates=None)
    rng = np.random.default_rng(seed)
    labels = rng.integers(0, 3, shape).astype(np.int32)
    assert bare.energy(labels) == kept.energy(labels)
    np.testing.assert_array_equal(bare.picked(labels), kept.picked(labels))
    np.testing.assert_array_equal(bare.candidate_labels(), kept.candidates)
    rows, columns = slice(0, max(1, shape[0] // 2)), slice(min(1, shape[1] - 1), shape[1])
    np.testing.assert_array_equal(
        boundary_unary(bare, labels, rows, columns), boundary_unary(kept, labels, rows, columns)
    )
    np.testing.assert_array_equal(
        bare.tile(rows, columns).candidate_labels(), kept.tile(rows, columns).candidates
    )
    np.testing.assert_array_equal(chain_sweeps(bare, bare.transposed(), labels),
                                  chain_sweeps(kept, kept.transposed(), labels))  # fmt: skip
    plain, compact = dual_decomposition(kept, 10), dual_decomposition(bare, 10)
    np.testing.assert_array_equal(compact.labels, plain.labels)
    assert (compact.energy, compact.lower_bound) == (plain.energy, plain.lower_bound)


def test_a_grid_or_level_needs_its_candidates_or_their_windows():
    kept = random_grid(0, 3, 4, labels=2, windows=False)
    assert kept.first is None
    with pytest.raises(ValueError, match="first"):
        replace(kept, candidates=None)
    scene = make_scene(20, 32, max_disparity=6, seed=3)
    config = MatchConfig(max_disparity=6)
    _, plans = plan_run(scene.left, scene.right, config)
    inputs = prepare_level(scene.left, scene.right, config, plans[0])
    assert inputs.candidates is None and inputs.first is not None  # the coarsest window
    with pytest.raises(ValueError, match="first"):
        replace(inputs, first=None)


def textureless_band_scene():
    """A slanted plane whose middle rows carry no texture in either view: a row alone cannot
    tell their disparity; the rows above and below can, through the vertical edges."""
    scene = make_scene(height=48, width=64, max_disparity=12, layers=0, seed=3)
    left, right = scene.left.copy(), scene.right.copy()
    band = slice(16, 32)
    left[band], right[band] = 0.5, 0.5
    return left, right, scene.disparity, band


def test_the_grid_recovers_a_textureless_band_that_rows_alone_miss():
    left, right, truth, band = textureless_band_scene()
    inner = (slice(band.start + 4, band.stop - 4), slice(16, 64))
    errors = {}
    for inference in Inference:
        config = MatchConfig(max_disparity=12, inference=inference)
        disparity = run_pipeline(left, right, config).disparity
        errors[inference] = float(np.abs(disparity[inner] - truth[inner]).mean())
    assert errors[Inference.GRID] < 1.0
    assert errors[Inference.ROWS] > 2 * errors[Inference.GRID]


def test_exact_grid_levels_report_energy_bound_and_gap():
    scene = make_scene(height=32, width=48, max_disparity=8, seed=1)
    result = run_pipeline(scene.left, scene.right, MatchConfig(max_disparity=8))
    for level in result.levels:
        assert level.lower_bound is not None and level.gap is not None
        assert level.lower_bound <= level.energy + 1e-6
        assert 0 <= level.gap < 0.05
        assert level.bundles == 2  # one grid per view


@pytest.mark.parametrize("block_bytes", [1, 2700, 4000])  # 2700: a shorter last block
def test_a_views_grid_costs_built_in_blocks_of_rows_equal_the_whole_volumes(
    monkeypatch, block_bytes
):
    """Without a cached volume a grid's unary is built a few rows at a time (memory bounded by
    the block, not the view): the very values of the whole view's volume."""
    scene = make_scene(20, 32, max_disparity=6, seed=3)
    config = MatchConfig(max_disparity=6)
    _, plans = plan_run(scene.left, scene.right, config)
    inputs = prepare_level(scene.left, scene.right, config, plans[-1])
    assert inputs.volumes is None
    for view in range(inputs.views):
        rows = (view * inputs.view_height, (view + 1) * inputs.view_height)
        monkeypatch.setattr(level_inputs, "VOLUME_BLOCK_BYTES", 2**40)  # one block: the view
        whole = inputs.grid(config, *rows).unary
        monkeypatch.setattr(level_inputs, "VOLUME_BLOCK_BYTES", block_bytes)
        np.testing.assert_array_equal(inputs.grid(config, *rows).unary, whole)


def test_views_whose_dual_state_exceeds_the_budget_are_minimised_one_after_the_other(
    monkeypatch,
):
    """Large levels run their views' grids one at a time (memory: 2000 x 2000 within 2 GiB);
    each grid is minimised on its own, so the map is the same either way."""
    import shared.inference.grid_views as solve

    scene = make_scene(24, 40, max_disparity=8, seed=2)
    config = MatchConfig(max_disparity=8)
    _, plans = plan_run(scene.left, scene.right, config)
    inputs = prepare_level(scene.left, scene.right, config, plans[-1])
    views = [(v * inputs.view_height, (v + 1) * inputs.view_height) for v in range(2)]
    monkeypatch.setattr(solve, "threads", lambda: 2)
    assert solve.grids_at_once(inputs, views) == 2
    one_grid = 4 * solve.GRID_STATE_ARRAYS * inputs.view_height * inputs.shape[1] * inputs.count
    monkeypatch.setattr(solve, "GRID_STATE_BYTES", 2 * one_grid - 1)
    assert solve.grids_at_once(inputs, views) == 1
    monkeypatch.setattr(solve, "GRID_STATE_BYTES", 0)
    assert solve.grids_at_once(inputs, views) == 1  # at least one, however small the budget
    sequential = run_pipeline(scene.left, scene.right, config).disparity
    monkeypatch.setattr(solve, "GRID_STATE_BYTES", 2**40)
    side_by_side = run_pipeline(scene.left, scene.right, config).disparity
    np.testing.assert_array_equal(sequential, side_by_side)
