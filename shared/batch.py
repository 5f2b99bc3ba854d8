"""``qhsm batch``: match every stereo pair below a folder and tabulate the results.

Pairs are the scene folders :func:`shared.datasets.find_datasets` recognises (our layout,
Middlebury 2001-2014's) and KITTI's own layout (``image_2/*_10.png`` with ``image_3``, ground
truth in ``disp_occ_0`` or ``disp_noc_0``, objects in ``obj_map``). Each pair's range is the one
given, else its stated one (protocol.json, Middlebury's calib.txt ndisp, a known scene), else
estimated (``auto``); the table says which for every pair. The ground truth's own maximum is
never used as the range (that would tell the matcher the answer). Each pair's map and its
validity, confidence and provenance maps go to ``OUT/<dataset>/<scene>.pfm``, ``.valid.png``,
``.confidence.pfm`` and ``.provenance.png``; the table counts the provenance map's pixels per
stage (``decided_<stage>`` columns).
"""

from __future__ import annotations

import csv
import json
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from shared.config import AUTO, MatchConfig
from shared.datasets.calibration import CalibrationError
from shared.datasets.scenes import find_datasets
from shared.images import load_disparity_values, load_mask

#: The measures in the table, per region (``Scores`` fields).
COLUMNS = ("rmse", "avgerr", "bad_0_5", "bad_1", "bad_2", "bad_4", "d1", "bpp")


@dataclass
class Pair:
    """One stereo pair to match, with what scores it."""

    name: str
    left: Path
    right: Path
    gt: Path | None = None
    scale: float = 1.0
    border: int = 0
    max_disparity: int | None = None  # None: estimated
    range_source: str = "estimated (auto)"
    regions: dict[str, Path] = field(default_factory=dict)  # nonocc / fg mask files
    calib: Path | None = None  # the scene's calibration file (Middlebury calib.txt)
    nonocc: Any = None  # a callable giving the non-occluded pixels, when the scene tells


def scene_pairs(root: Path) -> Iterator[Pair]:
    """The scene folders below ``root``, their ranges as stated (never the ground truth's)."""
    for scenes in find_datasets(root).values():
        for scene in scenes.values():
            stated = scene.range_is_stated
            yield Pair(
                name=scene.qualified_name,
                left=scene.left,
                right=scene.right,
                gt=scene.gt,
                scale=scene.scale,
                border=scene.border,
                max_disparity=scene.max_disparity if stated else None,
                range_source=scene.max_disparity_source if stated else "estimated (auto)",
                nonocc=scene.non_occluded if scene.non_occlusion != "none" else None,
                calib=scene.calibration,
            )


def kitti_pairs(root: Path) -> Iterator[Pair]:
    """KITTI's layout: ``image_2/N_10.png`` and ``image_3/N_10.png``, ground truth x 256."""
    for left in sorted((root / "image_2").glob("*_10.png")):
        right = root / "image_3" / left.name
        if not right.is_file():
            continue
        gt = next(
            (root / d / left.name for d in ("disp_occ_0", "disp_noc_0", "disp_occ", "disp_noc")
             if (root / d / left.name).is_file()),
            None,
        )  # fmt: skip
        regions = {}
        if (root / "obj_map" / left.name).is_file():
            regions["fg"] = root / "obj_map" / left.name
        if gt is not None and (root / "disp_noc_0" / left.name).is_file():
            regions["nonocc"] = root / "disp_noc_0" / left.name
        yield Pair(f"{root.name}/{left.stem}", left, right, gt, 256.0, 0, regions=regions)


def find_pairs(root: str | Path) -> list[Pair]:
    """Every pair below ``root`` (a KITTI folder, or scene folders), by name."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: no such directory")
    pairs = list(kitti_pairs(root)) if (root / "image_2").is_dir() else list(scene_pairs(root))
    if not pairs:
        raise FileNotFoundError(
            f"{root}: no stereo pair found (scene folders with left/right, Middlebury's file "
            "names, or KITTI's image_2/image_3)"
        )
    return sorted(pairs, key=lambda pair: pair.name)


def score_row(pair: Pair, disparity: np.ndarray) -> dict[str, Any]:
    """The pair's measures (all pixels, and nonocc / bg / fg where it has them)."""
    from shared.ground_truth import evaluate_ground_truth

    if pair.gt is None:
        return {}
    values = load_disparity_values(pair.gt)
    nonocc = None
    if "nonocc" in pair.regions:
        nonocc = load_disparity_values(pair.regions["nonocc"]) > 0
    elif pair.nonocc is not None:
        nonocc = pair.nonocc(values)
    foreground = load_mask(pair.regions["fg"]) if "fg" in pair.regions else None
    evaluation = evaluate_ground_truth(
        disparity, values, scale=pair.scale, border=pair.border, nonocc=nonocc,
        foreground=foreground,
    )  # fmt: skip
    row: dict[str, Any] = {}
    for region, scores in evaluation.scores.items():
        prefix = "" if region == "all" else f"{region}_"
        figures = scores.as_dict()
        row.update({f"{prefix}{key}": figures[key] for key in COLUMNS})
    return row


def run_batch(
    root: str | Path,
    out: str | Path,
    config: MatchConfig,
    range_given: bool,
    force: bool = False,
    processes: int = 0,
) -> list[dict[str, Any]]:
    """Match every pair below ``root`` into ``out`` (``<name>.pfm``, its maps and sidecar) and
    write ``out/results.csv`` and ``results.json``: one row per pair, failures included with
    their reason. ``range_given``: ``config.max_disparity`` holds for every pair."""
    from tqdm import tqdm

    from shared.images import load_pair, save_disparity, save_maps
    from shared.pipeline import run_pipeline
    from shared.process_pool import ProcessPoolLevelSolver
    from shared.provenance import provenance

    out = Path(out)
    pairs = find_pairs(root)
    rows: list[dict[str, Any]] = []
    with ProcessPoolLevelSolver(processes) as solve_level:
        for pair in tqdm(pairs, desc="pairs", unit="pair", dynamic_ncols=True):
            top: int | str = AUTO
            source = pair.range_source
            if range_given:
                top, source = config.max_disparity, "given"
            elif pair.max_disparity is not None:
                top = pair.max_disparity
            run = config.model_copy(update={"max_disparity": top})
            row: dict[str, Any] = {"name": pair.name, "range_source": source}
            try:
                left, right = load_pair(pair.left, pair.right)
                with warnings.catch_warnings(record=True) as seen:
                    warnings.simplefilter("always")
                    result = run_pipeline(left, right, run, solve_level, force=force)
                output = save_disparity(result.disparity, out / f"{pair.name}.pfm")
                maps = save_maps(result.validity, result.confidence, output, result.provenance_map)
                row |= {
                    "status": "ok",
                    "max_disparity": result.disparity_range.max_disparity,
                    "seconds": round(result.seconds, 3),
                    "output": str(output),
                    **{f"{name}_map": path for name, path in maps.items()},
                    **{
                        f"decided_{stage}": pixels
                        for stage, pixels in (result.summary()["provenance_counts"] or {}).items()
                    },
                    "warnings": "; ".join(str(w.message) for w in seen),
                    **score_row(pair, result.disparity),
                }
            except (ValueError, OSError, CalibrationError) as error:
                row |= {"status": "failed", "reason": str(error)}
            rows.append(row)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(
        json.dumps({"provenance": provenance(config), "pairs": rows}, indent=2, default=str)
    )
    columns = list(dict.fromkeys(key for row in rows for key in row))
    with (out / "results.csv").open("w", newline="") as stream:
        writer = csv.DictWriter(stream, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    return rows
