"""The residual design (issue 27, :mod:`shared.settle`): what the QPU and hybrid solvers are
charged once the host settles each level, and the QUBO solvers' quality against ``exact``.

    python benchmarks/residual.py                      # estimates: Tsukuba (range 16), 1280x720
    python benchmarks/residual.py --quality            # + RMSE of exact, sa, qpu-sim: half, full
    python benchmarks/residual.py --quality --busy 2   # ... with 2 CPU-bound processes beside
    python benchmarks/residual.py --quality --seeds 0 1 2 3 4   # each annealer with 5 seeds
    python benchmarks/residual.py --quality --skip-estimates --solvers exact exact-all sa
                                                       # exact-all: exact with --dual-gap 0

The estimates are ``qhsm estimate --local``'s (:func:`shared.residual.job_residual`, then
:func:`shared.solvers.meters.qpu_time.job_seconds`: classical work only, nothing is sent). The
1280x720 pair is Middlebury 2006 Lampshade1 resized to 1280x720 (no real pair of that size is
in the data; an upscaled pair is smoother than a camera's, so read it as an indication).
Quality runs offline (``qpu-sim``: MockDWaveSampler). Prints markdown for docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import multiprocessing
import time
from pathlib import Path

import cv2
import numpy as np
from qpu_economy import halved, surveys  # the half-size pair and truth, as issue 19 measured

from shared.config import MatchConfig
from shared.datasets.scenes import load_scene
from shared.images import load_disparity_values, load_pair
from shared.metrics import evaluate
from shared.pipeline import run_pipeline
from shared.solvers.meters.qpu_time import job_seconds
from shared.solvers.registry import resolve

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
TSUKUBA = DATA / "middlebury" / "tsukuba"
WIDE = DATA / "middlebury2006" / "Lampshade1"


def estimate_rows(name: str, left, right, max_disparity: int | str) -> list[str]:
    """Markdown rows: per solver, the total estimate and per level the pixels certified/sent."""
    rows = []
    for config, top, residual, surveyed in surveys(left, right, max_disparity):
        estimate = job_seconds(resolve(config), left.shape[:2], top, residual=residual)
        levels = "; ".join(
            f"{level.pixels_sent} px in {level.bundles_sent} tiles" for level in estimate.levels
        )
        rows.append(
            f"| {name} {left.shape[1]}x{left.shape[0]} | {config.solver} | {top} "
            f"| {levels} | {surveyed:.0f} | **{estimate.seconds:.2f}** |"
        )
    return rows


def wide_pair() -> tuple[np.ndarray, np.ndarray]:
    """Lampshade1 resized to 1280x720."""
    scene = load_scene(WIDE)
    left, right = load_pair(scene.left, scene.right)
    return tuple(cv2.resize(v, (1280, 720), interpolation=cv2.INTER_CUBIC) for v in (left, right))


def full(pair: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    scene = load_scene(pair)
    left, right = load_pair(scene.left, scene.right)
    return left, right, load_disparity_values(scene.gt), scene.scale


def quality_rows(size: str, solvers: list[str], reads: int | None, seeds: list[int]) -> list[str]:
    """Markdown rows: RMSE (and its ratio to exact's), bad-1, wall time, tiles sent/improved;
    each annealer once per seed (``MatchConfig.seed``: the tiles' sampler seeds) and, with
    several seeds, their median."""
    left, right, gt, scale = halved("tsukuba") if size == "half" else full(TSUKUBA)
    max_disparity = 8 if size == "half" else 16
    rows, reference = [], None
    for solver in solvers:
        params = {"num_reads": reads} if reads and solver in ("sa", "qpu-sim") else {}
        # exact-all: exact's decomposition without the gap stop, as the residual design's host
        options = (
            {"solver": "exact", "dual_gap": 0.0} if solver == "exact-all" else {"solver": solver}
        )
        deterministic = options["solver"] == "exact"
        ratios = []
        for seed in seeds[:1] if deterministic else seeds:
            config = MatchConfig(
                max_disparity=max_disparity, solver_params=params, seed=seed, **options
            )
            started = time.perf_counter()
            result = run_pipeline(left, right, config)
            seconds = time.perf_counter() - started
            scores = evaluate(result.disparity, gt, scale=scale, border=5)
            reference = scores.rmse if reference is None else reference
            ratios.append(scores.rmse / reference - 1)
            tiles = [
                f"{level.residual['tiles_improved']}/{level.residual['tiles']}"
                for level in result.levels
                if level.residual
            ]
            name = solver if deterministic or len(seeds) == 1 else f"{solver} (seed {seed})"
            rows.append(
                f"| Tsukuba {size} | {name} | {scores.rmse:.3f} | {ratios[-1]:+.1%} "
                f"| {scores.bpp:.2f} % | {seconds:.0f} | {', '.join(tiles) or '-'} |"
            )
        if len(ratios) > 1:
            rows.append(
                f"| Tsukuba {size} | {solver}, median of {len(ratios)} seeds | "
                f"| **{float(np.median(ratios)):+.1%}** | | | |"
            )
    return rows


def _burn() -> None:  # a CPU-bound neighbour
    while True:
        sum(i * i for i in range(10_000))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quality", action="store_true", help="RMSE of exact, sa, qpu-sim")
    parser.add_argument("--skip-estimates", action="store_true")
    parser.add_argument("--sizes", nargs="+", default=["half", "full"])
    parser.add_argument("--solvers", nargs="+", default=["exact", "sa", "qpu-sim"])
    parser.add_argument("--reads", type=int, default=None, help="num_reads of sa / qpu-sim")
    parser.add_argument("--busy", type=int, default=0, help="CPU-bound processes beside")
    parser.add_argument(
        "--seeds", type=int, nargs="+", default=[0], help="MatchConfig.seed of each annealer run"
    )
    args = parser.parse_args(argv)
    burners = [multiprocessing.Process(target=_burn, daemon=True) for _ in range(args.busy)]
    for burner in burners:
        burner.start()
    try:
        if not args.skip_estimates:
            print("| pair | solver | range | per level: sent | survey (s) | estimate (s) |")
            print("|---|---|---|---|---|---|")
            scene = load_scene(TSUKUBA)
            for row in estimate_rows("Tsukuba", *load_pair(scene.left, scene.right), 16):
                print(row, flush=True)
            for row in estimate_rows("Lampshade1", *wide_pair(), "auto"):
                print(row, flush=True)
        if args.quality:
            print("\n| pair | solver | RMSE (px) | vs exact | bad > 1 px | wall (s) "
                  "| tiles improved / sent per level |")  # fmt: skip
            print("|---|---|---|---|---|---|---|")
            for size in args.sizes:
                for row in quality_rows(size, args.solvers, args.reads, args.seeds):
                    print(row, flush=True)
    finally:
        for burner in burners:
            burner.terminate()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
