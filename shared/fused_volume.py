"""The census + gradient volume of a block by the kernels of :mod:`shared.volume_kernels`,
:data:`CHUNK` disparities at a time with OpenCV's ``exp`` between them: called through
:mod:`shared.kernels` (the compiled module when one is built, else numba), so that a process with
the compiled module builds its volumes without importing numba."""

from __future__ import annotations

import cv2
import numpy as np

from shared import kernels

#: Disparities whose gradient terms go through OpenCV's exp in one call.
CHUNK = 8


def build(
    inputs: tuple,
    block_rows: int,
    max_disparity: int,
    bin_width: int,
    table: np.ndarray,
    volume: np.ndarray | None = None,
    lowest: np.ndarray | None = None,
    count: int = 0,
) -> np.ndarray:
    """The block's volume binned at ``bin_width`` into ``volume`` (or a new array), or with
    ``lowest`` (rows, w) the (rows, w, ``count``) costs of each pixel's window of bins only
    (the disparities outside every window skipped): the kernels :data:`CHUNK` disparities at a
    time, their exponents through OpenCV's exp in one call between them."""
    census_left, census_right, gradients_left, gradients_right = inputs
    rows, width = census_left.shape
    start, stop = 0, max_disparity + 1
    if lowest is not None:
        out = np.empty((*lowest.shape, count), np.float32)
        start = int(lowest.min()) * bin_width
        stop = min(stop, (int(lowest.max()) + count) * bin_width)
    elif volume is None:
        out = np.empty((max_disparity // bin_width + 1, block_rows, width), np.float32)
    else:
        out = volume
    terms = np.empty((min(CHUNK, max(stop - start, 1)), rows, width), np.float32)
    for first in range(start, stop, CHUNK):
        chunk = terms[: min(CHUNK, stop - first)]
        kernels.gradient_exponents(*gradients_left, *gradients_right, max_disparity, first, chunk)
        flat = chunk.reshape(-1, width)
        cv2.exp(flat, dst=flat)
        codes = (census_left, census_right, chunk, table, max_disparity, first, bin_width)
        if lowest is None:
            kernels.census_aggregate(*codes, out)
        else:
            kernels.census_window(*codes, lowest, out)
    return out
