"""Compiled kernels of the census + gradient cost volume (:mod:`shared.data_terms`): the
per-disparity NumPy/OpenCV passes (XOR, bit count, table, two absolute differences, sum, scale,
exp, scale-add, 5x5 box filter, copy: a dozen passes over each disparity's plane, 23-52 % of a
large pair's run, issue 28) fused into two loops per disparity, with OpenCV's ``exp`` between
them (its float32 ``exp`` is its own approximation: it is called, not imitated):
:mod:`shared.fused_volume` drives them, through :mod:`shared.kernels` (compiled ahead of time
or just in time).

Why the results are OpenCV's bit for bit: every cost before aggregation is
``table[H] - exp_term / 2`` with ``table[H]`` in [0.5, 1) and ``exp_term`` in [0, 1] (float32),
so it is a multiple of 2^-26 in [0, 1): sums of 25 of them are exact in any order (here int32
in units of 2^-26, < 25 * 2^26), and ``cv2.boxFilter`` (float64 row and column sums, then
``sum * (1/25)`` rounded to float32) gives ``float32(exact_sum * (1/25))``, as here. The
element-wise float32 steps (absolute differences, their sum, the scale by -1/10,
``exp_term * -0.5 + table[H]``, exact products) round as OpenCV's do. ``nogil``: the views'
volumes are built in threads side by side.
"""

from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

#: Rows of the aggregation window, whose row sums are kept in a ring.
WINDOW = 5


@numba.njit(cache=True, nogil=True)
def gradient_exponents(
    left_x, left_y, right_x, right_y, max_disparity, first, out
):  # pragma: no cover - jit
    """``out[k]`` = -(|dxL - dxR| + |dyL - dyR|) / 10 (float32, as OpenCV's absdiff, add and
    multiply round) at disparity ``first + k``: the right view's (shifted) gradients read at
    column ``max_disparity - d + x``."""
    count, rows, width = out.shape
    scale = np.float32(-0.1)
    for k in range(count):
        shift = max_disparity - (first + k)
        for y in range(rows):
            # rows sliced first: indices from 0 vectorise (``shift + x`` kept them scalar, 4.5x)
            here_x, here_y, row = left_x[y], left_y[y], out[k, y]
            there_x = right_x[y, shift : shift + width]
            there_y = right_y[y, shift : shift + width]
            for x in range(width):
                row[x] = (abs(here_x[x] - there_x[x]) + abs(here_y[x] - there_y[x])) * scale


@numba.njit(cache=True, nogil=True)
def census_codes(gray, codes):  # pragma: no cover - jit
    """:func:`shared.data_terms.census` of ``gray`` (n, w) into ``codes`` (n - 4, w): each
    neighbour's bit in NumPy's order (rows, then columns, -2..2, the centre left out), set where
    the neighbour is darker, the columns beyond the edges replicated. Row by row, a pass over
    the code row per neighbour (vectorised; the row stays in cache), the edges' few columns
    with the edge column."""
    width = gray.shape[1]
    one = np.uint32(1)
    for y in range(codes.shape[0]):
        centre, code = gray[y + 2], codes[y]
        for x in range(width):
            code[x] = 0
        for dy in range(5):
            row = gray[y + dy]
            for dx in range(-2, 3):
                if dy == 2 and dx == 0:
                    continue
                low, high = max(0, -dx), min(width, width - dx)  # x + dx inside the row
                for x in range(min(low, width)):
                    code[x] = (code[x] << one) | np.uint32(row[0] < centre[x])
                # slices first: indices from 0 vectorise (``x + dx`` kept them scalar)
                inside = max(high - low, 0)
                here, there, bits = centre[low:high], row[low + dx : high + dx], code[low:high]
                for i in range(inside):
                    bits[i] = (bits[i] << one) | np.uint32(there[i] < here[i])
                for x in range(max(high, 0), width):
                    code[x] = (code[x] << one) | np.uint32(row[width - 1] < centre[x])


