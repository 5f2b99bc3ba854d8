"""Grid inference (issue 28): is a level's gap the bound's or the labels'? Dual decomposition's
labels against what exact chain sweeps make of them, on the very level energies of real scenes.

    python -m benchmarks.primal_gap [--scenes middlebury2006/midd1,middlebury2006/aloe]
        [--max-sweeps 30] [--all]

Runs the default pipeline (``exact``, range given: the ceil of the ground truth's maximum) and,
on every level and view, minimises the same grid MRF with
:func:`shared.grid.dual_decomposition` (the default's ``dual_iterations`` and ``dual_gap``), then
lowers its labelling with :func:`shared.grid.chain_sweeps` until a sweep no longer lowers the
energy (at most ``--max-sweeps``). Prints each view-level the DD leaves above its ``dual_gap``
(``--all``: every one): the DD's gap, the swept labelling's gap against the same bound, how far
the DD's energy lies above the swept one, and the share of pixels the sweeps changed. When the
DD's labels lie more than ``dual_gap`` above a labelling the sweeps found, no bound can certify
them: the level's gap is its labels', not its bound's.
"""

from __future__ import annotations

import argparse

from benchmarks.grid_energy import level_grids
from shared.grid import chain_sweeps, dual_decomposition


def rows(name: str, max_sweeps: int, every: bool) -> list[str]:
    config, grids = level_grids(name)
    lines = []
    for width, view, grid in grids:
        result = dual_decomposition(grid, config.dual_iterations, config.dual_gap)
        if result.gap <= config.dual_gap and not every:
            continue
        turned = grid.transposed()
        labels, energy, sweeps = result.labels, result.energy, 0
        while sweeps < max_sweeps:
            swept = chain_sweeps(grid, turned, labels)
            lowered = grid.energy(swept)
            sweeps += 1
            if lowered >= energy:
                break
            labels, energy = swept, lowered
        above = (result.energy - energy) / abs(result.energy)
        swept_gap = (energy - result.lower_bound) / abs(energy)
        changed = float((labels != result.labels).mean())
        lines.append(
            f"| {name} | {width} | {view} | {'x'.join(map(str, grid.shape))} "
            f"| {result.iterations} | {100 * result.gap:.2f} | {100 * swept_gap:.2f} "
            f"| {100 * above:.2f} | {sweeps} | {100 * changed:.1f} |"
        )
    return lines


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="middlebury2006/midd1,middlebury2006/aloe")
    parser.add_argument("--max-sweeps", type=int, default=30)
    parser.add_argument("--all", action="store_true", help="every view-level, certified too")
    args = parser.parse_args(argv)
    print(
        "| scene | bin width | view | grid | DD iterations | DD gap % | swept gap % "
        "| DD above swept % | sweeps | pixels changed % |"
    )
    print("|---|---:|---:|---|---:|---:|---:|---:|---:|---:|")
    for name in args.scenes.split(","):
        for line in rows(name, args.max_sweeps, args.all):
            print(line, flush=True)


if __name__ == "__main__":
    main()
