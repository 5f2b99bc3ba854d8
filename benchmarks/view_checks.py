"""The checks of an uploaded pair on every scene with ground truth: the views-order check
(``shared.disparity_range.views_warning``) on the pair as given, swapped, and spoilt (a vertical
offset, a rotation), and the inferred ground-truth scale (``shared.ground_truth``) against the
known one. Prints the markdown table of docs/benchmarks.md ("Checks of the views").

    python benchmarks/view_checks.py [DATA]     # DATA: folder of dataset folders, default
                                                # ../shared/data (middlebury, 2005, 2006)
"""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

import cv2
import numpy as np

from shared.datasets import default_middlebury_dir, find_scenes
from shared.disparity_range import ViewsWarning, quick_match, views_warning
from shared.ground_truth import ScaleNotInferredError, infer_gt_scale
from shared.synthetic import make_scene

#: Ground-truth scale per dataset folder (PROVENANCE-2005-2006.md); 2001/2003 scenes: protocol.
DATASET_SCALE = {"middlebury2005": 3.0, "middlebury2006": 2.0}


def verdict(text: str) -> str:
    """The warning in a word or two: ok, swapped, not rectified, same image."""
    kinds = {
        "the views look swapped": "swapped",
        "the views do not look rectified": "not rectified",
        "the left and right views are the same": "same image",
    }
    for start, kind in kinds.items():
        if text.startswith(start):
            return kind
    return text or "ok"


def spoilt(view: np.ndarray, shift: float = 0.0, angle: float = 0.0) -> np.ndarray:
    """``view`` moved down by ``shift`` px and rotated by ``angle`` degrees about its centre."""
    height, width = view.shape[:2]
    matrix = cv2.getRotationMatrix2D((width / 2, height / 2), angle, 1.0)
    matrix[1, 2] += shift
    return cv2.warpAffine(view, matrix, (width, height), borderMode=cv2.BORDER_REPLICATE)


def row(name: str, left, right, truth, scale: float, other) -> str:
    started = time.perf_counter()
    forward, reverse = quick_match(left, right), quick_match(right, left)
    seconds = time.perf_counter() - started
    height, width = left.shape[:2]
    unrelated = cv2.resize(other, (width, height), interpolation=cv2.INTER_AREA)
    if unrelated.ndim != right.ndim:
        unrelated = unrelated if right.ndim == 3 else unrelated.mean(axis=2, dtype=np.float32)
    checks = [
        views_warning(left, right, forward),
        views_warning(right, left, reverse),
        views_warning(left, spoilt(right, shift=0.02 * height)),
        views_warning(left, spoilt(right, shift=0.05 * height)),
        views_warning(left, spoilt(right, angle=5)),
        views_warning(left, unrelated),
    ]
    try:
        inferred = infer_gt_scale(left, right, truth, forward)
        scale_text = f"{inferred.scale:g} ({inferred.ratio:.2f})"
        scale_text += "" if inferred.scale == scale else " **wrong**"
    except ScaleNotInferredError as error:
        scale_text = f"refused: {str(error)[:40]}"
    return (
        f"| {name} | {width}x{height} | {100 * forward.share:.0f} % / {100 * reverse.share:.0f} % "
        f"| {forward.share / max(reverse.share, 1e-9):.1f} | "
        + " | ".join(verdict(check) for check in checks)
        + f" | {scale:g} | {scale_text} | {seconds:.2f} |"
    )


def main() -> None:
    warnings.simplefilter("ignore", ViewsWarning)
    data = Path(sys.argv[1]) if len(sys.argv) > 1 else default_middlebury_dir().parent
    print(
        "| scene | size | confirmed: given / swapped order | ratio | as given | swapped "
        "| down 2 % | down 5 % | rotated 5° | unrelated right view | GT scale "
        "| inferred (median ratio) | 2 matches (s) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    scenes = [
        (f"{folder.name}/{name}", scene, DATASET_SCALE.get(folder.name, scene.scale))
        for folder in sorted(path for path in data.iterdir() if path.is_dir())
        for name, scene in find_scenes(folder).items()
        if scene.gt is not None
    ]
    previous = make_scene(96, 128, max_disparity=16, seed=9).right
    for name, scene, scale in scenes:
        left, right = scene.load()
        print(row(name, left, right, scene.ground_truth(), scale, previous))
        previous = right
    for seed in range(3):
        synthetic = make_scene(96, 128, max_disparity=16, seed=seed)
        print(row(f"synthetic {seed}", synthetic.left, synthetic.right, synthetic.disparity, 1,
                  previous))  # fmt: skip


if __name__ == "__main__":
    main()