@intrinsic
def _bits(typingctx, code):  # pragma: no cover - compiled
    """Set bits of a 32-bit code: LLVM's ``ctpop`` (a shift-and-mask count is 2.5x slower and
    not vectorised)."""
    signature = types.uint32(types.uint32)

    def codegen(context, builder, signature, arguments):
        count = builder.module.declare_intrinsic("llvm.ctpop", [ir.IntType(32)])
        return builder.call(count, arguments)

    return signature, codegen


@numba.njit(cache=True, nogil=True, inline="always")
def _slide(
    census_left, census_right, terms, table, k, y, shift, cost, ring, column
):  # pragma: no cover - jit
    """Row ``y``'s costs at the disparity of ``terms[k]`` into ``column``: each column's sum
    over the last :data:`WINDOW` rows of 5-column sums (units of 2^-26: exact, module doc)."""
    width = column.shape[0]
    reach = WINDOW // 2
    half = np.float32(-0.5)
    unit = np.float32(2.0**26)
    here, there, term = census_left[y], census_right[y, shift : shift + width], terms[k, y]
    for x in range(width):
        bits = _bits(np.uint32(here[x] ^ there[x]))  # type: ignore[call-arg,var-annotated]
        cost[reach + x] = np.int32((term[x] * half + table[bits]) * unit)
    for j in range(reach):
        cost[j] = cost[reach]
        cost[reach + width + j] = cost[reach + width - 1]
    slot = ring[y % WINDOW]
    for x in range(width):
        s = cost[x] + cost[x + 1] + cost[x + 2] + cost[x + 3] + cost[x + 4]
        column[x] += s - slot[x]
        slot[x] = s


#: The box mean of a column sum in units of 2^-26: what ``cv2.boxFilter`` rounds.
MEAN = 2.0**-26 / (WINDOW * WINDOW)


