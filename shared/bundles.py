"""Bundles: blocks of consecutive epipolar lines (rows), or segments of them, one QUBO each.

Inside a bundle every pixel links to its 4-neighbours in the bundle; edges between bundles are
dropped, so bundles are independent problems that can be solved anywhere in any order.

A row too wide for the solver (a QPU's graph) is cut into *segments* of one width that overlap
by a margin. The last segment of a row is shifted left so that it has the full width too: every
segment of a level then has the same QUBO structure, and one minor embedding serves them all.
Stitching gives each pixel the label of the segment in which it lies farthest from a cut: in the
overlap of two neighbouring segments that is the left one up to the middle of the overlap and
the right one after it (:func:`owned_columns`). Far from a cut a segment's solution equals the
whole row's once the cut's influence has decayed (the MRF's correlation length along the row), so
the margin trades solver size for that error.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise

import numpy as np


@dataclass(frozen=True, order=True)
class Bundle:
    """Rows [row_start, row_stop) x columns [col_start, col_stop) of a level."""

    row_start: int
    row_stop: int
    col_start: int
    col_stop: int

    @property
    def shape(self) -> tuple[int, int]:
        return self.row_stop - self.row_start, self.col_stop - self.col_start

    def as_list(self) -> list[int]:
        """The bundle as JSON-friendly ``[row_start, row_stop, col_start, col_stop]``.

        Returns
        -------
        list of int
            The four bounds, in the order of :class:`Bundle`'s fields.
        """
        return [self.row_start, self.row_stop, self.col_start, self.col_stop]


def bundle_rows(height: int, bundle_height: int) -> list[tuple[int, int]]:
    """Row ranges [start, stop) that tile ``height`` rows; the last bundle may be shorter.

    Parameters
    ----------
    height : int
        Rows of the level.
    bundle_height : int
        Rows per bundle, at least 1.

    Returns
    -------
    list of tuple of int
        ``(start, stop)`` of every bundle, top to bottom.

    Raises
    ------
    ValueError
        If ``bundle_height`` is below 1.
    """
    if bundle_height < 1:
        raise ValueError("bundle_height must be at least 1")
    starts = range(0, height, bundle_height)
    return [(start, min(start + bundle_height, height)) for start in starts]


def segment_columns(width: int, bundle_width: int | None, margin: int) -> list[tuple[int, int]]:
    """Column ranges [start, stop) of a row's segments: all ``bundle_width`` wide (the last one
    shifted left to keep that width), consecutive ones overlapping by at least ``margin``.
    ``None`` or a width of at least the row's gives the whole row.

    Parameters
    ----------
    width : int
        Columns of the row.
    bundle_width : int or None
        Columns per segment; ``None`` for whole rows.
    margin : int
        Least overlap of consecutive segments, below half of ``bundle_width``.

    Returns
    -------
    list of tuple of int
        ``(start, stop)`` of every segment, left to right.

    Raises
    ------
    ValueError
        If ``2 * margin`` is not below ``bundle_width``.
    """
    if bundle_width is None or bundle_width >= width:
        return [(0, width)]
    if not 0 <= 2 * margin < bundle_width:
        raise ValueError(
            f"the segment margin ({margin}) must be below half the bundle width ({bundle_width})"
        )
    stride = bundle_width - margin
    segments = []
    start = 0
    while True:
        if start + bundle_width >= width:
            start = width - bundle_width
            segments.append((start, width))
            return segments
        segments.append((start, start + bundle_width))
        start += stride


def owned_columns(segments: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """The columns each segment (sorted by start, together tiling a row) labels in the stitched
    row: in each overlap the left segment keeps the pixels up to the middle, where both cuts are
    equally far, and the right one the rest; so a pixel is labelled by the segment in which it
    lies farthest from a cut. The ranges tile the row exactly once.

    Parameters
    ----------
    segments : list of tuple of int
        ``(start, stop)`` of a row's segments, as from :func:`segment_columns`.

    Returns
    -------
    list of tuple of int
        ``(start, stop)`` of the columns each segment labels, in the same order.
    """
    cuts = [(stop + start) // 2 for (_, stop), (start, _) in pairwise(segments)]
    bounds = [segments[0][0], *cuts, segments[-1][1]]
    return list(pairwise(bounds))


def bundle_key(spec: list[int] | tuple[int, ...]) -> str:
    """A bundle's id within its level, from [row_start, row_stop] (whole rows) or
    [row_start, row_stop, col_start, col_stop]: the first row for whole rows and first
    segments (a level's bundles are all whole rows or all segments), else "row.column".

    Parameters
    ----------
    spec : list or tuple of int
        ``[row_start, row_stop]`` or ``[row_start, row_stop, col_start, col_stop]``.

    Returns
    -------
    str
        ``"ROW"`` or ``"ROW.COLUMN"``.
    """
    if len(spec) > 2 and spec[2]:
        return f"{spec[0]}.{spec[2]}"
    return str(spec[0])


def bundle_seed(seed: int, level: int, row_start: int, col_start: int = 0) -> int:
    """A solver seed per bundle that depends only on (seed, level, first row, first column).

    In-process runs and distributed runs therefore give identical results for the same seed,
    whatever the grouping of bundles into tasks or their order. (Whole rows, column 0, keep the
    seeds they had before segments existed.)

    Seeds are below 2**31: dwave-samplers rejects larger ones despite its message.

    Parameters
    ----------
    seed : int
        The run's seed.
    level : int
        Pyramid level index.
    row_start, col_start : int
        First row and first column of the bundle.

    Returns
    -------
    int
        A seed in ``[0, 2**31)``.
    """
    entropy = [seed, level, row_start] + ([col_start] if col_start else [])
    return int(np.random.SeedSequence(entropy).generate_state(1)[0] >> 1)
