"""The provenance map: which stage decided each pixel, from the level's solve to the final map."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from shared import provenance_map as pm
from shared.config import MatchConfig
from shared.encodings import get_codec
from shared.inference import inference_for, level_bundles, solve_bundles, solve_level_in_process
from shared.inference.qubo import sampler_stages
from shared.pipeline import run_pipeline
from shared.provenance_map import Stage
from shared.settle import host_stages
from shared.solvers.base import SolveResult
from shared.synthetic import make_scene

ROOT = Path(__file__).resolve().parents[2]
SOLVER_CODES = {Stage.ROOF_DUALITY, Stage.SOLVER, Stage.REPAIRED}


@pytest.fixture(scope="module")
def pair():
    scene = make_scene(16, 40, max_disparity=6, seed=5)
    return scene.left, scene.right


def run(pair, **options):
    """The run and its finest level's inputs and solution."""
    levels = []

    def solve_level(inputs, cfg):
        solution = solve_level_in_process(inputs, cfg)
        levels.append((inputs, solution))
        return solution

    result = run_pipeline(*pair, MatchConfig(max_disparity=6, seed=7, **options), solve_level)
    return result, levels[-1]


def codes(stages: np.ndarray) -> set[Stage]:
    return {Stage(int(code)) for code in np.unique(stages)}


def test_exact_decides_on_the_host_only_and_the_fill_is_the_validity_maps_holes(pair):
    result, _ = run(pair)  # the accurate preset: grid inference, LR check, weighted median
    stages = result.provenance_map
    assert stages.shape == result.disparity.shape and stages.dtype == np.uint8
    assert codes(stages) <= {Stage.FILLED, Stage.CERTIFIED, Stage.HOST, Stage.FILTERED}
    assert Stage.CERTIFIED in codes(stages)
    assert np.array_equal(stages == Stage.FILLED, ~result.validity)
    counts = result.summary()["provenance_counts"]
    assert sum(counts.values()) == stages.size
    assert counts["filled"] == int((~result.validity).sum())


def test_the_finest_level_decides_and_only_the_fill_and_filters_change_it(pair):
    result, (inputs, solution) = run(pair, median=False, weighted_median=False)
    height = inputs.view_height
    level = solution.stages[:height]  # the left view's codes at full resolution (bins pyramid)
    expected = np.where(result.validity, level, np.uint8(Stage.FILLED))
    assert np.array_equal(result.provenance_map, expected)


def test_a_filter_marks_only_the_pixels_it_moved():
    stages = pm.filled((3, 4), Stage.CERTIFIED)
    stages[0, 0] = Stage.FILLED
    before = np.zeros((3, 4), np.float32)
    after = before.copy()
    after[0, 0] = after[1, 1] = 3.0  # a filled pixel stays filled
    after[2, 2] = 0.4  # within half a step: not moved
    moved = pm.moved(stages, before, after)
    assert moved[0, 0] == Stage.FILLED and moved[1, 1] == Stage.FILTERED
    assert (moved == Stage.FILTERED).sum() == 1


def test_the_paper_preset_is_host_exact_rows(pair):
    result, _ = run(pair, preset="paper")  # rows inference: each row's exact optimum
    assert result.validity is None
    assert codes(result.provenance_map) <= {Stage.CERTIFIED, Stage.FILTERED}


def test_a_sampler_without_the_residual_design_decides_its_tiles(pair):
    result, (_, solution) = run(
        pair, solver="sa", certify_tiles=False, solver_params={"num_reads": 2, "num_sweeps": 50}
    )
    assert codes(solution.stages) <= SOLVER_CODES and Stage.SOLVER in codes(solution.stages)
    assert codes(result.provenance_map) <= SOLVER_CODES | {Stage.FILLED, Stage.FILTERED}


class Answers:
    """A fake sampler: the given labels of each bundle, in the order they are asked."""

    def __init__(self, labels: list[np.ndarray], encoding: str, num_labels: int):
        codec = get_codec(encoding)
        self.samples = [codec.encode_labels(tile, num_labels) for tile in labels]

    def solve(self, bqm, **kwargs):
        sample = self.samples.pop(0)
        return SolveResult(sample=sample, energy=bqm.energy(sample), wall_time=0.0)


