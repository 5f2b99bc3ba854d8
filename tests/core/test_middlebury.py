"""Quality on the Middlebury scenes beside the repo (skipped when ../shared is absent).

The exact solver on the same formulation must beat the paper's Gurobi results (read from
:data:`shared.bench.PAPER_FIGURES`, the one copy of the paper's figures); where we know it does
better, the bound is ours.
"""

from __future__ import annotations

import pytest

from shared.bench import PAPER_FIGURES
from shared.config import MatchConfig
from shared.datasets import load_scene
from shared.metrics import evaluate
from shared.pipeline import run_pipeline

GUROBI = {scene: figure for (solver, scene), figure in PAPER_FIGURES.items() if solver == "gurobi"}


@pytest.mark.middlebury
@pytest.mark.parametrize(
    "name,rmse,bpp", [("tsukuba", 1.25, GUROBI["tsukuba"].bpp), ("venus", 0.85, 6.5)]
)
def test_exact_beats_the_papers_gurobi_results(middlebury_dir, name, rmse, bpp):
    scene = load_scene(middlebury_dir / name)
    left, right = scene.load()
    result = run_pipeline(left, right, MatchConfig())
    scores = evaluate(result.disparity, scene.ground_truth(), scene.scale, scene.border)
    assert scores.rmse <= rmse <= GUROBI[name].rmse
    assert scores.bpp <= bpp <= GUROBI[name].bpp
