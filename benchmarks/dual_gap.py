"""Grid inference: what stopping the dual decomposition at a certified gap costs and saves.

    python benchmarks/dual_gap.py [--scenes tsukuba,venus,cones] [--gaps 0.01,0]

For each scene of the Middlebury 2001/2003 copies (range given: the ceil of the ground truth's
maximum) it runs the default pipeline with ``exact`` for each ``--gaps`` value
(``MatchConfig.dual_gap``; 0 runs every ``dual_iterations``) and once with row inference, one
run at a time, and prints the all-pixel RMSE / BPP, the non-occluded BPP (the scene's mask), each
level's gap and the CPU seconds of the process (all threads): the figure to compare on a shared
machine, where wall time depends on the load.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

from shared.config import MatchConfig
from shared.datasets import default_middlebury_dir, load_scene
from shared.metrics import evaluate
from shared.pipeline import run_pipeline


def run(name: str, changes: dict[str, Any]) -> str:
    scene = load_scene(default_middlebury_dir() / name)
    left, right = scene.load()
    truth = scene.ground_truth()
    config = MatchConfig(max_disparity=scene.ground_truth_range(), **changes)
    started = time.process_time()
    result = run_pipeline(left, right, config)
    cpu = time.process_time() - started
    every = evaluate(result.disparity, truth, scene.scale, scene.border)
    visible = evaluate(result.disparity, truth, scene.scale, scene.border, scene.mask("nonocc"))
    gaps = ", ".join(f"{100 * (level.gap or 0.0):.3f}" for level in result.levels)
    return (
        f"{name} {changes}: RMSE {every.rmse:.3f} BPP {every.bpp:.2f} nonocc {visible.bpp:.2f} "
        f"| gaps % [{gaps}] | {cpu:.2f} s CPU"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="tsukuba,venus,cones")
    parser.add_argument("--gaps", default="0.01,0", help="dual_gap values, comma-separated")
    args = parser.parse_args()
    variants: list[dict[str, Any]] = [{"inference": "rows"}]
    variants += [{"dual_gap": float(gap)} for gap in args.gaps.split(",")]
    for name in args.scenes.split(","):
        for changes in variants:
            print(run(name, changes), flush=True)


if __name__ == "__main__":
    main()
