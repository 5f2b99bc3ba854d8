"""Grid inference (issue 17): how close a QUBO solver's tiles come to the exact DD bound.

    python benchmarks/grid_energy.py [--scenes tsukuba,middlebury2006/monopoly] [--solver sa]
        [--processes 2] [--no-certify-tiles]

For each scene (range given: the ceil of the ground truth's maximum) it runs the default
pipeline twice: with ``exact`` (dual decomposition: energy and lower bound per level) and with
``--solver`` (3-row tiles given their neighbours' labels). On every level of the solver's run it
also computes the DD lower bound of that same level (same candidates, which follow from the
solver's own coarser levels), so the gap is the solver's labelling against a bound on the optimum
of the very MRF it minimised. Prints per level: energy, bound, gap; and per run the all-pixel
RMSE / BPP and time.
"""

from __future__ import annotations

import argparse
import resource
import time

from shared.config import MatchConfig
from shared.datasets import Scene, default_middlebury_dir, load_scene
from shared.grid import GridMRF, dual_decomposition
from shared.inference import solve_level_in_process
from shared.level_inputs import LevelInputs
from shared.metrics import evaluate
from shared.pipeline import run_pipeline
from shared.process_pool import ProcessPoolLevelSolver


def bound_of(inputs: LevelInputs, config: MatchConfig) -> float:
    """The DD lower bound of a level (both views), as ``exact`` would compute it."""
    height = inputs.view_height
    return sum(
        dual_decomposition(
            inputs.grid(config, view * height, (view + 1) * height), config.dual_iterations
        ).lower_bound
        for view in range(inputs.views)
    )


def _cpu_seconds() -> float:
    """User + system CPU of this process and its joined children."""
    own, children = (
        resource.getrusage(resource.RUSAGE_SELF),
        resource.getrusage(resource.RUSAGE_CHILDREN),
    )
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def find_scene(name: str) -> Scene:
    """``tsukuba`` (in the Middlebury copies) or ``middlebury2006/monopoly`` (beside them)."""
    folder = default_middlebury_dir()
    if "/" in name:
        dataset, scene = name.split("/")
        candidates = [p for p in (folder.parent / dataset).iterdir() if p.name.lower() == scene]
        return load_scene(candidates[0])
    return load_scene(folder / name)


def level_grids(name: str) -> tuple[MatchConfig, list[tuple[int, int, GridMRF]]]:
    """The default run's grid MRFs of a scene (range given): (bin width, view, grid) for every
    level and view, as ``exact`` minimised them."""
    scene = find_scene(name)
    left, right = scene.load()
    config = MatchConfig(max_disparity=scene.ground_truth_range())
    grids: list[tuple[int, int, GridMRF]] = []

    def solve_level(inputs, config, **kwargs):
        height = inputs.view_height
        for view in range(inputs.views):
            grid = inputs.grid(config, view * height, (view + 1) * height)
            grids.append((inputs.plan.bin_width, view, grid))
        return solve_level_in_process(inputs, config, **kwargs)

    run_pipeline(left, right, config, solve_level)
    return config, grids


def run(scene: Scene, solver: str, processes: int, certify: bool = True) -> list[str]:
    left, right = scene.load()
    truth = scene.ground_truth()
    config = MatchConfig(
        solver=solver, max_disparity=scene.ground_truth_range(), certify_tiles=certify
    )
    bounds: list[float] = []
    cpu = _cpu_seconds()
    with ProcessPoolLevelSolver(processes) as pool:

        def solve_level(inputs, config, **kwargs):
            solution = pool(inputs, config, **kwargs)
            bounds.append(bound_of(inputs, config))
            return solution

        started = time.perf_counter()
        result = run_pipeline(left, right, config, solve_level)
        seconds = time.perf_counter() - started
    cpu = _cpu_seconds() - cpu  # the pool's children are counted once joined
    scores = evaluate(result.disparity, truth, scene.scale, scene.border)
    summary = (
        f"RMSE {scores.rmse:.3f} BPP {scores.bpp:.2f} ({seconds:.0f} s wall, "
        f"{cpu:.0f} s CPU with the pool, the bounds included)"
    )
    lines = [f"{scene.name} {solver}: {summary}"]
    for level, bound in zip(result.levels, bounds, strict=True):
        gap = (level.energy - bound) / abs(level.energy)
        settled = level.residual  # the host's settling (shared.settle)
        tiles = (
            ""
            if settled is None
            else f", {settled['certified']} of {settled['pixels']} pixels certified, "
            f"{settled['tiles']} tiles sent"
        )
        lines.append(
            f"  level {level.index} (bin {level.bin_width}): energy {level.energy:.1f} "
            f"bound {bound:.1f} gap {100 * gap:.3f} %{tiles}"
        )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="tsukuba,middlebury2006/monopoly")
    parser.add_argument("--solver", default="sa")
    parser.add_argument("--processes", type=int, default=2)
    parser.add_argument(
        "--no-certify-tiles",
        dest="certify",
        action="store_false",
        help="send every tile to the solver (the tiles of before certify_tiles)",
    )
    args = parser.parse_args()
    for name in args.scenes.split(","):
        scene = find_scene(name)
        for solver in ("exact", args.solver):
            print("\n".join(run(scene, solver, args.processes, args.certify)), flush=True)


if __name__ == "__main__":
    main()
