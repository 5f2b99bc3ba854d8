"""The host settles a QUBO solver's level (``certify_tiles``, :mod:`shared.settle`): only the
4x4 tiles around the pixels whose row and column copies disagree are sent, and a tile's answer
replaces the host's labels only where it lowers the energy. A tile's own dual decomposition
(``QuboTiles.problems`` with ``certify_tiles``) certifies its exact optimum."""

from __future__ import annotations

import hashlib
import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared import settle
from shared.config import MatchConfig
from shared.energy import Costs, mrf_energy
from shared.grid import dual_decomposition
from shared.inference import inference_for, level_bundles, solve_bundles, solve_level_in_process
from shared.inference.qubo_tiles import QuboTiles
from shared.level_inputs import LevelInputs
from shared.pipeline import run_pipeline
from shared.solvers import get_solver
from shared.solvers.base import SolveResult
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
        # a tile's own certificate: the tiles of a settled level, each with certify_tiles
        tiles = QuboTiles(lambda: get_solver(cfg.solver), warm=False)
        for problem in tiles.problems(inputs, cfg, level_bundles(inputs, cfg)):
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


def test_only_tiles_around_unsettled_pixels_are_sent_and_charged(monkeypatch):
    cfg = config(encoding="one-hot", solver_params={"num_reads": 2})
    inputs = level_inputs(cfg)[-1]
    bundles = level_bundles(inputs, cfg)  # the host settles the level (shared.settle)
    counts = inputs.prepared["settle"]
    assert counts["certified"] + counts["unsettled"] == inputs.shape[0] * inputs.shape[1]
    assert 0 < len(bundles) == counts["tiles"] < settle.tiles_of(16, 40, 2)
    unsettled = np.zeros(inputs.shape, dtype=bool)
    height = inputs.view_height
    for view in range(inputs.views):  # the host's decomposition again: which pixels it left
        grid = inputs.grid(cfg, view * height, (view + 1) * height)
        outcome = dual_decomposition(grid, cfg.dual_iterations)
        unsettled[view * height : (view + 1) * height] = outcome.unsettled
    covered = np.zeros(inputs.shape, dtype=bool)
    for bundle in bundles:
        assert bundle.shape == (settle.TILE, settle.TILE)
        tile = (slice(bundle.row_start, bundle.row_stop), slice(bundle.col_start, bundle.col_stop))
        assert unsettled[tile].any()  # no tile without an unsettled pixel is sent
        covered[tile] = True
    assert covered[unsettled].all()  # every unsettled pixel is in a sent tile
    counting = CountingSolver()
    monkeypatch.setattr("shared.inference.table.get_solver", lambda name: counting)
    results = solve_bundles(inputs, cfg, bundles)
    assert counting.calls == len(bundles)
    assert all(charged_seconds(r.timing) == 0.0 for r in results)  # (unmetered here)
    solution = inference_for(cfg).assemble(inputs, results, cfg)
    assert solution.residual["tiles"] == len(bundles)
    assert solution.residual["pixels_sent"] == 16 * len(bundles)


class WorstSolver:
    """Every variable 1: an invalid encoding, repaired to poor labels."""

    def solve(self, bqm, **kwargs):
        sample = np.ones(bqm.num_variables, dtype=np.int8)
        return SolveResult(sample=sample, energy=bqm.energy(sample), wall_time=0.0)


@pytest.mark.parametrize("solver", ["worst", "sa"])
def test_a_tiles_answer_replaces_the_hosts_only_where_it_lowers_the_energy(monkeypatch, solver):
    cfg = config(encoding="domain-wall", solver_params={"num_reads": 4})
    inputs = level_inputs(cfg)[-1]
    bundles = level_bundles(inputs, cfg)
    host = inputs.initial_labels.copy()  # the host's labels (prepare put them there)
    height = inputs.view_height
    grids = [inputs.grid(cfg, v * height, (v + 1) * height) for v in range(inputs.views)]
    host_energy = sum(g.energy(host[v * height : (v + 1) * height]) for v, g in enumerate(grids))
    if solver == "worst":
        monkeypatch.setattr("shared.inference.table.get_solver", lambda name: WorstSolver())
    solution = inference_for(cfg).assemble(inputs, solve_bundles(inputs, cfg, bundles), cfg)
    energy = sum(
        g.energy(solution.labels[v * height : (v + 1) * height]) for v, g in enumerate(grids)
    )
    assert solution.energy == pytest.approx(energy)
    assert energy <= host_energy + 1e-9
    assert solution.lower_bound <= energy + 1e-6
    changed = int(np.count_nonzero(solution.labels != host))
    assert changed == solution.residual["pixels_improved"]
    if solution.residual["tiles_improved"]:
        assert energy < host_energy
    else:
        assert changed == 0 and energy == pytest.approx(host_energy)
    if solver == "worst":
        assert solution.residual["tiles_improved"] == 0


@given(st.data())
@settings(max_examples=40, deadline=None)
def test_the_tiles_sent_cover_every_unsettled_pixel_and_only_tiles_holding_one(data):
    height = data.draw(st.integers(1, 13))
    width = data.draw(st.integers(1, 13))
    flat = data.draw(st.lists(st.booleans(), min_size=height * width, max_size=height * width))
    unsettled = np.array(flat, dtype=bool).reshape(height, width)
    tiles = settle.unsettled_tiles(unsettled)
    covered = np.zeros_like(unsettled)
    for top, left in tiles:
        window = unsettled[top : top + settle.TILE, left : left + settle.TILE]
        assert window.shape == (min(4, height), min(4, width))  # whole tiles, in bounds
        assert window.any()
        covered[top : top + settle.TILE, left : left + settle.TILE] = True
    assert covered[unsettled].all()
    assert len(set(tiles)) == len(tiles)


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
    from shared.inference import settles

    assert settles(config())
    assert not settles(config(certify_tiles=False))
    assert not settles(config(inference="rows"))
    assert not settles(MatchConfig(solver="exact", max_disparity=6))
