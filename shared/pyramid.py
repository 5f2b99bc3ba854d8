"""Coarse-to-fine pyramid: image sizes per level and each level's candidate disparities.

Disparities at a level are in that level's pixels. The coarsest level spreads its candidates
evenly over [0, max disparity]; each finer level looks at the window {2d-2, ..., 2d+1} around the
upsampled coarser estimate d, shifted (not cropped) so that the whole window stays inside
[0, max disparity]. Ground truth is never read here.
"""

from __future__ import annotations

import cv2
import numpy as np


def level_shape(shape: tuple[int, int], downsample: int) -> tuple[int, int]:
    """(height, width) of an image of ``shape`` downsampled by an integer factor."""
    height, width = shape
    return max(1, round(height / downsample)), max(1, round(width / downsample))


def downsample(image: np.ndarray, factor: int) -> np.ndarray:
    """Anti-aliased downsampling (area averaging) by an integer factor."""
    if factor == 1:
        return image
    height, width = level_shape(image.shape[:2], factor)
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)


def level_max_disparity(max_disparity: int, downsample_factor: int) -> int:
    """Largest disparity of a level, in that level's pixels."""
    return max(1, max_disparity // downsample_factor)


def initial_candidates(shape: tuple[int, int], count: int, max_disparity: int) -> np.ndarray:
    """Candidates of the coarsest level: ``count`` integers spread evenly over [0, max].

    With the paper's defaults (max 20 px, 1/4 resolution, 6 candidates) these are 0..5.
    Returns an int32 array of shape (h, w, count).
    """
    values = np.rint(np.linspace(0, max_disparity, count)).astype(np.int32)
    if max_disparity + 1 < count:  # fewer distinct disparities than candidates: repeat the top
        values = np.minimum(np.arange(count, dtype=np.int32), max_disparity)
    return np.broadcast_to(values, (*shape, count)).copy()


def refined_candidates(
    coarse_disparity: np.ndarray, shape: tuple[int, int], count: int, max_disparity: int
) -> np.ndarray:
    """Candidates of a finer level from the coarser level's (filtered) disparity map.

    The coarse map is upsampled to ``shape`` (nearest neighbour) and doubled; the window
    starts at 2d - 2 (for 4 candidates: {2d-2, ..., 2d+1}) and is shifted into [0, max].
    """
    height, width = shape
    upsampled = cv2.resize(
        np.asarray(coarse_disparity, dtype=np.float32),
        (width, height),
        interpolation=cv2.INTER_NEAREST,
    )
    start = np.rint(2.0 * upsampled).astype(np.int32) - count // 2
    start = np.clip(start, 0, max(0, max_disparity - count + 1))
    candidates = start[:, :, None] + np.arange(count, dtype=np.int32)
    return np.minimum(candidates, max_disparity)


def upsample_disparity(disparity: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Scale a level's disparity map to ``shape`` and to that resolution's pixel units."""
    height, width = shape
    factor = width / disparity.shape[1]
    resized = cv2.resize(
        np.asarray(disparity, dtype=np.float32), (width, height), interpolation=cv2.INTER_NEAREST
    )
    return resized * np.float32(factor)
