"""The Middlebury scenes the benchmark scripts run on: their quoted ranges and real level inputs.

The scripts beside this file import it as ``scenes`` (``python benchmarks/X.py`` puts this
folder first on ``sys.path``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from shared.config import MatchConfig
from shared.datasets import Scene, default_middlebury_dir, load_scene
from shared.inference import solve_level_in_process
from shared.level_inputs import LevelInputs
from shared.pipeline import run_pipeline

#: The ranges the targets are quoted for (PROVENANCE.md; Cones' disparities reach 55 px).
MAX_DISPARITY = {"tsukuba": 16, "venus": 20, "cones": 60}


def load(name: str, data: Path | None = None) -> tuple[Scene, np.ndarray, np.ndarray]:
    """Scene ``name`` and its two views.

    Parameters
    ----------
    name
        The scene's folder name.
    data
        The dataset folder (default: the Middlebury copies, ``QHSM_MIDDLEBURY_DIR``).

    Returns
    -------
    tuple
        The :class:`~shared.datasets.Scene`, its left and its right view.
    """
    scene = load_scene((data or default_middlebury_dir()) / name)
    return (scene, *scene.load())


def quoted_range(scene: Scene) -> int:
    """The disparity range a scene's figures are quoted for.

    Parameters
    ----------
    scene
        A loaded scene: its name picks the quoted range, or its protocol gives the range of a
        scene not quoted.

    Returns
    -------
    int
        The range in full-resolution pixels.
    """
    return MAX_DISPARITY.get(scene.name, scene.max_disparity)


def level_inputs(left: np.ndarray, right: np.ndarray, config: MatchConfig) -> list[LevelInputs]:
    """Each level's inputs as an ``exact`` run prepares them, so every solver faces the same
    problems.

    Parameters
    ----------
    left, right
        The views as loaded.
    config
        The configuration; its solver is replaced by ``exact``.

    Returns
    -------
    list of LevelInputs
        Coarsest level first, each built on the exact solution of the coarser one.
    """
    captured: list[LevelInputs] = []

    def solve_level(inputs: LevelInputs, cfg: MatchConfig):
        captured.append(inputs)
        return solve_level_in_process(inputs, cfg)

    run_pipeline(left, right, config.model_copy(update={"solver": "exact"}), solve_level)
    return captured
