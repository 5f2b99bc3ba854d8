"""Level inference as a strategy (``shared.inference``): the one table chooses each strategy from
the configuration and the solver's facts, and each strategy gives the very results the
if/isinstance dispatch it replaced gave (digests of tiny runs taken before the change)."""

from __future__ import annotations

import hashlib
import itertools

import numpy as np
import pytest

from shared.assembly import BundleResult
from shared.config import Inference, MatchConfig
from shared.inference import Termination, inference_for, settles, solve_level_in_process
from shared.inference.grid_views import GridViews, termination
from shared.inference.qubo_residual import ResidualTiles
from shared.inference.qubo_rows import QuboRows
from shared.inference.qubo_tiles import QuboTiles
from shared.inference.row_chains import RowChains
from shared.inference.table import ANY, TABLE
from shared.pipeline import run_pipeline
from shared.solvers.registry import get_solver
from shared.synthetic import make_scene

#: Each strategy's run on a tiny pair, and its digest (disparity, each level's energy, bound,
#: bundles, repairs) as the if/isinstance dispatch (since folded into the strategies) gave it
#: before them (main at e0e56e6; re-pinned with energies to 6 digits from 2d260cd, the commit that
#: checked them against e0e56e6, whose code gives the same digests as today's; re-pinned for
#: issue 27's unconfirmed right edge, with which set to 0 columns they are the ones before).
CASES = {
    "grid-dd": ({"solver": "exact", "inference": "grid"}, GridViews, "a2428fcd50f1d74c"),
    "grid-trws": (
        {"solver": "exact", "inference": "grid", "grid_inference": "trws"},
        GridViews,
        "d0ffe02eb34319eb",
    ),
    "row-chains": ({"solver": "exact", "inference": "rows"}, RowChains, "793a0b787e8abb50"),
    "qubo-rows": (
        {"solver": "steepest-descent", "inference": "rows", "bundle_width": 16, "bundle_margin": 4},
        QuboRows,
        "b9ff8c4c46d0553b",
    ),
    "qubo-tiles": (
        {
            "solver": "sa",
            "inference": "grid",
            "certify_tiles": False,
            "solver_params": {"num_reads": 2},
        },
        QuboTiles,
        "f70489973e28966d",
    ),
    "qubo-residual": (
        {"solver": "sa", "inference": "grid", "solver_params": {"num_reads": 2}},
        ResidualTiles,
        "de115474fece605a",
    ),
}


def config(options: dict) -> MatchConfig:
    return MatchConfig(max_disparity=5, seed=11, **options)


def pair():
    return make_scene(12, 32, max_disparity=5, seed=3)


def digest(options: dict, solve_level=solve_level_in_process) -> str:
    scene = pair()
    result = run_pipeline(scene.left, scene.right, config(options), solve_level)
    found = hashlib.sha256(np.ascontiguousarray(result.disparity, np.float32).tobytes())
    for level in result.levels:
        found.update(
            repr(
                (rounded(level.energy), rounded(level.lower_bound), level.bundles, level.repaired)
            ).encode()
        )
    return found.hexdigest()[:16]


def rounded(value: float | None) -> str | None:
    """Energies to 6 significant digits: OpenCV's SIMD paths (which differ between CPUs) move
    the costs in the 8th digit without changing a label; the disparity is hashed exactly."""
    return None if value is None else f"{value:.6g}"


@pytest.mark.parametrize("name", list(CASES))
def test_the_table_chooses_the_strategy(name):
    options, kind, _ = CASES[name]
    inference = inference_for(config(options))
    assert type(inference) is kind
    assert inference.name == name
    assert settles(config(options)) == (kind is ResidualTiles)


@pytest.mark.parametrize("name", list(CASES))
def test_each_strategy_gives_the_results_of_before(name):
    options, _, before = CASES[name]
    assert digest(options) == before


def test_every_configuration_matches_exactly_one_row():
    for key in itertools.product(Inference, (True, False), (True, False)):
        matches = [
            row
            for row in TABLE
            if all(p is ANY or p == k for p, k in zip(row.key, key, strict=True))
        ]
        assert len(matches) == 1, key


def test_solver_facts_steer_planning_and_splitting():
    grid = inference_for(config({"solver": "exact"}))
    assert not grid.plans_with_solver and not grid.splits  # vectorised in this process
    rows = inference_for(config({"solver": "sa", "inference": "rows"}))
    assert not rows.plans_with_solver and rows.splits
    qpu = inference_for(config({"solver": "qpu-sim", "inference": "rows"}))
    assert qpu.plans_with_solver  # embeds on its QPU graph: planned where the solver is
    assert qpu.width_setting(config({"solver": "qpu-sim"})) == "auto"
    hybrid = inference_for(config({"solver": "hybrid-sim", "inference": "rows"}))
    assert not hybrid.splits  # one problem a level: split, it would be billed per part
    segments = config({"solver": "exact", "bundle_width": 32, "bundle_margin": 4})
    with pytest.raises(ValueError, match="whole rows"):
        inference_for(segments).width_setting(segments)