def test_the_solver_code_is_exactly_where_a_tiles_answer_was_kept(pair, monkeypatch):
    cfg = MatchConfig(solver="sa", max_disparity=6, seed=7, encoding="domain-wall")
    _, (inputs, _) = run(pair, solver="sa", encoding="domain-wall", solver_params={"num_reads": 2})
    inputs.prepared.pop("settle", None)  # settle the level again, from its own inputs
    inputs.initial_labels = None
    bundles = level_bundles(inputs, cfg)
    host = inputs.initial_labels.copy()
    before = host_stages(inputs)
    tile = bundles[0]
    rows, columns = slice(tile.row_start, tile.row_stop), slice(tile.col_start, tile.col_stop)
    row, column = np.argwhere(before[rows, columns] == Stage.HOST)[0]
    row, column = row + tile.row_start, column + tile.col_start
    # the host made worse at one unsettled pixel of the first tile: its answer (the host's own
    # labels) lowers the energy there and is kept; the other tiles answer the worse labels
    costs = inputs.costs(cfg, row, row + 1).unary[0, column]
    inputs.initial_labels[row, column] = int(
        np.argmax(np.where(np.arange(costs.size) == host[row, column], -np.inf, costs))
    )
    answers = [host[rows, columns]] + [
        inputs.initial_labels[b.row_start : b.row_stop, b.col_start : b.col_stop]
        for b in bundles[1:]
    ]
    fake = Answers(answers, cfg.encoding, inputs.count)
    monkeypatch.setattr("shared.solvers.registry.get_solver", lambda name: fake)
    solution = inference_for(cfg).assemble(inputs, solve_bundles(inputs, cfg, bundles), cfg)
    assert solution.residual["tiles_improved"] == 1
    # the answer differs from the labels at that pixel only: the one pixel the tile decided (the
    # tile's other unsettled pixels, answered with the labels they had, stay the host's)
    expected = before.copy()
    expected[row, column] = Stage.SOLVER
    assert np.array_equal(solution.stages, expected)
    assert Stage.SOLVER in codes(solution.stages)


def test_a_samplers_codes_mark_roof_duality_and_repairs():
    labels = np.zeros((2, 3), np.int32)
    per_pixel = 2
    fixed = [0, 1, 2, 9]  # pixel 0 whole, pixel 1 half, pixel 4 half
    invalid = np.zeros((2, 3), bool)
    invalid[1, 2] = True
    stages = sampler_stages(invalid, fixed, per_pixel, labels)
    assert stages[0, 0] == Stage.ROOF_DUALITY and stages[1, 2] == Stage.REPAIRED
    assert (stages == Stage.SOLVER).sum() == 4


@given(
    arrays(np.uint8, st.tuples(st.integers(1, 9), st.integers(1, 9)), elements=st.integers(0, 6))
)
@settings(max_examples=40, deadline=None)
def test_the_png_colours_decode_to_the_codes_and_the_counts_sum_to_the_pixels(stages):
    image = cv2.imdecode(np.frombuffer(pm.png(stages), np.uint8), cv2.IMREAD_COLOR)
    assert np.array_equal(pm.decode(image), stages)
    assert sum(pm.counts(stages).values()) == stages.size


def test_the_legend_is_one_colour_a_code_and_the_docs_carry_it():
    entries = pm.legend()
    assert [e["code"] for e in entries] == list(range(len(Stage)))
    assert len({e["colour"] for e in entries}) == len(entries)
    readme = (ROOT / "README.md").read_text()
    assert pm.legend_markdown() in readme, "README: paste shared.provenance_map.legend_markdown()"


def test_the_cli_writes_the_map_and_its_counts(pair, tmp_path, capsys):
    from shared.cli import main

    left, right = pair
    for name, view in (("l.png", left), ("r.png", right)):
        cv2.imwrite(str(tmp_path / name), (view * 255).round().astype(np.uint8))
    out = tmp_path / "d.pfm"
    command = ["match", str(tmp_path / "l.png"), str(tmp_path / "r.png"), "-o", str(out)]
    assert main([*command, "--max-disparity", "6", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    written = summary["maps"]["provenance"]
    assert written == str(tmp_path / "d.provenance.png")
    stages = pm.decode(cv2.imread(written, cv2.IMREAD_COLOR))
    assert summary["provenance_counts"] == pm.counts(stages)
    valid = cv2.imread(summary["maps"]["validity"], cv2.IMREAD_GRAYSCALE) > 0
    assert np.array_equal(stages == Stage.FILLED, ~valid)
