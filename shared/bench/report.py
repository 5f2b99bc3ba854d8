"""The bench's outputs for people: per-run images, log lines and the Markdown report.

Per scene ``OUT/<scene>/<experiment>-<variant>.png`` (disparity preview), ``.pfm`` (the
disparity) and ``-error.png`` (error map); ``OUT/results.md`` has one table per experiment with
the paper's figures beside ours.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from shared.bench.scoring import Run
from shared.datasets import Scene
from shared.images import preview_png, save_disparity
from shared.metrics import Truth

#: Errors above this many pixels saturate the error-map colours.
ERROR_MAP_MAX = 4.0

TABLE_HEADER = (
    "| scene | variant | RMSE | BPP % | RMSE nonocc | BPP nonocc % | BPP disc % | wall s "
    "| paper RMSE | paper BPP % | avgerr | bad-0.5 % | bad-2 % | bad-4 % | D1 % "
    "| bad-2 nonocc % | note |\n"
    "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"
)
#: The measures after the paper's columns (``Scores`` fields), all pixels.
EXTRA_COLUMNS = ("avgerr", "bad_0_5", "bad_2", "bad_4", "d1")


def fmt(value: float | None, digits: int = 2) -> str:
    """A figure as the report prints it.

    Parameters
    ----------
    value
        The figure, or None where there is none.
    digits
        Decimal places.

    Returns
    -------
    str
        ``"n/a"`` for a missing or non-finite figure, else the rounded value.
    """
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "n/a"
    return f"{value:.{digits}f}"


def error_map_png(errors: np.ndarray, saturation: float = ERROR_MAP_MAX) -> bytes:
    """Encode an error map as a PNG.

    Parameters
    ----------
    errors
        |d - gt| per pixel (px), NaN where not evaluated.
    saturation
        Errors at or above this many pixels get the brightest colour.

    Returns
    -------
    bytes
        A PNG: black where not evaluated, inferno colours up to ``saturation``.
    """
    known = np.isfinite(errors)
    scaled = np.clip(np.where(known, errors, 0.0) / saturation, 0.0, 1.0)
    colours = cv2.applyColorMap((scaled * 255).astype(np.uint8), cv2.COLORMAP_INFERNO)
    colours[~known] = 0
    ok, buf = cv2.imencode(".png", colours)
    if not ok:
        raise RuntimeError("OpenCV could not encode the error map")
    return buf.tobytes()


def write_images(
    run: Run, disparity: np.ndarray, scene: Scene, gt: np.ndarray | None, out: Path
) -> None:
    """Write a run's preview, disparity and error map below ``out``; record them in ``run.files``.

    Parameters
    ----------
    run
        The run (its experiment and variant name the files; ``files`` is filled in).
    disparity
        The full-resolution left-view disparity (px).
    scene
        The scene (its folder name, disparity range and protocol).
    gt
        The stored ground truth, or None (then no error map is written).
    out
        The bench's output folder.
    """
    folder = out / scene.name
    folder.mkdir(parents=True, exist_ok=True)
    stem = f"{run.experiment}-{run.variant}"
    preview = folder / f"{stem}.png"
    preview.write_bytes(preview_png(disparity, scene.max_disparity))
    raw = save_disparity(disparity, folder / f"{stem}.pfm")
    run.files = {"preview": _relative(preview, out), "disparity": _relative(raw, out)}
    if gt is not None:
        errors = folder / f"{stem}-error.png"
        errors.write_bytes(error_map_png(Truth(gt, scene.scale, scene.border).error_map(disparity)))
        run.files["error_map"] = _relative(errors, out)


def _relative(path: Path, root: Path) -> str:
    return path.relative_to(root).as_posix()


def log_line(run: Run) -> str:
    """One finished run as the bench logs it.

    Parameters
    ----------
    run
        The finished run.

    Returns
    -------
    str
        Scene, variant and figures (or the status and reason), with an estimated range.
    """
    head = f"{run.scene} {run.experiment}/{run.variant}:"
    if run.status != "ok":
        return f"{head} {run.status} ({run.reason})"
    line = f"{head} RMSE {fmt(run.rmse)} BPP {fmt(run.bpp)} in {fmt(run.seconds)} s"
    found = run.info.get("disparity_range")
    if found and found["source"] != "given":
        line += f" (range {found['max_disparity']} px, {found['source']})"
    return line


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def markdown(results: dict) -> str:
    """The Markdown report: one table per experiment, per-scene rows and each variant's average.

    Parameters
    ----------
    results
        The data :func:`shared.bench.run_bench` writes to ``results.json``.

    Returns
    -------
    str
        The text of ``results.md``.
    """
    lines = [
        "# qhsm bench results",
        "",
        f"Dataset `{results['dataset']}`, created {results['created']}"
        + (f", service {results['url']}" if results["url"] else ", in process")
        + f"; machine: {results['machine']['platform']}, {results['machine']['cpus']} CPUs.",
    ]
    if results["command"]:
        lines += ["", "Command: `" + " ".join(results["command"]) + "`"]
    lines += [
        "",
        "Protocol: left-view disparity; RMSE and BPP (|d - gt| > 1 px, in %) over every pixel "
        "with known ground truth outside the scene's border; *disc* uses the v2 evaluation mask "
        "where the scene has it, *nonocc* the non-occluded pixels (the nonocc mask, else the "
        "ground truth's left-right check). Wall time is the whole run of the scene. "
        "Paper figures: n/a where unknown.",
        "",
        "| scene | layout | GT scale | border px | max disparity (from) | masks "
        "| non-occluded from |",
        "|---|---|---:|---:|---:|---|---|",
    ]
    for name, protocol in results["scenes"].items():
        lines.append(
            _row(
                [
                    name,
                    protocol["layout"],
                    f"{protocol['scale']:g}",
                    str(protocol["border"]),
                    f"{protocol['max_disparity']} ({protocol.get('max_disparity_source', '?')})",
                    ", ".join(protocol["masks"]) or "none",
                    protocol["non_occlusion"],
                ]
            )
        )
    averages_by_key = {(a["experiment"], a["variant"]): a for a in results["averages"]}
    for experiment in dict.fromkeys(run["experiment"] for run in results["runs"]):
        lines += ["", f"## {experiment}", "", TABLE_HEADER]
        runs = [run for run in results["runs"] if run["experiment"] == experiment]
        for variant in dict.fromkeys(run["variant"] for run in runs):
            for run in (r for r in runs if r["variant"] == variant):
                lines.append(_row(_run_cells(run)))
            average = averages_by_key.get((experiment, variant))
            if average is not None and len(results["scenes"]) > 1:
                lines.append(_row(_average_cells(average)))
    lines += ["", "Known figures of the paper (the rest of its table is not reproduced here):", ""]
    lines += ["| solver | scene | RMSE | BPP % |", "|---|---|---:|---:|"]
    for figure in results["paper"]:
        lines.append(
            _row([figure["solver"], figure["scene"], fmt(figure["rmse"]), fmt(figure["bpp"])])
        )
    return "\n".join(lines) + "\n"


def _run_cells(run: dict) -> list[str]:
    nonocc, disc = run["masks"].get("nonocc", {}), run["masks"].get("disc", {})
    paper = run["paper"] or {}
    note = run["reason"]
    if run["status"] != "ok":
        note = f"{run['status']}: {note}"
    if paper and paper.get("source") != run["solver"]:
        note = (note + "; " if note else "") + f"paper figure is {paper['source']}'s"
    return [
        run["scene"],
        run["variant"],
        fmt(run["rmse"]),
        fmt(run["bpp"]),
        fmt(nonocc.get("rmse")),
        fmt(nonocc.get("bpp")),
        fmt(disc.get("bpp")),
        fmt(run["seconds"]),
        fmt(paper.get("rmse")),
        fmt(paper.get("bpp")),
        *(fmt(run.get("metrics", {}).get(key)) for key in EXTRA_COLUMNS),
        fmt(nonocc.get("bad_2")),
        note.replace("|", "/").replace("\n", " "),
    ]


def _average_cells(average: dict) -> list[str]:
    masks = average["masks"]
    return [
        "**average**",
        average["variant"],
        fmt(average["rmse"]),
        fmt(average["bpp"]),
        fmt(masks.get("nonocc", {}).get("rmse")),
        fmt(masks.get("nonocc", {}).get("bpp")),
        fmt(masks.get("disc", {}).get("bpp")),
        fmt(average["seconds"]),
        "n/a",
        "n/a",
        *(fmt(average.get("metrics", {}).get(key)) for key in EXTRA_COLUMNS),
        "n/a",
        f"over {', '.join(average['scenes'])}",
    ]
