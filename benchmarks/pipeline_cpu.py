"""The pipeline's CPU time per configuration, in one process (no imports, no start), runs
alternated so that the machine's load falls on every variant alike.

    python benchmarks/pipeline_cpu.py --pair tsukuba=LEFT,RIGHT,16 [--pair ...] \
        --variant trws=grid_inference:trws [--variant ...] [--repeats 3]

Each pair runs the accurate preset's defaults (``default``) and each ``--variant`` (the syntax
of ``benchmarks/generalisation.py``: ``NAME=KEY:VALUE,...``, ``MatchConfig`` fields), once
untimed each (numba's cache load), then the order reversed every repeat; printed: process CPU
seconds (every thread), their medians, and each variant's median over the default's.
"""

from __future__ import annotations

import argparse
import statistics
import time

from shared.bench.generalisation import parse_variant
from shared.config import MatchConfig, Preset
from shared.images import load_pair
from shared.pipeline import run_pipeline


def parse_pair(text: str) -> tuple[str, str, str, int]:
    """``NAME=LEFT,RIGHT,MAX_DISPARITY`` -> its parts."""
    name, _, rest = text.partition("=")
    left, right, max_disparity = rest.split(",")
    return name, left, right, int(max_disparity)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pair", action="append", type=parse_pair, required=True)
    parser.add_argument("--variant", action="append", type=parse_variant, default=[])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--levels", action="store_true", help="per-level solver seconds, gaps")
    args = parser.parse_args()
    configs = {"default": {"preset": Preset.ACCURATE}}
    configs |= {
        v.name: {"preset": v.preset, "solver": v.solver, **v.overrides} for v in args.variant
    }
    for name, left_path, right_path, max_disparity in args.pair:
        left, right = load_pair(left_path, right_path)
        seconds: dict[str, list[float]] = {variant: [] for variant in configs}
        levels: dict[str, list[list[tuple[float, float]]]] = {variant: [] for variant in configs}
        for variant in configs:  # warm: the kernels each configuration uses loaded once
            run_pipeline(left, right, MatchConfig(max_disparity=max_disparity, **configs[variant]))
        for repeat in range(args.repeats):
            order = list(configs) if repeat % 2 == 0 else list(configs)[::-1]
            for variant in order:
                config = MatchConfig(max_disparity=max_disparity, **configs[variant])
                started = time.process_time()
                result = run_pipeline(left, right, config)
                seconds[variant].append(time.process_time() - started)
                levels[variant].append([(r.solver_seconds, r.gap or 0.0) for r in result.levels])
        medians = {variant: statistics.median(times) for variant, times in seconds.items()}
        for variant, times in seconds.items():
            ratio = medians[variant] / medians["default"]
            runs = " ".join(f"{t:.2f}" for t in times)
            print(f"{name} {variant}: {runs} s, median {medians[variant]:.2f} s, {ratio:.2f}x")
            if args.levels:
                print(f"  {name} {variant} levels: {level_cells(levels[variant])}")


def level_cells(runs: list[list[tuple[float, float]]]) -> str:
    """Each level's median solver seconds and worst gap over the runs, coarsest first."""
    cells = []
    for level in zip(*runs, strict=True):
        median = statistics.median(s for s, _ in level)
        cells.append(f"{median:.2f} s ({100 * max(g for _, g in level):.2f} %)")
    return " | ".join(cells)


if __name__ == "__main__":
    main()