class Batched:
    """Steepest descent behind ``solve_batch``: the bundles of a call in one problem."""

    def __init__(self):
        self.inner = get_solver("steepest-descent")
        self.calls = 0

    def solve(self, bqm, **kwargs):  # pragma: no cover - a batch solver is given batches
        raise AssertionError("a batch solver's bundles go through solve_batch")

    def solve_batch(self, problems, **params):
        self.calls += 1
        return [
            self.inner.solve(bqm, seed=seed, initial_state=initial, **params)
            for bqm, seed, initial in problems
        ]


def test_a_batch_solver_gets_a_levels_bundles_in_one_call_with_the_same_results(monkeypatch):
    batched = Batched()
    monkeypatch.setattr("shared.solvers.registry.get_solver", lambda name: batched)
    options, _, before = CASES["qubo-rows"]
    assert digest(options) == before
    assert batched.calls == len(run_levels(options))


def run_levels(options: dict) -> list:
    scene = pair()
    return run_pipeline(scene.left, scene.right, config(options)).levels


@pytest.mark.parametrize("name", list(CASES))
def test_a_level_solved_in_shares_is_the_level_solved_at_once(name):
    """The service's way: planned once, bundles solved in tasks (any share, any process),
    assembled from all results; the same level as in process."""
    options, _, before = CASES[name]

    def in_shares(inputs, cfg):
        inference = inference_for(cfg)
        bundles = inference.plan(inputs, cfg)
        assert inference.planned(inputs, cfg) == bundles
        half = len(bundles) // 2
        results = [
            *inference.solve(inputs, cfg, bundles[half:]),
            *inference.solve(inputs, cfg, bundles[:half]),
        ]
        return inference.assemble(inputs, results, cfg)

    assert digest(options, in_shares) == before


def test_each_level_says_why_it_stopped():
    levels = {name: run_levels(CASES[name][0]) for name in ("grid-dd", "row-chains", "qubo-tiles")}
    grid_reasons = {Termination.OPTIMAL, Termination.GAP, Termination.ITERATIONS}
    assert all(level.termination in grid_reasons for level in levels["grid-dd"])
    assert all(level.termination == Termination.OPTIMAL for level in levels["row-chains"])
    assert all(level.termination == Termination.SAMPLED for level in levels["qubo-tiles"])
    cut = run_levels({**CASES["grid-dd"][0], "dual_iterations": 1, "dual_gap": 0.0})
    assert any(level.termination == Termination.ITERATIONS for level in cut)
    residual = run_levels(CASES["qubo-residual"][0])
    for level in residual:
        sent = level.residual["tiles"]
        assert level.termination == (Termination.SAMPLED if sent else Termination.SETTLED)


def result(disagreeing: int, iterations: int) -> BundleResult:
    labels = np.zeros((1, 1), dtype=np.int32)
    info = {"dual_iterations": iterations, "disagreeing": disagreeing}
    return BundleResult(0, 1, labels, 0.0, 0, 0.0, info=info)


def test_a_grids_termination_is_read_from_its_views():
    cfg = MatchConfig(solver="exact", dual_iterations=10)
    assert termination([result(0, 3), result(0, 10)], cfg) == Termination.OPTIMAL
    assert termination([result(0, 3), result(2, 10)], cfg) == Termination.ITERATIONS
    assert termination([result(0, 3), result(2, 4)], cfg) == Termination.GAP
    assert (
        termination([result(0, 3), BundleResult(1, 2, np.zeros((1, 1)), 0.0, 0, 0.0)], cfg) is None
    )


@pytest.mark.parametrize("name", ["grid-dd", "row-chains", "qubo-rows"])
def test_solving_refuses_segments_to_whole_row_strategies_and_reports_each_bundle(name):
    """:meth:`LevelInference.solve`, shared by every strategy: a segment of a row goes to the QUBO
    strategies only; nothing given, nothing solved or reported; otherwise (done, given) after
    each unit of work, ending at all of them."""
    options, _, _ = CASES[name]
    events: list[tuple[int, int]] = []
    outcome: dict[str, object] = {}

    def check(inputs, cfg):
        events.clear()  # each level's own
        inference = inference_for(cfg)
        bundles = inference.plan(inputs, cfg)
        assert inference.solve(inputs, cfg, [], progress=lambda *e: events.append(e)) == []
        assert events == []
        segment = [0, 1, 0, inputs.shape[1] // 2]
        try:
            outcome["segment"] = len(inference.solve(inputs, cfg, [segment]))
        except ValueError as error:
            outcome["segment"] = str(error)
        results = inference.solve(inputs, cfg, bundles, progress=lambda *e: events.append(e))
        outcome["bundles"] = len(bundles)
        return inference.assemble(inputs, results, cfg)

    scene = pair()
    run_pipeline(scene.left, scene.right, config(options), check)
    refused = "exact solves whole rows only, not row segments"
    assert outcome["segment"] == (1 if name == "qubo-rows" else refused)
    given = outcome["bundles"]
    assert events[-1] == (given, given)
    assert [done for done, _ in events] == sorted({done for done, _ in events})
