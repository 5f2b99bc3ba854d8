"""The generalisation benchmark's verdict: each variant against the SGBM baseline, scene by scene
and over the scenes where both ran, and the Markdown report of ``results.json``'s data (the runs
themselves: :mod:`shared.bench.generalisation`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from typing import Any

import numpy as np

from shared.bench.report import fmt
from shared.bench.scoring import Run

BASELINE = "sgbm"
#: The figure compared: bad pixels (> 1 px, %) on the non-occluded pixels.
MAIN_MASK = "nonocc"


def _main_bpp(run: Run) -> float | None:
    """The compared figure: BPP on the non-occluded pixels; on a scene that cannot tell them
    (no mask, no right-view ground truth: KITTI), on every pixel with known ground truth."""
    if run.status != "ok":
        return None
    figure = run.masks.get(MAIN_MASK)
    return run.bpp if figure is None else float(figure["bpp"])


def compare(runs: list[Run], baseline: str = BASELINE) -> list[dict[str, Any]]:
    """Each variant against the baseline, scene by scene, and over the scenes where both ran.

    Parameters
    ----------
    runs
        Every run (variants and the baseline) of the benchmark.
    baseline
        The baseline's variant name.

    Returns
    -------
    list of dict
        Per variant (in run order): ``rows`` (scene, ``ours`` and ``baseline`` non-occluded BPP
        %, ``ratio``, ``result`` win / loss / tie, all-pixel RMSE and BPP of both, seconds),
        ``wins``, ``losses``, ``ties``, ``scenes`` compared, ``mean`` and ``baseline_mean``
        over them, their ``ratio``, and ``missing`` (scenes where either did not run, with the
        reason).
    """
    reference = {run.scene: run for run in runs if run.variant == baseline}
    table = []
    for variant in dict.fromkeys(run.variant for run in runs if run.variant != baseline):
        rows, missing = [], []
        for run in (r for r in runs if r.variant == variant):
            other = reference.get(run.scene)
            ours, theirs = _main_bpp(run), None if other is None else _main_bpp(other)
            if other is None or ours is None or theirs is None:
                missing.append({"scene": run.scene, "reason": _why_missing(run, other)})
                continue
            rows.append(
                {
                    "scene": run.scene,
                    "ours": ours,
                    "baseline": theirs,
                    "ratio": ours / theirs if theirs > 0 else None,
                    "result": "win" if ours < theirs else "loss" if ours > theirs else "tie",
                    "rmse_all": run.rmse,
                    "bpp_all": run.bpp,
                    "baseline_rmse_all": other.rmse,
                    "baseline_bpp_all": other.bpp,
                    "seconds": run.seconds,
                }
            )
        outcomes = [row["result"] for row in rows]
        mean = float(np.mean([row["ours"] for row in rows])) if rows else None
        baseline_mean = float(np.mean([row["baseline"] for row in rows])) if rows else None
        table.append(
            {
                "variant": variant,
                "rows": rows,
                "scenes": len(rows),
                "wins": outcomes.count("win"),
                "losses": outcomes.count("loss"),
                "ties": outcomes.count("tie"),
                "mean": mean,
                "baseline_mean": baseline_mean,
                "ratio": mean / baseline_mean if mean is not None and baseline_mean else None,
                "missing": missing,
            }
        )
    return table


def _why_missing(run: Run, baseline: Run | None) -> str:
    """Why a scene has no comparison: a run that did not finish, or no non-occluded figure."""
    if baseline is None:
        return "the baseline did not run"
    failed = run if run.status != "ok" else baseline
    return f"{failed.variant} {failed.status}: {failed.reason}"


def _row(cells: Iterable[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _ratio(value: float | None) -> str:
    return "n/a" if value is None or not math.isfinite(value) else f"{value:.2f}x"


def markdown(data: dict[str, Any]) -> str:
    """The report: scene protocols, then per variant the table against the baseline.

    Parameters
    ----------
    data
        What :func:`results` returns.

    Returns
    -------
    str
        Markdown (``results.md``; the benchmark also prints it).
    """
    lines = ["# Generalisation benchmark", ""]
    if data["command"]:
        lines += ["Command: `" + " ".join(data["command"]) + "`", ""]
    machine = data["machine"]
    lines += [
        f"Created {data['created']} on {machine['platform']}, {machine['cpus']} CPUs, load "
        f"average {fmt((machine['load_average'] or [None])[0], 1)} at the end; "
        f"{data['processes']} processes; wall time {data['wall_seconds']:.0f} s.",
        "",
        "Main figure: bad pixels (|d - gt| > 1 px, %) over the non-occluded pixels with known "
        "ground truth (the dataset's nonocc mask, else the ground truth's left-right check within "
        "1 px); range given = ceil of the ground truth's maximum. *all*: RMSE / BPP over every "
        "pixel with known ground truth outside the border (`qhsm eval`). Baseline: OpenCV "
        "StereoSGBM (colour, block 5, P1 600, P2 2400, 8 paths, invalid pixels filled).",
        "",
        "| scene | GT scale | border | range px | non-occluded from |",
        "|---|---:|---:|---:|---|",
    ]
    for name, protocol in data["scenes"].items():
        cells = [name, f"{protocol['scale']:g}", str(protocol["border"])]
        lines.append(_row([*cells, str(protocol["max_disparity"]), protocol["non_occlusion"]]))
    summary = data["comparison"]
    if len(summary) > 1:
        lines += ["", "| variant | wins | mean % | SGBM mean % | ratio |"]
        lines += ["|---|---:|---:|---:|---:|"]
        for entry in summary:
            cells = [entry["variant"], f"{entry['wins']} / {entry['scenes']}"]
            cells += [fmt(entry["mean"]), fmt(entry["baseline_mean"]), _ratio(entry["ratio"])]
            lines.append(_row(cells))
    for entry in summary:
        description = data["variants"][entry["variant"]]
        lines += [
            "",
            f"## {entry['variant']}",
            "",
            f"Preset {description['preset']}, solver {description['solver']}, changes "
            f"`{json.dumps(description['changes'])}`.",
            "",
            "| scene | ours % | SGBM % | ours / SGBM | result | ours RMSE / BPP all "
            "| SGBM RMSE / BPP all | ours s |",
            "|---|---:|---:|---:|---|---:|---:|---:|",
        ]
        for row in entry["rows"]:
            cells = [row["scene"], fmt(row["ours"]), fmt(row["baseline"]), _ratio(row["ratio"])]
            cells += [row["result"], f"{fmt(row['rmse_all'], 3)} / {fmt(row['bpp_all'])}"]
            cells += [f"{fmt(row['baseline_rmse_all'], 3)} / {fmt(row['baseline_bpp_all'])}"]
            lines.append(_row([*cells, fmt(row["seconds"], 1)]))
        lines += [
            "",
            f"**{entry['variant']}: fewer bad pixels than SGBM on {entry['wins']} of "
            f"{entry['scenes']} scenes** ({entry['losses']} losses, {entry['ties']} ties); "
            f"average {fmt(entry['mean'])} % vs SGBM {fmt(entry['baseline_mean'])} % "
            f"({_ratio(entry['ratio'])}).",
        ]
        for gone in entry["missing"]:
            lines.append(f"- {gone['scene']}: not compared ({gone['reason']})")
    return "\n".join(lines) + "\n"
