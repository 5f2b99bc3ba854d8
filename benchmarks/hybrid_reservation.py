"""What a ``hybrid`` worker reserves for a level (issue 27, item 4): the task's bundles as the
worker gets them, before roof duality (``batch_estimate``, what workers reserved before: with
the residual design the tiles the host's settling leaves) against the level's estimate the job
is accepted with (what they reserve now), on Tsukuba shrunk.

    python benchmarks/hybrid_reservation.py 0.125:4 0.17:6 0.25:8

Each argument is ``scale:max_disparity``. Classical work only: nothing is sent. Prints markdown
rows for docs/benchmarks.md.
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2

from shared import settle
from shared.config import MatchConfig
from shared.images import load_pair
from shared.inference import settles
from shared.pipeline import match_views, plan_run, prepare_level
from shared.residual import job_residual
from shared.solvers.meters import qpu_time
from shared.solvers.registry import resolve

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "middlebury" / "tsukuba"


def row(scale: float, max_disparity: int) -> str:
    """One scene size: the first level's accepted estimate and both reservations."""
    config = MatchConfig(solver="hybrid", max_disparity=max_disparity)
    left, right = load_pair(DATA / "left.ppm", DATA / "right.ppm")
    size = (round(left.shape[1] * scale), round(left.shape[0] * scale))
    left, right = (cv2.resize(view, size, interpolation=cv2.INTER_AREA) for view in (left, right))
    residual = job_residual(config, left, right, max_disparity, None)
    accepted = qpu_time.job_seconds(resolve(config), left.shape[:2], max_disparity, None, residual)
    _, plans = plan_run(left, right, config)
    inputs = prepare_level(*match_views(left, right, config), config, plans[0])
    sent = config
    if settles(config):  # as the control task does: the tiles the host leaves
        settle.prepare(inputs, config)
        sent = settle.tile_config(config)
    before = qpu_time.batch_estimate(
        inputs, sent, inputs.planned_bundles(sent), solver=resolve(sent)
    )
    now = accepted.levels[0].seconds
    scene = f"{size[0]}x{size[1]}, range {max_disparity}"
    return f"| {scene} | {now:.1f} s | {before:.1f} s ({before / now:.1f}x) | {now:.1f} s |"


def main(arguments: list[str]) -> None:
    print("| Tsukuba | level 1 estimate | reserved before | reserved now |")
    print("|---|---|---|---|")
    for argument in arguments:
        scale, max_disparity = argument.split(":")
        print(row(float(scale), int(max_disparity)))


if __name__ == "__main__":
    main(sys.argv[1:] or ["0.125:4", "0.17:6", "0.25:8"])
