"""Quality on the Middlebury scenes beside the repo (skipped when ../shared is absent).

The paper's Gurobi results are Tsukuba RMSE 1.53 / BPP 12.93 and Venus 0.96 / 8.16; the exact
solver on the same formulation must beat them.
"""

from __future__ import annotations

import pytest

from shared.config import MatchConfig
from shared.datasets import load_scene
from shared.metrics import evaluate
from shared.pipeline import run_pipeline


@pytest.mark.middlebury
@pytest.mark.parametrize("name,rmse,bpp", [("tsukuba", 1.25, 12.93), ("venus", 0.85, 6.5)])
def test_exact_beats_the_papers_gurobi_results(middlebury_dir, name, rmse, bpp):
    scene = load_scene(middlebury_dir / name)
    left, right = scene.load()
    result = run_pipeline(left, right, MatchConfig())
    scores = evaluate(result.disparity, scene.ground_truth(), scene.scale, scene.border)
    assert scores.rmse <= rmse
    assert scores.bpp <= bpp
