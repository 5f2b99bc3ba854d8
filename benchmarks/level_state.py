"""CPU of a run's level state without its solves (issue 28, item 4): per level ``prepare_level``,
the cached volumes (built at the first level) and their bins, each view's grid MRF (its costs
gathered from the bins) and the level map and provenance codes from the warm-start labels; the
least of ``--repeats`` runs of each part, one process. Run it with each checkout's ``shared``
first on PYTHONPATH and compare:

    PYTHONPATH=/tmp/base python benchmarks/level_state.py --repeats 8
    PYTHONPATH=$PWD python benchmarks/level_state.py --repeats 8

Default pair: Middlebury 2006 Aloe, half size, 106 px (``QHSM_MIDDLEBURY_DIR``'s parent holds
``middlebury2006``).
"""

from __future__ import annotations

import argparse
import inspect
import json
import time
from pathlib import Path

import cv2
import numpy as np

from shared import pipeline
from shared.assembly import LevelSolution
from shared.config import MatchConfig
from shared.datasets import default_middlebury_dir
from shared.finishing import finish_level, level_stages

PARTS = ("prepare", "volumes", "binned", "grids", "finish")


def one_run(left: np.ndarray, right: np.ndarray, config: MatchConfig) -> dict[str, float]:
    """CPU seconds of each part over every level of one run."""
    _, plans = pipeline.plan_run(left, right, config)
    # an older checkout's prepare_level takes no coarser level
    reuse = "coarser" in inspect.signature(pipeline.prepare_level).parameters
    spent = dict.fromkeys(PARTS, 0.0)
    level_map, inputs, volumes, width = None, None, None, 1

    def lap(part: str, started: float) -> float:
        now = time.process_time()
        spent[part] += now - started
        return now

    for plan in plans:
        started = time.process_time()
        extra = (inputs,) if reuse else ()
        inputs = pipeline.prepare_level(left, right, config, plan, level_map, *extra)
        started = lap("prepare", started)
        if plan.index == 0:
            volumes, width = pipeline._cached_volumes(inputs, config, plans)
        inputs.volumes, inputs.volume_bin_width = volumes, width
        started = lap("volumes", started)
        inputs.binned_volumes()
        started = lap("binned", started)
        height = inputs.view_height
        grids = [inputs.grid(config, v * height, (v + 1) * height) for v in range(inputs.views)]
        started = lap("grids", started)
        labels = inputs.initial_labels
        if labels is None:
            labels = np.zeros(inputs.shape, np.int32)
        solution = LevelSolution(labels, energy=0.0, repaired=0, bundles=1, solver_seconds=0.0)
        level_map = finish_level(inputs, solution, config)
        level_stages(inputs, solution, level_map)
        lap("finish", started)
        del grids
    return spent


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", type=Path, help="a folder with left.png and right.png")
    parser.add_argument("--max-disparity", type=int, default=106)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    scene = args.scene or default_middlebury_dir().parent / "middlebury2006" / "Aloe"
    views = [cv2.imread(str(scene / f"{side}.png")) for side in ("left", "right")]
    config = MatchConfig(max_disparity=args.max_disparity)
    left, right = pipeline.match_views(*(v.astype(np.float32) / 255.0 for v in views), config)
    best = dict.fromkeys(PARTS, float("inf"))
    for _ in range(args.repeats):
        for part, seconds in one_run(left, right, config).items():
            best[part] = min(best[part], seconds)
    best["without volumes"] = sum(best[p] for p in PARTS if p != "volumes")
    print(json.dumps({part: round(seconds, 3) for part, seconds in best.items()}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
