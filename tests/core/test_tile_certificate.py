"""The host settles a QUBO solver's level (``certify_tiles``, :mod:`shared.settle`): only the
4x4 tiles around the pixels whose row and column copies disagree are sent, and a tile's answer
replaces the host's labels only where it lowers the energy."""

from __future__ import annotations

import hashlib
import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from shared import settle
from shared.config import MatchConfig
from shared.grid import GridMRF, dual_decomposition
from shared.inference import (
    inference_for,
    level_bundles,
    settles,
    solve_bundles,
    solve_level_in_process,
)
from shared.level_inputs import LevelInputs
from shared.pipeline import run_pipeline
from shared.provenance_map import Stage
from shared.solvers.base import SolveResult
from shared.solvers.meters.qpu_time import charged_seconds
from shared.solvers.registry import get_solver
from shared.synthetic import make_scene

SMALL = {"height": 16, "width": 40, "max_disparity": 6}


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
    monkeypatch.setattr("shared.solvers.registry.get_solver", lambda name: counting)
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
        monkeypatch.setattr("shared.solvers.registry.get_solver", lambda name: WorstSolver())
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
    assert all(level.residual is None for level in result.levels)


def test_rows_inference_and_row_solvers_are_not_settled():
    assert settles(config())
    assert not settles(config(certify_tiles=False))
    assert not settles(config(inference="rows"))
    assert not settles(MatchConfig(solver="exact", max_disparity=6))


def small_grid(data, height: int, width: int, labels: int) -> GridMRF:
    """A random grid MRF whose costs are small integers (ties happen), candidates 0..K-1."""

    def values(*shape):
        flat = data.draw(st.lists(st.integers(0, 3), min_size=int(np.prod(shape)),
                                  max_size=int(np.prod(shape))))  # fmt: skip
        return np.array(flat, dtype=np.float32).reshape(shape)

    candidates = np.broadcast_to(np.arange(labels, dtype=np.int32), (height, width, labels))
    return GridMRF(
        unary=values(height, width, labels),
        candidates=np.ascontiguousarray(candidates),
        weight_h=values(height, width - 1),
        weight_v=values(height - 1, width),
        slope=1.0,
        truncation=2.0,
    )


@given(st.data())
@settings(max_examples=60, deadline=None)
def test_a_tiles_answer_is_kept_exactly_in_the_parts_that_lower_the_level_energy(data):
    grid = small_grid(data, 6, 6, 3)
    host = np.array(data.draw(st.lists(st.integers(0, 2), min_size=36, max_size=36)),
                    dtype=np.int32).reshape(6, 6)  # fmt: skip
    proposed = np.array(data.draw(st.lists(st.integers(0, 2), min_size=16, max_size=16)),
                        dtype=np.int32).reshape(4, 4)  # fmt: skip
    top, left = data.draw(st.integers(0, 2)), data.draw(st.integers(0, 2))
    rows, columns = slice(top, top + 4), slice(left, left + 4)
    labels = host.copy()
    stages = np.full(host.shape, int(Stage.HOST), dtype=np.uint8)
    stages[0, :] = Stage.CERTIFIED  # pinned pixels stay the host's, kept part or not
    before_stages = stages.copy()
    kept = settle._keep_improving(grid, labels, rows, columns, proposed, stages, Stage.SOLVER)
    assert kept == np.count_nonzero(labels != host)
    # provenance: exactly the changed, uncertified pixels are the solver's
    changed = labels != host
    assert np.all(stages[changed & (before_stages != Stage.CERTIFIED)] == Stage.SOLVER)
    assert np.array_equal(stages[~changed], before_stages[~changed])
    assert np.all(stages[before_stages == Stage.CERTIFIED] == Stage.CERTIFIED)
    outside = np.ones_like(host, dtype=bool)
    outside[rows, columns] = False
    assert np.array_equal(labels[outside], host[outside])  # only the tile's pixels change
    inside = labels[rows, columns]
    assert np.all((inside == host[rows, columns]) | (inside == proposed))
    # brute force over the subsets of the answer's 4-connected parts of change
    parts, count = ndimage.label(host[rows, columns] != proposed)
    best = grid.energy(host)
    for chosen in itertools.product([False, True], repeat=count):
        trial = host.copy()
        mask = np.isin(parts, [i + 1 for i, on in enumerate(chosen) if on])
        trial[rows, columns] = np.where(mask, proposed, host[rows, columns])
        best = min(best, grid.energy(trial))
    assert grid.energy(labels) == pytest.approx(best, abs=1e-6)
    assert grid.energy(labels) <= grid.energy(host)
    # no part kept at equal energy: undoing any kept part raises the energy
    kept_parts = np.unique(parts[labels[rows, columns] != host[rows, columns]])
    for part in kept_parts:
        undone = labels.copy()
        window = undone[rows, columns]
        window[parts == part] = host[rows, columns][parts == part]
        assert grid.energy(undone) > grid.energy(labels)