@numba.njit(cache=True, nogil=True)
def census_aggregate(
    census_left, census_right, terms, table, max_disparity, first, bin_width, volume
):  # pragma: no cover - jit
    """``volume[(first + k) // bin_width]`` = the least over its bin's disparities (width 1: the
    disparity's own) of the 5x5 box mean (columns replicated) of
    ``table[H] - terms[k] / 2`` over the block: H the Hamming distance of the left codes and
    the right (shifted) codes at disparity ``first + k``; ``terms`` (count, rows + 4, w) and
    the codes have the aggregation's two rows of context above and below."""
    count, rows, width = terms.shape
    cost = np.empty(width + WINDOW - 1, np.int32)
    ring = np.zeros((WINDOW, width), np.int32)
    column = np.empty(width, np.int32)
    for k in range(count):
        d = first + k
        column[:] = 0
        ring[:] = 0
        for y in range(rows):
            _slide(
                census_left, census_right, terms, table, k, y, max_disparity - d, cost, ring, column
            )
            if y >= WINDOW - 1:
                out = volume[d // bin_width, y - (WINDOW - 1)]
                if d % bin_width == 0:  # a bin's first disparity
                    for x in range(width):
                        out[x] = np.float32(np.float64(column[x]) * MEAN)
                else:
                    for x in range(width):
                        out[x] = min(out[x], np.float32(np.float64(column[x]) * MEAN))


@numba.njit(cache=True, nogil=True)
def census_window(
    census_left, census_right, terms, table, max_disparity, first, bin_width, lowest, costs
):  # pragma: no cover - jit
    """:func:`census_aggregate`'s bins, kept only at each pixel's window: ``costs[y, x, j]``
    is bin ``lowest[y, x] + j`` (``costs`` (rows, w, K)); no volume is written or gathered."""
    count, rows, width = terms.shape
    slots = costs.shape[2]
    cost = np.empty(width + WINDOW - 1, np.int32)
    ring = np.zeros((WINDOW, width), np.int32)
    column = np.empty(width, np.int32)
    for k in range(count):
        d = first + k
        label = d // bin_width
        starts = d % bin_width == 0
        column[:] = 0
        ring[:] = 0
        for y in range(rows):
            _slide(
                census_left, census_right, terms, table, k, y, max_disparity - d, cost, ring, column
            )
            if y >= WINDOW - 1:
                row = y - (WINDOW - 1)
                for x in range(width):
                    j = label - lowest[row, x]
                    if 0 <= j < slots:
                        value = np.float32(np.float64(column[x]) * MEAN)
                        if starts:
                            costs[row, x, j] = value
                        else:
                            costs[row, x, j] = min(costs[row, x, j], value)


@numba.njit(cache=True, nogil=True)
def lowest_costs(volume, outside, skip_near, index, minimum):  # pragma: no cover - jit
    """Each pixel's least cost over the disparities of ``volume`` (D, h, w) into ``minimum``
    and the first disparity reaching it into ``index`` (set beforehand: +inf and 0), leaving
    out the disparities within 1 of ``outside`` when ``skip_near``: plane after plane, strictly
    lower replaces, as :func:`shared.filters.lowest`'s NumPy loop."""
    count, rows, width = volume.shape
    for d in range(count):
        for y in range(rows):
            for x in range(width):
                value = volume[d, y, x]
                if value < minimum[y, x] and (not skip_near or abs(outside[y, x] - d) > 1):
                    minimum[y, x] = value
                    index[y, x] = d


@numba.njit(cache=True, nogil=True)
def least_costs(volume, values, indices):  # pragma: no cover - jit
    """Each pixel's ``values.shape[0]`` least costs over the disparities of ``volume`` (D, h, w)
    into ``values`` (set beforehand: +inf), ascending, and their disparities into ``indices``:
    disparity after disparity, a cost goes in before the first strictly greater one (of equal
    costs the earlier disparity first), as :func:`shared.filters.least_costs`'s NumPy loop. Row
    by row: a row's kept costs stay in the cache while its planes' rows stream past."""
    count, rows, width = volume.shape
    last = values.shape[0] - 1
    for y in range(rows):
        for d in range(count):
            for x in range(width):
                value = volume[d, y, x]
                if value < values[last, y, x]:
                    slot = last
                    while slot > 0 and value < values[slot - 1, y, x]:
                        values[slot, y, x] = values[slot - 1, y, x]
                        indices[slot, y, x] = indices[slot - 1, y, x]
                        slot -= 1
                    values[slot, y, x] = value
                    indices[slot, y, x] = d


@numba.njit(cache=True, nogil=True)
def window_minima(volume, top, lowest, bin_width, costs):  # pragma: no cover - jit
    """``costs[y, x, j]`` (rows, w, K) = the least of ``volume[d, top + y, x]`` over bin
    ``lowest[y, x] + j``'s disparities (bin b: ``b * bin_width`` up to the volume's last;
    width 1: the disparity's own cost): :func:`shared.data_terms.gather_window` of
    :func:`shared.data_terms.bin_minimum` without the binned volume (bins and gather indices:
    two (bins or K, h, w) arrays and their page faults per view and level). Each row's bins
    its windows reach are taken in a row buffer, plane rows read in order (vectorised), then
    gathered from it; the same floats (a minimum is exact). Every window within the bins."""
    planes = volume.shape[0]
    rows, width, count = costs.shape
    bins = (planes + bin_width - 1) // bin_width
    binned = np.empty((bins, width), np.float32)
    for y in range(rows):
        row, windows = top + y, lowest[y]
        if bin_width == 1:  # the planes are the bins: gather straight from them
            for x in range(width):
                for j in range(count):
                    costs[y, x, j] = volume[windows[x] + j, row, x]
            continue
        low, high = windows[0], windows[0]
        for x in range(width):
            low, high = min(low, windows[x]), max(high, windows[x])
        for b in range(low, high + count):
            start = b * bin_width
            into, source = binned[b], volume[start, row]
            for x in range(width):
                into[x] = source[x]
            for d in range(start + 1, min(start + bin_width, planes)):
                source = volume[d, row]
                for x in range(width):
                    into[x] = min(into[x], source[x])
        for x in range(width):
            for j in range(count):
                costs[y, x, j] = binned[windows[x] + j, x]
