"""Quality and speed of the in-process pipeline on the Middlebury scenes, both presets.

    python benchmarks/core.py [--repeats 5] [--data DIR] [--solver exact] [--encoding E]

For each scene and preset (``accurate``, the default, and ``paper``): RMSE / BPP over all pixels
and non-occluded ones (Middlebury conventions from PROVENANCE.md, the scene's known range), the
median in-process time per level, and the median wall time of the whole ``qhsm match`` command
(process start included), with the accurate/paper time ratio measured in the same run. Then the
QUBO size of one bundle per level with each encoding. Prints Markdown.
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

from scenes import load, quoted_range

from shared.config import Encoding, MatchConfig, Preset
from shared.datasets import default_middlebury_dir
from shared.encodings import get_codec
from shared.metrics import evaluate
from shared.pipeline import match_views, plan_run, prepare_level, run_pipeline


def command_seconds(scene, options: list[str], repeats: int) -> float:
    exe = shutil.which("qhsm")
    if exe is None:
        sys.exit("qhsm is not installed: pip install -e .")
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(repeats):
            started = time.perf_counter()
            command = [exe, "match", str(scene.left), str(scene.right)]
            command += ["-o", str(Path(tmp) / "d.pfm"), *options]
            subprocess.run(command, check=True, capture_output=True)
            times.append(time.perf_counter() - started)
    return statistics.median(times)


def qubo_sizes(left, right, config: MatchConfig) -> list[str]:
    """Variables / couplings of the first bundle of each level, one-hot and domain-wall."""
    left, right = match_views(left, right, config)
    _, plans = plan_run(left, right, config)
    cells = []
    for plan in plans:
        inputs = prepare_level(left, right, config, plan)  # candidates as on the coarsest level
        if plan.index > 0 and inputs.candidates is not None:  # finer levels: a window of K
            inputs.candidates = inputs.candidates[:, :, : plan.candidates]
        costs = inputs.costs(config, 0, config.bundle_height)
        sizes = []
        for encoding in Encoding:
            bqm = get_codec(encoding).encode(costs, config.rectifier)
            sizes.append(f"{bqm.num_variables}/{bqm.num_interactions}")
        cells.append(" & ".join(sizes))
    return cells


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--data", type=Path, default=default_middlebury_dir())
    parser.add_argument("--scenes", default="tsukuba,venus,cones")
    parser.add_argument("--solver", default="exact")
    parser.add_argument("--encoding", choices=[e.value for e in Encoding])
    parser.add_argument("--no-command", action="store_true", help="skip the `qhsm match` timing")
    args = parser.parse_args()

    print(
        "| scene | preset | RMSE all | BPP all (%) | RMSE nonocc | BPP nonocc (%) | "
        "level times (ms, median) | `qhsm match` wall (s, median) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    sizes: dict[str, list[str]] = {}
    walls: dict[tuple[str, str], float] = {}
    for name in args.scenes.split(","):
        scene, left, right = load(name, args.data)
        max_disparity = quoted_range(scene)
        for preset in Preset:
            options = {"preset": preset, "max_disparity": max_disparity, "solver": args.solver}
            if args.encoding:
                options["encoding"] = args.encoding
            config = MatchConfig(**options)
            runs = [run_pipeline(left, right, config) for _ in range(args.repeats)]
            level_ms = " / ".join(
                f"{statistics.median(run.levels[k].seconds for run in runs) * 1000:.0f}"
                for k in range(len(runs[0].levels))
            )
            wall = float("nan")
            if not args.no_command:
                flags = [f"--{k.replace('_', '-')}={v}" for k, v in options.items()]
                wall = command_seconds(scene, flags, args.repeats)
            walls[name, preset.value] = wall
            gt = scene.ground_truth()
            scores = [
                evaluate(runs[0].disparity, gt, scene.scale, scene.border, scene.mask(mask))
                for mask in ("all", "nonocc")
            ]
            print(
                f"| {name} | {preset.value} | {scores[0].rmse:.3f} | {scores[0].bpp:.2f} | "
                f"{scores[1].rmse:.3f} | {scores[1].bpp:.2f} | {level_ms} | {wall:.2f} |"
            )
            sizes[f"{name} {preset.value}"] = qubo_sizes(left, right, config)
    if not args.no_command:
        print()
        for name in args.scenes.split(","):
            ratio = walls[name, "accurate"] / walls[name, "paper"]
            print(f"- {name}: accurate / paper `qhsm match` wall time = {ratio:.2f}")
    print()
    print("QUBO of one bundle per level, variables/couplings, one-hot & domain-wall:")
    print()
    for key, cells in sizes.items():
        print(f"- {key}: " + "; ".join(f"level {i}: {c}" for i, c in enumerate(cells)))


if __name__ == "__main__":
    main()
