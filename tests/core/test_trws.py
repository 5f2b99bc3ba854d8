"""TRW-S over the grid's row and column chains (``grid_inference=trws``)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.config import GridInference, MatchConfig
from shared.grid import dual_decomposition
from shared.grid_inference import trws
from shared.pipeline import run_pipeline
from shared.synthetic import make_scene
from tests.core.test_grid import brute_force, random_grid


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    shape=st.sampled_from([(1, 4), (2, 2), (2, 3), (3, 3)]),
    windows=st.booleans(),
)
def test_the_bound_holds_and_tiny_grids_reach_the_optimum(seed, shape, windows):
    mrf = random_grid(seed, *shape, labels=3, windows=windows)
    optimum = brute_force(mrf)
    result = trws(mrf, iterations=30)
    assert result.lower_bound <= optimum + 1e-5
    assert result.energy >= optimum - 1e-9
    assert result.energy == pytest.approx(mrf.energy(result.labels))
    # within 1 % of the optimum (exactly it on most: the bound certifies)
    assert result.energy <= optimum + 0.01 * abs(optimum)
    if result.disagreeing == 0:
        assert result.energy == pytest.approx(optimum, abs=1e-5)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**31), windows=st.booleans())
def test_its_bound_is_the_dual_decompositions_in_fewer_iterations(seed, windows):
    """Both ascend the dual of the same chain decomposition: TRW-S's bound is at least the
    subgradient's after 60 iterations (within 0.2 % of the energy), and never above either
    method's labelling; its energy within 1 % of the subgradient's."""
    mrf = random_grid(seed, 10, 14, labels=5, windows=windows)
    fast = trws(mrf, iterations=10)
    slow = dual_decomposition(mrf, iterations=60)
    assert fast.lower_bound <= slow.energy + 1e-6 and slow.lower_bound <= fast.energy + 1e-6
    assert fast.lower_bound >= slow.lower_bound - 2e-3 * abs(slow.energy)
    assert fast.energy <= slow.energy + 1e-2 * abs(slow.energy)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**31), tolerance=st.sampled_from([0.005, 0.02]))
def test_a_gap_tolerance_stops_only_with_its_certificate(seed, tolerance):
    mrf = random_grid(seed, 12, 16, labels=5)
    result = trws(mrf, iterations=30, gap=tolerance)
    if result.iterations < 30:
        assert result.gap <= tolerance


def test_the_level_reports_energy_bound_and_gap_and_the_map_matches_dual_decompositions():
    scene = make_scene(height=32, width=48, max_disparity=8, seed=1)
    maps = {}
    for method in GridInference:
        config = MatchConfig(max_disparity=8, grid_inference=method)
        result = run_pipeline(scene.left, scene.right, config)
        for level in result.levels:
            assert level.lower_bound is not None and level.gap is not None
            assert level.lower_bound <= level.energy + 1e-6
            assert 0 <= level.gap <= config.dual_gap + 1e-9
        maps[method] = result.disparity
    truth = scene.disparity
    errors = {m: float(np.abs(d - truth).mean()) for m, d in maps.items()}
    assert errors[GridInference.TRWS] < errors[GridInference.DD] + 0.1


@pytest.mark.parametrize(
    "given, expected", [([], GridInference.DD), (["trws"], GridInference.TRWS)]
)
def test_the_cli_option_sets_the_grid_inference_and_dd_stays_the_default(given, expected):
    from shared.cli import build_parser
    from shared.cli_options import config_from_args

    flag = ["--grid-inference", *given] if given else []
    args = build_parser().parse_args(["match", "l.png", "r.png", "-o", "d.pfm", *flag])
    assert config_from_args(args).grid_inference is expected
