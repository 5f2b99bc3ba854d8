"""The Middlebury scenes the benchmark scripts run on: their quoted ranges and real level inputs.

The scripts beside this file import it as ``scenes`` (``python benchmarks/X.py`` puts this
folder first on ``sys.path``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from shared.config import MatchConfig
from shared.datasets import Scene, default_middlebury_dir, load_scene
from shared.pipeline import run_pipeline
from shared.solve import LevelInputs, solve_level_in_process

#: The ranges the targets are quoted for (PROVENANCE.md; Cones' disparities reach 55 px).
MAX_DISPARITY = {"tsukuba": 16, "venus": 20, "cones": 60}


def load(name: str, data: Path | None = None) -> tuple[Scene, np.ndarray, np.ndarray]:
    """Scene ``name`` below ``data`` (default: the Middlebury copies) and its two views."""
    scene = load_scene((data or default_middlebury_dir()) / name)
    return (scene, *scene.load())


def quoted_range(scene: Scene) -> int:
    """The range the targets are quoted for, else the scene's own protocol."""
    return MAX_DISPARITY.get(scene.name, scene.max_disparity)


def level_inputs(left: np.ndarray, right: np.ndarray, config: MatchConfig) -> list[LevelInputs]:
    """Each level's inputs as an ``exact`` run prepares them (on its coarser level's estimate),
    so every solver compared faces the same problems."""
    captured: list[LevelInputs] = []

    def solve_level(inputs: LevelInputs, cfg: MatchConfig):
        captured.append(inputs)
        return solve_level_in_process(inputs, cfg)

    run_pipeline(left, right, config.model_copy(update={"solver": "exact"}), solve_level)
    return captured
