"""The price of row segments: energy gaps vs the row optimum, and quality vs whole rows.

    python benchmarks/segments.py price [--scenes tsukuba,venus,cones] [--widths 32,64,128]
    python benchmarks/segments.py gaps  [--scenes tsukuba,cones] [--rows 4] [--widths 32,64]

``price`` (issue 11, item 1): per scene and width, (a) the MRF energy gap of rows stitched from
exactly solved segments (the row DP on each segment's costs) vs the row optimum, median and worst
over every row of every level: the price of cutting alone, free of any solver's error; and
(b) RMSE / BPP of the full ``accurate`` pipeline with ``sa`` at that width vs whole rows (same
seed), with the bad-pixel rate in the columns within 2 px of a stitching cut vs the rest (a
visible seam would raise the former).

``gaps`` (item 5): per scene, level, solver (sa, tabu, qpu-sim, hybrid-sim), encoding and width,
the median and worst energy gap of stitched rows vs the row optimum, on a sample of rows of each
level (evenly spaced over both views). Every level's inputs come from an ``exact`` run, so all
solvers face the same problems. Prints Markdown.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from scenes import level_inputs, load, quoted_range

from shared.bundles import owned_columns, segment_columns
from shared.config import Encoding, MatchConfig
from shared.datasets import Scene, default_middlebury_dir
from shared.energy import Costs, mrf_energy
from shared.inference import solve_bundles
from shared.metrics import evaluate
from shared.pipeline import run_pipeline
from shared.solvers.exact import solve_chains

MARGIN = 12


def stitch(segments: list[tuple[int, int]], parts: list[np.ndarray], width: int) -> np.ndarray:
    """One row (rows, width) from segment labels by :func:`owned_columns`."""
    out = np.empty((parts[0].shape[0], width), dtype=np.int32)
    for (first, _), (own_first, own_last), part in zip(
        segments, owned_columns(segments), parts, strict=True
    ):
        out[:, own_first:own_last] = part[:, own_first - first : own_last - first]
    return out


def row_gaps(costs: Costs, labels: np.ndarray, optimum: np.ndarray) -> np.ndarray:
    """Relative energy gap of each row of ``labels`` vs ``optimum`` (same costs)."""
    gaps = []
    for row in range(costs.shape[0]):
        part = costs.rows(row, row + 1)
        best = mrf_energy(part, optimum[row : row + 1])
        gaps.append((mrf_energy(part, labels[row : row + 1]) - best) / max(best, 1e-12))
    return np.array(gaps)


def exact_stitched(costs: Costs, width: int | None) -> np.ndarray:
    """Rows stitched from the exact optimum of every segment."""
    segments = segment_columns(costs.shape[1], width, MARGIN)
    parts = [solve_chains(costs.columns(a, b)) for a, b in segments]
    return stitch(segments, parts, costs.shape[1])


def cut_columns(width: int, bundle_width: int | None) -> list[int]:
    """Where stitched rows change segment."""
    owned = owned_columns(segment_columns(width, bundle_width, MARGIN))
    return [start for start, _ in owned[1:]]


def table_head(columns: str) -> None:
    """Print a Markdown table's header: ``columns`` are the titles separated by `` | ``."""
    print(f"| {columns} |")
    print("|" + "---|" * len(columns.split(" | ")))


def scenes_of(args: argparse.Namespace) -> Iterator[tuple[str, Scene, tuple, MatchConfig]]:
    """Each scene of ``--scenes``: its name, itself, its views and the default configuration at
    the range its targets are quoted for."""
    for name in args.scenes.split(","):
        scene, left, right = load(name, args.data)
        yield (
            name,
            scene,
            (left, right),
            MatchConfig(max_disparity=quoted_range(scene), seed=args.seed),
        )


