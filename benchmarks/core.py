"""Quality and speed of the core engine with the exact solver on the Middlebury scenes.

    python benchmarks/core.py [--repeats 5] [--data DIR]

Prints a Markdown table: RMSE / BPP per scene and mask (Middlebury conventions from
PROVENANCE.md), the median in-process time per level, and the median wall time of the whole
`qhsm match` command (process start included).
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from shared.config import MatchConfig
from shared.datasets import default_middlebury_dir, load_scene
from shared.metrics import evaluate
from shared.pipeline import run_pipeline

PAPER_GUROBI = {"tsukuba": (1.53, 12.93), "venus": (0.96, 8.16)}
#: Cones' disparities reach 55 px; the default max (20) would cut them off.
MAX_DISPARITY = {"cones": 60}


def command_seconds(scene, max_disparity: int, repeats: int) -> float:
    exe = shutil.which("qhsm")
    if exe is None:
        sys.exit("qhsm is not installed: pip install -e .")
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(repeats):
            started = time.perf_counter()
            subprocess.run(
                [
                    exe,
                    "match",
                    str(scene.left),
                    str(scene.right),
                    "-o",
                    str(Path(tmp) / "d.pfm"),
                    "--max-disparity",
                    str(max_disparity),
                ],
                check=True,
                capture_output=True,
            )
            times.append(time.perf_counter() - started)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--data", type=Path, default=default_middlebury_dir())
    parser.add_argument("--scenes", default="tsukuba,venus,cones")
    args = parser.parse_args()

    print(
        "| scene | mask | max disp | RMSE | BPP (%) | paper Gurobi RMSE / BPP | "
        "level times (ms, median) | `qhsm match` wall (s, median) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for name in args.scenes.split(","):
        scene = load_scene(args.data / name)
        left, right = scene.load()
        max_disparity = MAX_DISPARITY.get(name, 20)
        config = MatchConfig(max_disparity=max_disparity)
        runs = [run_pipeline(left, right, config) for _ in range(args.repeats)]
        level_ms = [
            statistics.median(run.levels[k].seconds for run in runs) * 1000
            for k in range(len(config.levels))
        ]
        wall = command_seconds(scene, max_disparity, args.repeats)
        gt = scene.ground_truth()
        masks = ["all", "nonocc"] if scene.masks else ["all"]
        for mask_name in masks:
            scores = evaluate(
                runs[0].disparity, gt, scene.scale, scene.border, scene.mask(mask_name)
            )
            paper = PAPER_GUROBI.get(name) if mask_name == "all" else None
            paper_text = f"{paper[0]} / {paper[1]}" if paper else "n/a"
            times = " / ".join(f"{ms:.0f}" for ms in level_ms)
            print(
                f"| {name} | {mask_name} | {max_disparity} | {scores.rmse:.3f} | "
                f"{scores.bpp:.2f} | {paper_text} | {times} | {wall:.2f} |"
            )


if __name__ == "__main__":
    main()
