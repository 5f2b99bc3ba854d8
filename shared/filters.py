"""Post-processing of disparity maps: a median filter per level and a bilateral filter at the end
(the paper's "No B" / "No M No B" ablations switch them off)."""

from __future__ import annotations

import cv2
import numpy as np


def median(disparity: np.ndarray, size: int = 7) -> np.ndarray:
    """Median filter with edge replication.

    Level disparities are integers; OpenCV's fast median needs uint8 above size 5, so maps that
    fit in uint8 take that path and anything else (fractions, > 255) goes through SciPy.
    """
    if size <= 1:
        return disparity
    disparity = np.asarray(disparity, np.float32)
    as_bytes = disparity.astype(np.uint8)
    if np.array_equal(as_bytes, disparity):
        padded = cv2.copyMakeBorder(as_bytes, *(size // 2,) * 4, cv2.BORDER_REPLICATE)
        pad = size // 2
        return cv2.medianBlur(padded, size)[pad:-pad, pad:-pad].astype(np.float32)
    from scipy import ndimage  # slow to import; only needed off the fast path

    return ndimage.median_filter(disparity, size=size, mode="nearest")


def bilateral(
    disparity: np.ndarray, diameter: int, sigma_color: float, sigma_space: float
) -> np.ndarray:
    """Edge-preserving smoothing of the disparity map (sigma_color in disparity pixels)."""
    return cv2.bilateralFilter(
        np.asarray(disparity, np.float32), diameter, sigma_color, sigma_space
    )