def price(args: argparse.Namespace) -> None:
    widths = [int(w) for w in args.widths.split(",")]
    table_head(
        "scene | width | energy gap median (%) | energy gap worst (%) | RMSE | BPP (%) | "
        "RMSE vs whole | BPP near cuts / elsewhere (%) | sa s"
    )
    for name, scene, (left, right), base in scenes_of(args):
        gt = scene.ground_truth()
        levels = level_inputs(left, right, base)
        costs = [inputs.costs(base) for inputs in levels]
        optima = [solve_chains(c) for c in costs]
        whole = None
        for width in [None, *widths]:
            gaps = np.concatenate(
                [
                    row_gaps(c, exact_stitched(c, width), o)
                    for c, o in zip(costs, optima, strict=True)
                ]
            )
            config = base.model_copy(
                update={"solver": "sa", "bundle_width": width, "bundle_margin": MARGIN}
            )
            started = time.perf_counter()
            result = run_pipeline(left, right, config)
            seconds = time.perf_counter() - started
            scores = evaluate(result.disparity, gt, scene.scale, scene.border)
            if width is None:
                whole = scores
            bad = np.abs(result.disparity - gt / scene.scale) > 1.0
            valid = gt > 0
            near = np.zeros(gt.shape[1], dtype=bool)
            for cut in cut_columns(gt.shape[1], width):
                near[max(0, cut - 2) : cut + 2] = True
            near_rate = 100 * bad[:, near][valid[:, near]].mean() if near.any() else float("nan")
            far_rate = 100 * bad[:, ~near][valid[:, ~near]].mean()
            if args.maps:
                import cv2

                args.maps.mkdir(parents=True, exist_ok=True)
                error = np.where(
                    valid, np.minimum(np.abs(result.disparity - gt / scene.scale), 4), 0
                )
                cv2.imwrite(
                    str(args.maps / f"{name}-{width or 'whole'}.png"),
                    (error * 63).astype(np.uint8),
                )
            print(
                f"| {name} | {width or 'whole row'} | {100 * np.median(gaps):.3f} | "
                f"{100 * gaps.max():.2f} | {scores.rmse:.3f} | {scores.bpp:.2f} | "
                f"{100 * (scores.rmse / whole.rmse - 1):+.1f} % | "
                f"{near_rate:.2f} / {far_rate:.2f} | {seconds:.0f} |",
                flush=True,
            )


def gaps(args: argparse.Namespace) -> None:
    widths = [int(w) for w in args.widths.split(",")]
    table_head(
        "scene | level | K | solver | encoding | width | gap median (%) | gap worst (%) | s per row"
    )
    for name, _, (left, right), base in scenes_of(args):
        for inputs in level_inputs(left, right, base):
            height = inputs.shape[0]
            sample = np.linspace(0, height - 1, args.rows).round().astype(int).tolist()
            optimum = {r: solve_chains(inputs.costs(base, r, r + 1)) for r in sample}
            for solver in args.solvers.split(","):
                # hybrid-sim takes ~10-80 s a row here: fewer rows
                rows = sample[: args.hybrid_rows] if solver.startswith("hybrid") else sample
                for encoding in Encoding:
                    for width in [None, *widths]:
                        if solver == "qpu-sim" and width is None:
                            continue  # a whole row does not embed (issue 11)
                        config = base.model_copy(
                            update={
                                "solver": solver,
                                "encoding": encoding,
                                "bundle_width": width,
                                "bundle_margin": MARGIN,
                            }
                        )
                        started = time.perf_counter()
                        found = []
                        for r in rows:
                            bundles = [
                                (r, r + 1, a, b)
                                for a, b in segment_columns(inputs.shape[1], width, MARGIN)
                            ]
                            results = solve_bundles(inputs, config, bundles)
                            labels = stitch(
                                [res.columns for res in results],
                                [res.labels for res in results],
                                inputs.shape[1],
                            )
                            row_costs = inputs.costs(base, r, r + 1)
                            found.extend(row_gaps(row_costs, labels, optimum[r]))
                        seconds = (time.perf_counter() - started) / len(rows)
                        print(
                            f"| {name} | {inputs.plan.index} | {inputs.count} | "
                            f"{solver} | {encoding.value} | {width or 'whole row'} | "
                            f"{100 * statistics.median(found):.2f} | {100 * max(found):.2f} | "
                            f"{seconds:.2f} |",
                            flush=True,
                        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=["price", "gaps"])
    parser.add_argument("--data", type=Path, default=default_middlebury_dir())
    parser.add_argument("--scenes")
    parser.add_argument("--widths", default="32,64,128")
    parser.add_argument("--rows", type=int, default=4, help="gaps: rows sampled per level")
    parser.add_argument("--solvers", default="sa,tabu,qpu-sim,hybrid-sim")
    parser.add_argument("--hybrid-rows", type=int, default=1, help="gaps: rows for hybrid-sim")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--maps", type=Path, help="price: write error maps (PNG) here")
    args = parser.parse_args()
    if args.what == "price":
        args.scenes = args.scenes or "tsukuba,venus,cones"
        price(args)
    else:
        args.scenes = args.scenes or "tsukuba,cones"
        gaps(args)


if __name__ == "__main__":
    main()
