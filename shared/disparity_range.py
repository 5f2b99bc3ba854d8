"""``max_disparity: auto``: the disparity range estimated from sparse feature matches.

ORB features of both views are matched (Hamming distance, Lowe's ratio test, rows within 1 px,
as a rectified pair requires). The horizontal offsets x_L - x_R of the surviving matches sample
the scene's disparities; the nearest surfaces are often poorly textured or partly occluded, so
the estimate is a high percentile of the positive offsets widened by a relative and an absolute
margin. Too wide a range costs time and a little accuracy; too narrow a range loses the
nearest objects, so the margins err on the wide side.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import cv2
import numpy as np

from shared.images import to_gray

FEATURES = 3000
RATIO = 0.8
ROW_TOLERANCE = 1.0
PERCENTILE = 99.0
RELATIVE_MARGIN = 1.2
ABSOLUTE_MARGIN = 4.0
#: Fewer matches than this and the estimate falls back to a share of the image width.
MIN_MATCHES = 20
FALLBACK_WIDTH_SHARE = 0.25
LIMIT = 1024


@dataclass(frozen=True)
class RangeEstimate:
    """The chosen maximum disparity (full-resolution px) and how it was found."""

    max_disparity: int
    source: str  # "given", "auto" or "auto-fallback"
    matches: int = 0
    note: str = ""

    def as_dict(self) -> dict:
        return asdict(self)


def _as_uint8(view: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(to_gray(view) * 255.0), 0, 255).astype(np.uint8)


def match_offsets(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Horizontal offsets x_L - x_R (px) of ORB matches that pass the ratio and row tests."""
    orb = cv2.ORB_create(nfeatures=FEATURES, fastThreshold=5)
    keys_left, desc_left = orb.detectAndCompute(_as_uint8(left), None)
    keys_right, desc_right = orb.detectAndCompute(_as_uint8(right), None)
    if desc_left is None or desc_right is None or len(keys_right) < 2:
        return np.zeros(0, dtype=np.float32)
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(desc_left, desc_right, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < RATIO * p[1].distance]
    if not good:
        return np.zeros(0, dtype=np.float32)
    points_left = np.array([keys_left[m.queryIdx].pt for m in good], dtype=np.float32)
    points_right = np.array([keys_right[m.trainIdx].pt for m in good], dtype=np.float32)
    same_row = np.abs(points_left[:, 1] - points_right[:, 1]) <= ROW_TOLERANCE
    return (points_left[same_row, 0] - points_right[same_row, 0]).astype(np.float32)


def estimate_max_disparity(left: np.ndarray, right: np.ndarray) -> RangeEstimate:
    """The maximum disparity of a rectified pair, estimated without any ground truth."""
    width = left.shape[1]
    ceiling = max(1, min(LIMIT, width - 1))
    offsets = match_offsets(left, right)
    positive = offsets[offsets > 0]
    if positive.size < MIN_MATCHES:
        guess = max(1, min(ceiling, math.ceil(FALLBACK_WIDTH_SHARE * width)))
        return RangeEstimate(
            guess,
            "auto-fallback",
            int(positive.size),
            f"only {positive.size} feature matches; assumed a quarter of the width. Give "
            "--max-disparity if you know the range",
        )
    note = ""
    if np.median(offsets) < 0:
        note = "most matches have negative disparity: are the left and right views swapped?"
    high = float(np.percentile(positive, PERCENTILE))
    value = math.ceil(RELATIVE_MARGIN * high + ABSOLUTE_MARGIN)
    return RangeEstimate(max(1, min(ceiling, value)), "auto", int(positive.size), note)


def resolve_max_disparity(
    left: np.ndarray, right: np.ndarray, max_disparity: int | str
) -> RangeEstimate:
    """The run's maximum disparity: the given one, or the estimate when it is ``auto``."""
    if isinstance(max_disparity, int):
        return RangeEstimate(max_disparity, "given")
    return estimate_max_disparity(left, right)
