"""Scoring: a run's figures under its scene's protocol, and each variant's mean over the scenes.

The main figures use every pixel with known ground truth outside the scene's border (as the
paper's table does); the v2 masks ``all``/``disc`` are scored as well where the scene has them,
and ``nonocc`` wherever the scene can tell its non-occluded pixels (its mask, else the ground
truth's left-right check: :meth:`shared.datasets.Scene.non_occluded`).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from shared.datasets import Scene
from shared.metrics import evaluate


@dataclass
class Run:
    """The outcome of one variant on one scene (``status``: ok, skipped or failed)."""

    scene: str
    experiment: str
    variant: str
    method: str
    solver: str | None
    status: str
    reason: str = ""
    rmse: float | None = None
    bpp: float | None = None
    pixels: int | None = None
    masks: dict[str, dict[str, float]] = field(default_factory=dict)
    #: Every measure of :class:`shared.metrics.Scores` on all pixels (avgerr, bad-x, D1, ...).
    metrics: dict[str, float] = field(default_factory=dict)
    seconds: float | None = None
    levels: list[dict] = field(default_factory=list)
    info: dict = field(default_factory=dict)
    paper: dict | None = None
    files: dict[str, str] = field(default_factory=dict)
    config: dict | None = None


def score(run: Run, disparity: np.ndarray, scene: Scene, gt: np.ndarray | None) -> None:
    """Fill in ``run``'s RMSE, BPP, pixel count and per-mask figures (nothing without a GT).

    ``run.masks["nonocc"]`` is there whenever the scene's non-occluded pixels are known (see the
    module doc), not only where a mask file is.

    Parameters
    ----------
    run
        The run record to complete (changed in place).
    disparity
        The full-resolution left-view disparity (px).
    scene
        The scene: its ground-truth scale, border and masks.
    gt
        The scene's ground truth as stored (scaled), or None where it has none.

    Raises
    ------
    ValueError
        Where the protocol leaves no pixel or the sizes differ (from :func:`evaluate`).
    """
    if gt is None:
        return
    main = evaluate(disparity, gt, scale=scene.scale, border=scene.border)
    run.rmse, run.bpp, run.pixels = main.rmse, main.bpp, main.pixels
    run.metrics = main.as_dict()
    masks = {name: scene.mask(name) for name in scene.masks}
    non_occluded = scene.non_occluded(gt)  # the mask, else the ground truth's left-right check
    if non_occluded is not None:
        masks["nonocc"] = non_occluded
    for name, mask in sorted(masks.items()):
        run.masks[name] = evaluate(
            disparity, gt, scale=scene.scale, border=scene.border, mask=mask
        ).as_dict()


#: The measures averaged per variant beside RMSE and BPP (their fields in ``Scores``).
AVERAGED = ("avgerr", "bad_0_5", "bad_1", "bad_2", "bad_4", "d1")


def averages(runs: list[Run]) -> list[dict]:
    """Mean figures per variant over the scenes where it ran.

    Parameters
    ----------
    runs
        Every run of the bench.

    Returns
    -------
    list of dict
        Per variant that ran somewhere: experiment, variant, scenes, mean RMSE, BPP, wall time,
        the other measures (``metrics``: avgerr, bad-x, D1) and per-mask RMSE/BPP (masks every
        such scene has), in run order.
    """
    table: list[dict] = []
    keys = list(dict.fromkeys((run.experiment, run.variant) for run in runs))
    for experiment, variant in keys:
        done = [
            r
            for r in runs
            if (r.experiment, r.variant) == (experiment, variant)
            and r.status == "ok"
            and r.rmse is not None
        ]
        if not done:
            continue
        masks = sorted(set.intersection(*(set(r.masks) for r in done)))
        table.append(
            {
                "experiment": experiment,
                "variant": variant,
                "scenes": [r.scene for r in done],
                "rmse": _mean(r.rmse for r in done),
                "bpp": _mean(r.bpp for r in done),
                "seconds": _mean(r.seconds for r in done),
                "metrics": {
                    key: _mean(r.metrics[key] for r in done)
                    for key in AVERAGED
                    if all(r.metrics.get(key) is not None for r in done)
                },
                "masks": {
                    name: {
                        "rmse": _mean(r.masks[name]["rmse"] for r in done),
                        "bpp": _mean(r.masks[name]["bpp"] for r in done),
                    }
                    for name in masks
                },
            }
        )
    return table


def _mean(values: Iterable) -> float:
    values = [float(v) for v in values]
    return float(np.mean(values))
