"""TRW-S against the subgradient dual decomposition on the very level energies of real scenes.

    python -m benchmarks.trws [--scenes tsukuba,cones,middlebury2006/aloe] [--repeats 3]

Runs the default pipeline (``exact``, ``grid_inference=dd``, range given) and, on every level
and view, minimises the same grid MRF with :func:`shared.grid.dual_decomposition` and
:func:`shared.grid_inference.trws` (``dual_iterations`` and ``dual_gap`` of the default),
alternating which goes first, timing each by the CPU time of its thread
(``time.thread_time``: what the other users of a shared machine disturb least). Prints per
scene the summed inference CPU (median of the repeats), the ratio, the worst gap of each and
the summed energies and bounds.
"""

from __future__ import annotations

import argparse
import statistics
import time

from benchmarks.grid_energy import level_grids
from shared.config import MatchConfig
from shared.grid import DualResult, GridMRF, dual_decomposition
from shared.grid_inference import trws


def timed(method, grid: GridMRF, config: MatchConfig) -> tuple[float, DualResult]:
    started = time.thread_time()
    result = method(grid, config.dual_iterations, config.dual_gap)
    return time.thread_time() - started, result


def scene_row(name: str, repeats: int) -> str:
    config, levels = level_grids(name)
    grids = [grid for _, _, grid in levels]
    seconds: dict[str, list[float]] = {"dd": [], "trws": []}
    results: dict[str, list[DualResult]] = {}
    methods = {"dd": dual_decomposition, "trws": trws}
    for repeat in range(repeats):
        order = ["dd", "trws"] if repeat % 2 == 0 else ["trws", "dd"]
        for key in order:
            runs = [timed(methods[key], grid, config) for grid in grids]
            seconds[key].append(sum(s for s, _ in runs))
            results[key] = [r for _, r in runs]
    dd, tr = statistics.median(seconds["dd"]), statistics.median(seconds["trws"])
    cells = [name, f"{len(grids)}", f"{dd:.2f}", f"{tr:.2f}", f"{dd / tr:.1f}x"]
    for key in ("dd", "trws"):
        worst = max(r.gap for r in results[key])
        iterations = sum(r.iterations for r in results[key])
        energy = sum(r.energy for r in results[key])
        bound = sum(r.lower_bound for r in results[key])
        cells.append(f"{100 * worst:.2f} % / {iterations} / {energy:.1f} / {bound:.1f}")
    return "| " + " | ".join(cells) + " |"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="tsukuba,cones,middlebury2006/aloe")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    print(
        "| scene | view-levels | dd CPU s | trws CPU s | dd / trws | dd worst gap / iterations "
        "/ energy / bound | trws worst gap / iterations / energy / bound |"
    )
    print("|---|---:|---:|---:|---:|---|---|")
    for name in args.scenes.split(","):
        print(scene_row(name, args.repeats), flush=True)


if __name__ == "__main__":
    main()
