"""Post-processing of disparity maps: a median filter per level and a bilateral filter at the end
(the paper's "No B" / "No M No B" ablations switch them off)."""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage


def median(disparity: np.ndarray, size: int = 7) -> np.ndarray:
    """Median filter with edge replication (OpenCV's medianBlur needs uint8 above size 5)."""
    if size <= 1:
        return disparity
    return ndimage.median_filter(np.asarray(disparity, np.float32), size=size, mode="nearest")


def bilateral(
    disparity: np.ndarray, diameter: int = 9, sigma_color: float = 2.0, sigma_space: float = 5.0
) -> np.ndarray:
    """Edge-preserving smoothing of the disparity map (sigma_color in disparity pixels)."""
    return cv2.bilateralFilter(
        np.asarray(disparity, np.float32), diameter, sigma_color, sigma_space
    )
