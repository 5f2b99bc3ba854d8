"""Data terms: what it costs to say that left-view pixel (y, x) has disparity d.

``squared`` (the paper) is evaluated at a level's candidates only:

    c(y, x, d) = (I_L(y, x) - I_R(y, x - d))^2            gray images in [0, 1]

``ad-census`` is a cost volume over every disparity 0..D, aggregated by a 5x5 box (mean):

    c(y, x, d) = 1/2 [(1 - exp(-AD / 10)) + (1 - exp(-H / 30))]

with AD the mean absolute colour difference on the 0..255 scale (gray inputs: the gray
difference) and H the Hamming distance between the 5x5 census codes of the gray images
(bit = neighbour darker than the centre).

``census-gradient`` (the accurate default) replaces the colour term by a gradient term, which
does not move with the exposure or colour balance of either camera:

    c(y, x, d) = 1/2 [(1 - exp(-H / 30)) + (1 - exp(-G / 10))]
    G = |dI_L/dx - dI_R/dx| + |dI_L/dy - dI_R/dy|       (Sobel 3x3 / 4, gray on 0..255)

In every term right-image columns x - d < 0 are clamped to column 0. Rows beyond a view's
border replicate its first or last row, so a block of rows gets exactly the values it would get
as part of the whole image: costs are computed per block of rows (memory bounded by the block,
not the image) and blocks can be computed anywhere.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np

from shared import fused_volume, kernels
from shared.images import to_gray

#: AD-census constants: the exponential scales of the terms and the window sizes.
AD_SCALE = 10.0
GRADIENT_SCALE = 10.0
CENSUS_SCALE = 30.0
CENSUS_WINDOW = 5
AGGREGATION_WINDOW = 5
#: Volumes (of a block) of at least this many bytes are built by compiled kernels
#: (:func:`_fused_census_gradient`: the same floats); smaller ones by OpenCV and NumPy, which
#: spares a small pair numba's import.
FUSED_VOLUME_BYTES = 16 * 2**20
#: A view whose whole volume is at least this large takes the compiled kernels even before
#: numba is loaded (:func:`_fused`).
FUSED_VIEW_BYTES = 2**30
#: Image rows a block of cost rows needs on each side (census reach + aggregation reach).
HALO = CENSUS_WINDOW // 2 + AGGREGATION_WINDOW // 2


@dataclass(frozen=True)
class VolumeBlock:
    """The part of a view's cost volume to build: disparities 0..``max_disparity`` of the rows
    [``start``, ``stop``) (the views' other rows are context)."""

    max_disparity: int
    start: int
    stop: int

    @property
    def rows(self) -> int:
        """Rows of the block."""
        return self.stop - self.start

    def within(self, scratch: np.ndarray | None) -> np.ndarray | None:
        """The block's volume (D + 1, rows, w) in the first elements of ``scratch`` (a buffer for
        the largest block, or None): contiguous, as the compiled kernels take it (a slice of
        the rows is not, and sent a shorter last block to numba's import and JIT)."""
        if scratch is None:
            return None
        shape = (scratch.shape[0], self.rows, scratch.shape[-1])
        return scratch.reshape(-1)[: shape[0] * shape[1] * shape[2]].reshape(shape)


class VolumeFunction(Protocol):
    """A data term as a cost volume: ``(left, right, block, out=None)`` -> costs
    (D + 1, ``block.rows``, w) of the term's dtype (:func:`volume_dtype`).

    ``left`` and ``right`` are whole views (h, w) gray or (h, w, 3) BGR in [0, 1] (rows outside
    the block are context); ``out`` (the term's dtype, any strides) receives the costs, which
    are returned: a buffer reused from block to block of rows saves the page faults of a fresh
    64 MiB array per block (5 % of an Art x3 run).
    """

    def __call__(
        self,
        left: np.ndarray,
        right: np.ndarray,
        block: VolumeBlock,
        out: np.ndarray | None = None,
    ) -> np.ndarray: ...


def squared_difference(left: np.ndarray, right: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """(I_L(y, x) - I_R(y, x - d))^2 for every candidate d of (h, w, K) gray images' pixels.

    Parameters
    ----------
    left, right : numpy.ndarray
        Gray views (h, w) in [0, 1].
    candidates : numpy.ndarray
        Integer disparities (h, w, K) of every pixel; columns left of the image read column 0.

    Returns
    -------
    numpy.ndarray
        Costs (h, w, K), float64.
    """
    height, width, _ = candidates.shape
    columns = np.arange(width)[None, :, None] - candidates
    np.clip(columns, 0, width - 1, out=columns)
    rows = np.arange(height)[:, None, None]
    diff = left[:, :, None].astype(np.float64) - right[rows, columns]
    return diff * diff


def squared_volume(
    left: np.ndarray, right: np.ndarray, block: VolumeBlock, out: np.ndarray | None = None
) -> np.ndarray:
    """:class:`VolumeFunction` of the squared difference, float64, at every disparity (what the
    bin pyramid needs to take a bin's minimum); colour views are turned gray."""
    max_disparity, rows = block.max_disparity, slice(block.start, block.stop)
    left_rows = to_gray(left[rows]).astype(np.float64)
    right_rows = _shifted(to_gray(right[rows]).astype(np.float64), max_disparity)
    width = left_rows.shape[1]
    return np.stack(
        [
            (left_rows - right_rows[:, max_disparity - d : max_disparity - d + width]) ** 2
            for d in range(max_disparity + 1)
        ],
        out=out,
    )


def census(gray: np.ndarray) -> np.ndarray:
    """5x5 census codes (24 bits) of the rows 2..n-3 of ``gray`` (n, w); columns replicate.

    Parameters
    ----------
    gray : numpy.ndarray
        Gray rows (n, w), n > 4.

    Returns
    -------
    numpy.ndarray
        Census codes (n - 4, w), uint32: one bit per neighbour, set where it is darker.
    """
    reach = CENSUS_WINDOW // 2
    rows, width = gray.shape
    if gray.dtype == np.float32 and kernels.ready(kernels.census_codes):  # 7x these passes
        codes = np.empty((max(rows - 2 * reach, 0), width), dtype=np.uint32)
        kernels.census_codes(np.ascontiguousarray(gray), codes)
        return codes
    padded = np.pad(gray, ((0, 0), (reach, reach)), mode="edge")
    centre = gray[reach : rows - reach]
    code = np.zeros(centre.shape, dtype=np.uint32)
    darker = np.empty(centre.shape, dtype=bool)  # in place: no temporary array per neighbour
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):
            if dy == 0 and dx == 0:
                continue
            neighbour = padded[reach + dy : rows - reach + dy, reach + dx : reach + dx + width]
            np.left_shift(code, np.uint32(1), out=code)
            np.bitwise_or(code, np.less(neighbour, centre, out=darker), out=code)
    return code


def _shifted(image: np.ndarray, max_disparity: int) -> np.ndarray:
    """``image`` with ``max_disparity`` replicated copies of column 0 in front: column
    ``max_disparity + x - d`` of the result is column ``max(x - d, 0)`` of the image."""
    pad = [(0, 0), (max_disparity, 0)] + [(0, 0)] * (image.ndim - 2)
    return np.pad(image, pad, mode="edge")


def _block_rows(view: np.ndarray, block: VolumeBlock) -> np.ndarray:
    """Row numbers of the block and its HALO context, borders replicated."""
    return np.clip(np.arange(block.start - HALO, block.stop + HALO), 0, view.shape[0] - 1)


def ad_census_volume(
    left: np.ndarray, right: np.ndarray, block: VolumeBlock, out: np.ndarray | None = None
) -> np.ndarray:
    """:class:`VolumeFunction` of the aggregated AD-census costs, float32 (colour differences
    when the views are BGR): by the census kernel when it runs without numba's import (the
    quick match of every run's views' check: 1.7x faster on Aloe), else by OpenCV, the same
    floats (module doc of :mod:`shared.volume_kernels`: the costs are exact multiples of 2^-26
    either way)."""
    max_disparity = block.max_disparity
    rows = _block_rows(left, block)
    left_rows = left[rows].astype(np.float32) * np.float32(255.0)
    right_rows = right[rows].astype(np.float32) * np.float32(255.0)
    census_left = census(to_gray(left_rows))
    census_right = _shifted(census(to_gray(right_rows)), max_disparity)
    census_reach = CENSUS_WINDOW // 2
    left_rows = left_rows[census_reach:-census_reach]
    right_rows = _shifted(right_rows[census_reach:-census_reach], max_disparity)
    channel_mean = np.full((1, 3), 1.0 / 3.0, dtype=np.float32)
    width = census_left.shape[1]

    def exponent(disparity: int, out: np.ndarray | None = None) -> np.ndarray:
        """-AD / AD_SCALE at ``disparity`` (AD the colours' mean absolute difference)."""
        columns = slice(max_disparity - disparity, max_disparity - disparity + width)
        ad = cv2.absdiff(left_rows, right_rows[:, columns])
        if ad.ndim == 3:
            ad = cv2.transform(ad, channel_mean)
        return np.multiply(ad, np.float32(-1.0 / AD_SCALE), out=ad if out is None else out)

    if kernels.ready(kernels.census_aggregate):

        def fill(chunk: np.ndarray, first: int) -> None:
            for offset, plane in enumerate(chunk):
                exponent(first + offset, plane)

        codes, table = (census_left, census_right), _census_table()
        return fused_volume.build(codes, fill, block.rows, max_disparity, 1, table, out)

    def ad_term(columns: slice) -> np.ndarray:
        return cv2.exp(exponent(max_disparity - columns.start))

    return _census_and(census_left, census_right, ad_term, block, out)


CensusGradientInputs = tuple[np.ndarray, np.ndarray, list[np.ndarray], list[np.ndarray]]


def _census_gradient_inputs(
    left: np.ndarray, right: np.ndarray, block: VolumeBlock
) -> CensusGradientInputs:
    """The census codes and Sobel gradients of the block's rows and context (the right view's
    :func:`_shifted`): what every disparity's census + gradient cost reads."""
    max_disparity = block.max_disparity
    rows = _block_rows(left, block)
    gray_left = to_gray(left[rows]).astype(np.float32) * np.float32(255.0)
    gray_right = to_gray(right[rows]).astype(np.float32) * np.float32(255.0)
    reach = CENSUS_WINDOW // 2
    return (
        census(gray_left),
        _shifted(census(gray_right), max_disparity),
        [g[reach:-reach] for g in _sobel(gray_left)],
        [_shifted(g[reach:-reach], max_disparity) for g in _sobel(gray_right)],
    )


def _fused(block: VolumeBlock, view: np.ndarray) -> bool:
    """Whether the block of ``view``'s volume goes to the kernels: a large block, when they run
    without waiting for numba's import (compiled ahead of time, or numba loaded already) or the
    view's volume is so large (built in blocks, level after level) that numba's import (~0.4 s
    of CPU) is worth it; else OpenCV (the same floats)."""
    volume_bytes = (block.max_disparity + 1) * view.shape[1] * 4
    if volume_bytes * block.rows < FUSED_VOLUME_BYTES:
        return False
    return volume_bytes * view.shape[0] >= FUSED_VIEW_BYTES or kernels.ready(
        kernels.gradient_exponents, kernels.census_aggregate, kernels.census_window
    )


def census_gradient_volume(
    left: np.ndarray, right: np.ndarray, block: VolumeBlock, out: np.ndarray | None = None
) -> np.ndarray:
    """:class:`VolumeFunction` of the aggregated census + gradient costs, float32 (colour is
    not read: colour views are turned gray)."""
    census_left, census_right, gradients_left, gradients_right = inputs = _census_gradient_inputs(
        left, right, block
    )
    if _fused(block, left):
        return _fused_census_gradient(inputs, block, 1, out)

    def gradient_term(columns: slice) -> np.ndarray:
        gradient = cv2.add(
            cv2.absdiff(gradients_left[0], gradients_right[0][:, columns]),
            cv2.absdiff(gradients_left[1], gradients_right[1][:, columns]),
        )
        return cv2.exp(np.multiply(gradient, np.float32(-1.0 / GRADIENT_SCALE), out=gradient))

    return _census_and(census_left, census_right, gradient_term, block, out)


def binned_cost_volume(
    data_term: str,
    left: np.ndarray,
    right: np.ndarray,
    block: VolumeBlock,
    bin_width: int,
    scratch: np.ndarray | None = None,
) -> np.ndarray:
    """:func:`bin_minimum` of :func:`cost_volume` (``scratch``: a buffer of the full volume's
    shape, which the result may be a view of). A large census + gradient block goes straight
    into its bins by the compiled kernels: the full volume is neither written nor read again
    (the same floats: the least of the same costs)."""
    if data_term == "census-gradient" and bin_width > 1 and _fused(block, left):
        bins = block.max_disparity // bin_width + 1
        out = None if scratch is None else scratch[:bins]
        return _fused_census_gradient(
            _census_gradient_inputs(left, right, block), block, bin_width, out
        )
    return bin_minimum(cost_volume(data_term, left, right, block, scratch), bin_width)


def _census_table() -> np.ndarray:
    """table[H] = 1/2 (1 - exp(-H / 30)) + 1/2 (float32), so that cost = table[H] - term / 2."""
    table = np.zeros(256, dtype=np.float32)
    table[: CENSUS_WINDOW**2] = 0.5 * (1.0 - np.exp(-np.arange(CENSUS_WINDOW**2) / CENSUS_SCALE))
    table += 0.5
    return table


def _fused_census_gradient(
    inputs: CensusGradientInputs,
    block: VolumeBlock,
    bin_width: int,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """:func:`_census_and` of the gradient term binned at ``bin_width`` (:func:`bin_minimum`)
    by the kernels (:func:`shared.fused_volume.build`: the same floats), into
    ``out`` (or a new array) of shape (bins, block rows, w)."""
    table, fill = _census_table(), fused_volume.gradients(inputs, block.max_disparity)
    return fused_volume.build(
        inputs[:2], fill, block.rows, block.max_disparity, bin_width, table, out
    )


def window_costs(
    data_term: str,
    left: np.ndarray,
    right: np.ndarray,
    block: VolumeBlock,
    bin_width: int,
    lowest: np.ndarray,
    count: int,
) -> np.ndarray | None:
    """(block rows, w, ``count``) float32 costs of each pixel's bins ``lowest`` ..
    ``lowest + count - 1`` (:func:`gather_window` of :func:`binned_cost_volume`, the same
    floats) straight from the compiled kernels, a tile at a time over the disparities of the
    tile's windows (:func:`shared.fused_volume.windows`); None when the kernels do not build
    this block (the caller gathers)."""
    if data_term != "census-gradient" or not _fused(block, left):
        return None
    inputs = _census_gradient_inputs(left, right, block)
    table = _census_table()
    reach = AGGREGATION_WINDOW // 2
    return fused_volume.windows(inputs, block.max_disparity, bin_width, table, lowest, count, reach)


def _census_and(
    census_left: np.ndarray,
    census_right: np.ndarray,
    term: Callable[[slice], np.ndarray],
    block: VolumeBlock,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """The volume 1/2 [(1 - exp(-H / 30)) + (1 - term)] of every disparity, 5x5 box-aggregated:
    H from the census codes (the right view's :func:`_shifted`), ``term(columns)`` the other
    term's exp(-x / scale) with the right view read at ``columns``; each has the block's rows
    plus the aggregation's reach on both sides; written into ``out`` when given."""
    width = census_left.shape[1]
    table = _census_table()
    box = (AGGREGATION_WINDOW, AGGREGATION_WINDOW)
    reach = AGGREGATION_WINDOW // 2
    max_disparity = block.max_disparity
    volume = np.empty((max_disparity + 1, block.rows, width), np.float32) if out is None else out
    # scratch for the codes' differing bits and their count, reused at every disparity
    differing = np.empty(census_left.shape, dtype=census_left.dtype)
    hamming = np.empty(census_left.shape, dtype=np.uint8)
    for d in range(max_disparity + 1):
        columns = slice(max_disparity - d, max_disparity - d + width)
        np.bitwise_xor(census_left, census_right[:, columns], out=differing)
        np.bitwise_count(differing, out=hamming)
        cost = cv2.scaleAdd(term(columns), -0.5, cv2.LUT(hamming, table))
        aggregated = cv2.boxFilter(cost, -1, box, borderType=cv2.BORDER_REPLICATE)
        volume[d] = aggregated[reach:-reach]
    return volume


def _sobel(gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal and vertical Sobel 3x3 derivatives / 4 of gray rows (replicated borders)."""
    return (
        cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3, scale=0.25, borderType=cv2.BORDER_REPLICATE),
        cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3, scale=0.25, borderType=cv2.BORDER_REPLICATE),
    )


#: Every data term as a cost volume over all disparities, by its ``MatchConfig.data_term`` name:
#: a new data term is one function here and one name in :class:`shared.config.DataTerm`.
VOLUMES: dict[str, VolumeFunction] = {
    "squared": squared_volume,
    "ad-census": ad_census_volume,
    "census-gradient": census_gradient_volume,
}


def window_reach(data_term: str) -> int:
    """Columns at an image edge whose costs under ``data_term`` read the replicated border: at
    the right edge both views' windows are padded alike only at disparity 0, which biases those
    pixels to 0 (the left-right check then confirms the bias: issue 27)."""
    return 0 if data_term == "squared" else HALO


def cost_volume(
    data_term: str,
    left: np.ndarray,
    right: np.ndarray,
    block: VolumeBlock,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """The :class:`VolumeFunction` of the :class:`shared.config.DataTerm` named ``data_term``
    (:data:`VOLUMES`) applied to the other arguments."""
    return VOLUMES[data_term](left, right, block, out=out)


def volume_dtype(data_term: str) -> type:
    """The dtype of ``data_term``'s :func:`cost_volume`."""
    return np.float64 if data_term == "squared" else np.float32


def bin_minimum(volume: np.ndarray, bin_width: int) -> np.ndarray:
    """(bins, n, w): each bin's cost is the least cost over its ``bin_width`` disparities.

    Parameters
    ----------
    volume : numpy.ndarray
        Costs (D + 1, n, w) per disparity.
    bin_width : int
        Disparities per bin; the last bin may be narrower.

    Returns
    -------
    numpy.ndarray
        Costs (ceil((D + 1) / bin_width), n, w) per bin (``volume`` itself for width 1).
    """
    if bin_width == 1:
        return volume
    # strided minima: the same values as np.minimum.reduceat, 10-20x faster on (D + 1, h, w);
    # the first two sub-bins straight into the result (no copy of the first, ~1/4 of the time)
    lowest = volume[::bin_width]
    binned = np.empty_like(lowest)
    second = volume[1::bin_width]
    np.minimum(lowest[: len(second)], second, out=binned[: len(second)])
    binned[len(second) :] = lowest[len(second) :]
    for offset in range(2, bin_width):
        part = volume[offset::bin_width]
        np.minimum(binned[: len(part)], part, out=binned[: len(part)])
    return binned


def gather(per_label: np.ndarray, candidates: np.ndarray, dtype: type = np.float64) -> np.ndarray:
    """(n, w, K) costs of the candidate labels from a (labels, n, w) stack.

    Parameters
    ----------
    per_label : numpy.ndarray
        Costs (labels, n, w) of every label.
    candidates : numpy.ndarray
        Labels (n, w, K) to pick at every pixel.
    dtype : type, optional
        Of the result (float32 for a grid: the volume's own precision).

    Returns
    -------
    numpy.ndarray
        Costs (n, w, K), ``dtype``.
    """
    return _take(per_label, candidates.astype(np.intp)).astype(dtype, copy=False)


def gather_window(
    per_label: np.ndarray, first: np.ndarray, count: int, dtype: type = np.float64
) -> np.ndarray:
    """:func:`gather` of the candidates ``first, first + 1, ..., first + count - 1`` (a bin
    level's window), from each pixel's first label alone: no (n, w, K) candidate array.

    Parameters
    ----------
    per_label : numpy.ndarray
        Costs (labels, n, w) of every label.
    first : numpy.ndarray
        Each pixel's first candidate label (n, w).
    count : int
        Candidates per pixel.
    dtype : type, optional
        Of the result.

    Returns
    -------
    numpy.ndarray
        Costs (n, w, count), ``dtype``.
    """
    index = np.empty((*first.shape, count), dtype=np.intp)
    np.add(first[:, :, None], np.arange(count, dtype=np.intp), out=index)
    return _take(per_label, index).astype(dtype, copy=False)


def window_minimum(
    volume: np.ndarray,
    top: int,
    lowest: np.ndarray,
    count: int,
    bin_width: int,
    dtype: type = np.float64,
) -> np.ndarray | None:
    """:func:`gather_window` of :func:`bin_minimum` of rows ``top`` .. ``top + len(lowest)`` of
    ``volume``, without the binned volume, by the compiled kernel (the same floats:
    :func:`shared.volume_kernels.window_minima`); None when the kernel does not take these
    arrays (the caller bins and gathers).

    Parameters
    ----------
    volume : numpy.ndarray
        Costs (D + 1, h, w) per disparity (or per bin of a narrower width).
    top : int
        The volume's row of ``lowest``'s first row.
    lowest : numpy.ndarray
        Each pixel's first bin (rows, w).
    count : int
        Bins per window.
    bin_width : int
        Planes of ``volume`` per bin.
    dtype : type, optional
        Of the result.

    Returns
    -------
    numpy.ndarray or None
        Costs (rows, w, count), ``dtype``.

    Raises
    ------
    IndexError
        If a window reaches outside the bins (as :func:`gather_window`).
    """
    rows = lowest.shape[0]
    if not (
        window_minimum_runs(volume)
        and lowest.dtype == np.int32
        and lowest.flags.c_contiguous
        and 0 <= top <= top + rows <= volume.shape[1]
        and lowest.shape[1] == volume.shape[2]
    ):
        return None
    bins = -(-volume.shape[0] // bin_width)
    if lowest.size and (lowest.min() < 0 or int(lowest.max()) + count > bins):
        raise IndexError(f"a window of {count} bins reaches outside the {bins} bins")
    costs = np.empty((*lowest.shape, count), dtype=np.float32)
    kernels.window_minima(volume, top, lowest, bin_width, costs)
    return costs.astype(dtype, copy=False)


def window_minimum_runs(volume: np.ndarray) -> bool:
    """Whether :func:`window_minimum` reads windows from ``volume`` now (float32, C-contiguous,
    the kernel running without numba's import: :func:`shared.kernels.ready`) given each
    pixel's first bin as C-contiguous int32 rows."""
    return (
        volume.dtype == np.float32
        and volume.flags.c_contiguous
        and kernels.ready(kernels.window_minima)
    )


def _take(per_label: np.ndarray, index: np.ndarray) -> np.ndarray:
    """The costs (n, w, K) of the labels ``index`` (n, w, K) intp, which become indices in
    place: the label's cost is ``flat[label * plane + row * row_step + column * column_step]``
    in a 1-D view of the memory of ``per_label`` (labels, n, w). One flat array gathers 1.5-2x
    faster than ``take_along_axis`` over the label axis moved last; a block of rows of a view's
    volume (a strided slice) needs no copy, and the pixels' offsets are added by broadcasting
    (no (n, w) offset arrays: 64 MB at 2000 x 2000)."""
    if any(stride < 0 or stride % per_label.itemsize for stride in per_label.strides):
        per_label = np.ascontiguousarray(per_label)
    plane, row_step, column_step = (stride // per_label.itemsize for stride in per_label.strides)
    labels, rows, columns = per_label.shape
    span = (labels - 1) * plane + (rows - 1) * row_step + (columns - 1) * column_step + 1
    flat = np.lib.stride_tricks.as_strided(
        per_label, shape=(span,), strides=(per_label.itemsize,), writeable=False
    )
    index *= plane
    index += (np.arange(rows, dtype=np.intp) * row_step)[:, None, None]
    index += (np.arange(columns, dtype=np.intp) * column_step)[None, :, None]
    return flat.take(index)
