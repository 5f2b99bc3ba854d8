"""The census + gradient volume of a block by the kernels of :mod:`shared.volume_kernels`,
:data:`CHUNK` disparities at a time with OpenCV's ``exp`` between them: called through
:mod:`shared.kernels` (the compiled module when one is built, else numba), so that a process with
the compiled module builds its volumes without importing numba. The AD-census volume takes the
same census kernel with OpenCV's colour differences as its other term (:func:`build`)."""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from shared import kernels

#: Disparities whose gradient terms go through OpenCV's exp in one call.
CHUNK = 8
#: Rows and columns of the tiles whose window costs are built each over its own disparities
#: (:func:`windows`): a tile of a smooth map needs a few dozen of a large range's disparities;
#: smaller tiles recompute more of their aggregation's margins.
TILE_ROWS = 32
TILE_COLUMNS = 128

#: The census codes, the right codes shifted, the left and the right (shifted) gradients.
Inputs = tuple[np.ndarray, np.ndarray, list[np.ndarray], list[np.ndarray]]
#: A census kernel's call on a chunk: its arguments up to the bin width, then its output's.
Aggregate = Callable[..., None]
#: ``fill(chunk, first)``: the other term's exponents (before OpenCV's exp) of disparities
#: ``first``, ``first + 1``, ... into ``chunk`` (count, rows, w).
Fill = Callable[[np.ndarray, int], None]


def gradients(inputs: Inputs, max_disparity: int) -> Fill:
    """The census + gradient cost's :data:`Fill`: the gradient kernel."""
    _, _, gradients_left, gradients_right = inputs

    def fill(chunk: np.ndarray, first: int) -> None:
        kernels.gradient_exponents(*gradients_left, *gradients_right, max_disparity, first, chunk)

    return fill


def _chunks(
    codes: tuple[np.ndarray, np.ndarray],
    fill: Fill,
    max_disparity: int,
    bin_width: int,
    table: np.ndarray,
    disparities: range,
    aggregate: Aggregate,
) -> None:
    """``aggregate`` over ``disparities`` :data:`CHUNK` at a time, their other terms filled in
    and put through OpenCV's exp in one call between the two."""
    census_left, census_right = codes
    rows, width = census_left.shape
    terms = np.empty((min(CHUNK, max(len(disparities), 1)), rows, width), np.float32)
    for first in range(disparities.start, disparities.stop, CHUNK):
        chunk = terms[: min(CHUNK, disparities.stop - first)]
        fill(chunk, first)
        flat = chunk.reshape(-1, width)
        cv2.exp(flat, dst=flat)
        aggregate(census_left, census_right, chunk, table, max_disparity, first, bin_width)


def build(
    codes: tuple[np.ndarray, np.ndarray],
    fill: Fill,
    block_rows: int,
    max_disparity: int,
    bin_width: int,
    table: np.ndarray,
    volume: np.ndarray | None = None,
) -> np.ndarray:
    """The block's volume of census codes ``codes`` (left, right shifted) and the other term
    ``fill`` gives, binned at ``bin_width``, into ``volume`` (or a new array)."""
    width = codes[0].shape[1]
    if volume is None:
        volume = np.empty((max_disparity // bin_width + 1, block_rows, width), np.float32)
    out = volume

    def aggregate(*arguments: object) -> None:
        kernels.census_aggregate(*arguments, out)

    _chunks(codes, fill, max_disparity, bin_width, table, range(max_disparity + 1), aggregate)
    return out


def windows(
    inputs: Inputs,
    max_disparity: int,
    bin_width: int,
    table: np.ndarray,
    lowest: np.ndarray,
    count: int,
    reach: int,
) -> np.ndarray:
    """The (rows, w, ``count``) costs of each pixel's window of bins ``lowest`` (rows, w)
    onwards, a tile at a time, each tile over the disparities of its own windows only: at a
    fine level of a large range a block's windows span the range, a tile's a few dozen, and a
    tile across a depth edge skips the disparities between its two surfaces' windows
    (:func:`needed_runs`; every disparity's costs are built on their own, the same floats).

    A tile's kernels read ``reach`` (the aggregation's half width) more columns on each side
    (the box sums are exact integers: the same floats as one pass over the block) and the
    right view's columns its disparities reach, with a maximum disparity of the tile's own:
    the right codes are read at ``max_disparity - d + x``."""
    rows, width = lowest.shape
    context = inputs[0].shape[0] - rows  # the aggregation's rows above and below
    out = np.empty((rows, width, count), np.float32)
    beyond = np.iinfo(np.int32).max  # no window: the margins' pixels are not written
    for top in range(0, rows, TILE_ROWS):
        bottom = min(top + TILE_ROWS, rows)
        for left in range(0, width, TILE_COLUMNS):
            right = min(left + TILE_COLUMNS, width)
            start, stop = max(left - reach, 0), min(right + reach, width)
            here = lowest[top:bottom, left:right]
            runs = needed_runs(here, count, bin_width, max_disparity)
            first, last = runs[0][0], runs[-1][1]
            # the right view's columns of disparities first .. last at columns start .. stop
            shifted = slice(max_disparity - last + start, max_disparity - first + stop)
            band = slice(top, bottom + context)
            tile = (
                np.ascontiguousarray(inputs[0][band, start:stop]),
                np.ascontiguousarray(inputs[1][band, shifted]),
                [np.ascontiguousarray(g[band, start:stop]) for g in inputs[2]],
                [np.ascontiguousarray(g[band, shifted]) for g in inputs[3]],
            )
            tile_lowest = np.full((bottom - top, stop - start), beyond, np.int32)
            tile_lowest[:, left - start : right - start] = here
            costs = np.empty((bottom - top, stop - start, count), np.float32)

            def aggregate(*codes: object) -> None:
                kernels.census_window(*codes, tile_lowest, costs)  # noqa: B023 - called here

            fill = gradients(tile, last)
            for run_first, run_last in runs:
                disparities = range(run_first, run_last + 1)
                _chunks(tile[:2], fill, last, bin_width, table, disparities, aggregate)
            out[top:bottom, left:right] = costs[:, left - start : right - start]
    return out


def needed_runs(
    lowest: np.ndarray, count: int, bin_width: int, max_disparity: int
) -> list[tuple[int, int]]:
    """The disparities of the bins ``lowest`` .. ``lowest + count - 1`` of a tile's pixels, as
    runs ``(first, last)`` of whole bins, ascending (up to ``max_disparity``): the union of
    the windows, with the gaps between them left out.

    Parameters
    ----------
    lowest : numpy.ndarray
        Each pixel's first bin (non-empty, non-negative).
    count : int
        Bins per window.
    bin_width : int
        Disparities per bin.
    max_disparity : int
        The range's last disparity (the last bin may be narrower).

    Returns
    -------
    list of tuple of int
    """
    base = int(lowest.min())
    present = np.bincount((lowest - base).ravel()) > 0
    # bin b is needed where a window starts at one of b - count + 1 .. b
    starts = np.concatenate([[0], np.cumsum(present)])
    span = np.arange(len(present) + count - 1)
    needed = starts[np.minimum(span + 1, len(present))] > starts[np.maximum(span - count + 1, 0)]
    edges = np.flatnonzero(np.diff(np.concatenate([[False], needed, [False]]).astype(np.int8)))
    last_bin = max_disparity // bin_width
    runs = []
    for run_start, run_stop in zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True):
        first, stop = base + run_start, min(base + run_stop, last_bin + 1)
        if first < stop:
            runs.append((first * bin_width, min(max_disparity, stop * bin_width - 1)))
    return runs
