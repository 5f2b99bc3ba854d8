"""QPU economy (issue 19): what roof duality leaves of the metered solvers' bundles, the QPU and
hybrid seconds the estimate gives with the defaults, and qpu-sim's quality against exact.

    python benchmarks/qpu_economy.py                  # estimates for Tsukuba, Venus, Cones
    python benchmarks/qpu_economy.py --quality        # + qpu-sim vs exact on Tsukuba halved

Estimates only run roof duality on the host (nothing is sent); ``--quality`` runs qpu-sim
(MockDWaveSampler) offline. Prints markdown for docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from shared.config import MatchConfig
from shared.datasets.scenes import load_scene
from shared.disparity_range import resolve_max_disparity
from shared.images import load_disparity_values, load_pair
from shared.metrics import evaluate
from shared.pipeline import match_views, run_pipeline
from shared.process_pool import ProcessPoolLevelSolver
from shared.residual import LevelResidual, job_residual
from shared.solvers.meters.qpu_time import job_seconds
from shared.solvers.registry import resolve

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "middlebury"
PAIRS = ("tsukuba", "venus", "cones")


def surveys(
    left: np.ndarray, right: np.ndarray, max_disparity: str | int
) -> Iterator[tuple[MatchConfig, int, list[LevelResidual] | None, float]]:
    """Per metered solver (qpu, hybrid) what ``qhsm estimate --local`` does before it prices a
    job: its configuration, the pair's range, the host's residual survey and its seconds."""
    for solver in ("qpu", "hybrid"):
        config = MatchConfig(solver=solver, max_disparity=max_disparity)
        top = resolve_max_disparity(*match_views(left, right, config), config.max_disparity)
        started = time.perf_counter()
        residual = job_residual(config, left, right, top.max_disparity)
        yield config, top.max_disparity, residual, time.perf_counter() - started


def estimates(pair: str, max_disparity: str | int) -> list[str]:
    """Markdown rows: per level and solver, bundles sent, shares and seconds."""
    scene = load_scene(DATA / pair)
    left, right = load_pair(scene.left, scene.right)
    rows = []
    for config, top, residual, surveyed in surveys(left, right, max_disparity):
        solver = config.solver
        before = job_seconds(resolve(config), left.shape[:2], top)
        after = job_seconds(resolve(config), left.shape[:2], top, residual=residual)
        for level, whole in zip(after.levels, before.levels, strict=True):
            rows.append(
                f"| {pair} | {solver} | {level.index} | {level.bundles} | {level.bundles_sent} "
                f"| {level.classical_share:.1%} | {level.variables_share:.1%} "
                f"| {whole.seconds:,.1f} | {level.seconds:,.1f} |"
            )
        rows.append(
            f"| {pair} | {solver} | all (range {top}, survey {surveyed:.0f} s) "
            f"| {after.bundles} | {after.bundles_sent} "
            f"| {1 - after.bundles_sent / after.bundles:.1%} | | {before.seconds:,.1f} "
            f"| **{after.seconds:,.1f}** |"
        )
    return rows


def halved(pair: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The pair and its ground truth at half size (area-averaged views, nearest ground truth)."""
    scene = load_scene(DATA / pair)
    left, right = load_pair(scene.left, scene.right)
    size = (left.shape[1] // 2, left.shape[0] // 2)
    views = [cv2.resize(view, size, interpolation=cv2.INTER_AREA) for view in (left, right)]
    gt = load_disparity_values(scene.gt)
    gt = cv2.resize(gt.astype(np.float32), size, interpolation=cv2.INTER_NEAREST)
    return views[0], views[1], gt, scene.scale * 2


def quality(pair: str, max_disparity: int, solvers: list[str]) -> list[str]:
    """Markdown rows: RMSE and bad-1 of each solver on the halved pair, wall time, QPU seconds."""
    left, right, gt, scale = halved(pair)
    rows = []
    for solver in solvers:
        config = MatchConfig(solver=solver, max_disparity=max_disparity)
        started = time.perf_counter()
        with ProcessPoolLevelSolver() as solve_level:
            result = run_pipeline(left, right, config, solve_level)
        seconds = time.perf_counter() - started
        scores = evaluate(result.disparity, gt, scale=scale, border=5)
        charged = sum(level.timing.get("qpu_access_time", 0.0) for level in result.levels)
        sent = [level.info.get("bundles_sent") for level in result.levels]
        rows.append(
            f"| {pair} halved | {solver} | {scores.rmse:.3f} | {scores.bpp:.2f} % | {seconds:.0f} "
            f"| {charged:.2f} | {sent} |"
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", nargs="+", default=list(PAIRS))
    parser.add_argument("--quality", action="store_true", help="qpu-sim vs exact, halved Tsukuba")
    parser.add_argument("--skip-estimates", action="store_true")
    args = parser.parse_args(argv)
    if not args.skip_estimates:
        print("| pair | solver | level | bundles | sent | solved classically | variables sent "
              "| estimate before (s) | estimate now (s) |")  # fmt: skip
        print("|---|---|---|---|---|---|---|---|---|")
        for pair in args.pairs:
            for row in estimates(pair, 16 if pair == "tsukuba" else "auto"):
                print(row, flush=True)
    if args.quality:
        print("\n| pair | solver | RMSE (px) | bad > 1 px | wall (s) | QPU s charged "
              "| bundles sent |")  # fmt: skip
        print("|---|---|---|---|---|---|---|")
        for row in quality("tsukuba", 8, ["exact", "qpu-sim"]):
            print(row, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
