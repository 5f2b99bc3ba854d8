"""Grid tiles certified on the host (``certify_tiles``): a QUBO solver's tile whose dual
decomposition agrees is the tile's exact optimum, solved on the host, never sent and charged
nothing; the others are sent and keep the better of the two labellings."""

from __future__ import annotations

import hashlib
import itertools

import numpy as np
import pytest

from shared.bundle_plan import level_bundles
from shared.config import MatchConfig
from shared.energy import Costs, mrf_energy
from shared.level_inputs import LevelInputs
from shared.pipeline import run_pipeline
from shared.solve import encoded_bundles, solve_bundles, solve_level_in_process
from shared.solvers import get_solver
from shared.solvers.qpu_time import charged_seconds
from shared.synthetic import make_scene

SMALL = {"height": 16, "width": 40, "max_disparity": 6}


def tile_optimum(costs: Costs) -> float:
    """The least MRF energy of a tile by brute force over its columns' labellings: a dynamic
    programme whose state is a whole column (K^h states), independent of dual decomposition."""
    height, width, labels = costs.unary.shape
    states = np.array(list(itertools.product(range(labels), repeat=height)))  # (S, h)
    rows = np.arange(height)

    def column_cost(x: int) -> np.ndarray:
        cost = costs.unary[rows, x][rows, states].sum(axis=1)
        for r in range(height - 1):
            cost += costs.pair_v[r, x][states[:, r], states[:, r + 1]]
        return cost

    best = column_cost(0)
    for x in range(1, width):
        step = sum(
            costs.pair_h[r, x - 1][states[:, r][:, None], states[:, r][None, :]]
            for r in range(height)
        )
        best = (best[:, None] + step).min(axis=0) + column_cost(x)
    return float(best.min())


def level_inputs(config: MatchConfig) -> list[LevelInputs]:
    """Every level's inputs of a small scene (each with the coarser estimate it starts from)."""
    pair = make_scene(SMALL["height"], SMALL["width"], max_disparity=SMALL["max_disparity"], seed=5)
    levels: list[LevelInputs] = []

    def solve_level(inputs, cfg):
        levels.append(inputs)
        return solve_level_in_process(inputs, cfg)

    run_pipeline(pair.left, pair.right, config, solve_level)
    return levels


def config(**options) -> MatchConfig:
    return MatchConfig(solver="sa", max_disparity=SMALL["max_disparity"], seed=7, **options)


def test_a_certified_tile_is_the_tiles_exact_optimum():
    cfg = config(encoding="domain-wall")
    certified = uncertified = 0
    for inputs in level_inputs(cfg):
        for problem in encoded_bundles(inputs, cfg, level_bundles(inputs, cfg)):
            assert problem.dual is not None
            optimum = tile_optimum(problem.costs)
            found = mrf_energy(problem.costs, problem.dual.labels)
            if problem.bqm is None:  # certified: nothing is built for the solver
                certified += 1
                assert found == pytest.approx(optimum, rel=1e-6, abs=1e-6)
            else:
                uncertified += 1
                assert found >= optimum - 1e-6
    assert certified > 0 and uncertified > 0  # the scene exercises both paths


class CountingSolver:
    """Steepest descent that counts the bundles it was given."""

    def __init__(self):
        self.inner = get_solver("steepest-descent")
        self.calls = 0

    def solve(self, bqm, **kwargs):
        self.calls += 1
        return self.inner.solve(bqm, **kwargs)


def test_a_certified_tile_is_not_sent_and_is_charged_nothing(monkeypatch):
    cfg = config(encoding="one-hot", solver_params={"num_reads": 2})
    inputs = level_inputs(cfg)[-1]
    bundles = level_bundles(inputs, cfg)
    counting = CountingSolver()
    monkeypatch.setattr("shared.solve.get_solver", lambda name: counting)
    results = solve_bundles(inputs, cfg, bundles)
    certified = [r for r in results if r.info["certified"]]
    assert 0 < len(certified) < len(results)
    assert counting.calls == len(results) - len(certified)
    for result in certified:
        assert result.timing == {} and charged_seconds(result.timing) == 0.0
        assert result.info["residual_variables"] == 0 and result.info["variables"] > 0
    for result in results:
        assert result.info["certified"] or result.info["kept"] in ("host", "solver")
    summary = solve_level_in_process(inputs, cfg).info  # the level's report counts them
    assert summary["bundles_certified"] == len(certified)
    assert summary["bundles_sent"] == len(results) - len(certified)
    assert summary["variables_sent"] < summary["variables"]


def test_a_sent_tile_keeps_the_better_of_the_solvers_and_the_hosts_labels():
    cfg = config(encoding="domain-wall", solver_params={"num_reads": 1, "num_sweeps": 1})
    inputs = level_inputs(cfg)[-1]
    bundles = level_bundles(inputs, cfg)
    problems = {p.bundle: p for p in encoded_bundles(inputs, cfg, bundles)}
    for result in solve_bundles(inputs, cfg, bundles):
        problem = next(p for b, p in problems.items() if b.row_start == result.row_start)
        assert result.energy == pytest.approx(mrf_energy(problem.costs, result.labels))
        assert result.energy <= mrf_energy(problem.costs, problem.dual.labels) + 1e-9


@pytest.mark.parametrize(
    ("solver", "options", "before"),
    [
        ("sa", {"encoding": "domain-wall"}, "57245b50c00eafd5"),
        (
            "steepest-descent",
            {"encoding": "one-hot", "bundle_width": 16, "bundle_margin": 4},
            "42507954d13782c8",
        ),
    ],
)
def test_turning_it_off_gives_the_tiles_of_before(solver, options, before):
    pair = make_scene(SMALL["height"], SMALL["width"], max_disparity=SMALL["max_disparity"], seed=5)
    off = MatchConfig(
        solver=solver, max_disparity=SMALL["max_disparity"], seed=7, certify_tiles=False, **options
    )
    result = run_pipeline(pair.left, pair.right, off)
    digest = hashlib.sha256(np.ascontiguousarray(result.disparity, np.float32).tobytes())
    # the GRID_CASES digests of tests/solvers/test_same_disparities.py before certify_tiles
    assert digest.hexdigest()[:16] == before
    assert all("bundles_certified" not in level.info for level in result.levels)


def test_rows_inference_and_row_solvers_are_not_certified():
    from shared.solve import certifies_tiles

    assert certifies_tiles(config())
    assert not certifies_tiles(config(certify_tiles=False))
    assert not certifies_tiles(config(inference="rows"))
    assert not certifies_tiles(MatchConfig(solver="exact", max_disparity=6))
