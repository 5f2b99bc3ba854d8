"""The compiled kernels of :mod:`shared.grid`: chain min-sum DP, grid energy, neighbour costs
and the dual decomposition's multiplier step (TRW-S's pass: :mod:`shared.trws_kernels`). Serial
on purpose (a numba-parallel launch costs more than it saves on small levels); ``nogil`` so
that views run side by side in threads.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def _regulariser(a, b, slope, truncation):  # pragma: no cover - jit
    penalty = abs(a - b) * slope
    return truncation if penalty > truncation else penalty


#: Label differences whose regulariser the chain kernels look up rather than compute.
TABLE_SIZE = 64


@numba.njit(cache=True, nogil=True)
def _regulariser_table(slope, truncation):  # pragma: no cover - jit
    """``_regulariser(d, 0)`` for d = 0..TABLE_SIZE - 1 (the same floats, computed once)."""
    table = np.empty(TABLE_SIZE)
    for d in range(TABLE_SIZE):
        table[d] = _regulariser(d, 0, slope, truncation)
    return table


@numba.njit(cache=True, nogil=True, inline="always")
def _tabled(table, difference, slope, truncation):  # pragma: no cover - jit
    """``_regulariser`` of a label difference: from the table when it holds it."""
    distance = abs(difference)
    if distance < TABLE_SIZE:
        return table[distance]
    return _regulariser(distance, 0, slope, truncation)


@numba.njit(cache=True, nogil=True, inline="always")
def _label(candidates, first, windows, y, x, k):  # pragma: no cover - jit
    """The label candidate ``k`` of pixel (y, x) stands for."""
    return first[y, x] + k if windows else candidates[y, x, k]


@numba.njit(cache=True, nogil=True)
def _label_table(first, count, slope, truncation):  # pragma: no cover - jit
    """``_regulariser(|d|, 0)`` at ``d + reach`` for every label difference d of a window grid
    (reach returned): lookups without ``abs`` or a branch (:func:`_tabled`'s floats). Callers
    index it with ``np.uintp`` (d + reach >= 0): numba then skips its negative-index check."""
    lowest, highest = (first.min(), first.max()) if first.size else (0, 0)
    reach = highest - lowest + count
    table = np.empty(2 * reach + 1)
    for d in range(-reach, reach + 1):
        table[d + reach] = _regulariser(abs(d), 0, slope, truncation)
    return table, reach


@numba.njit(cache=True, nogil=True)
def _grid_energy_windows(
    unary, first, weight_h, weight_v, slope, truncation, labels
):  # pragma: no cover - jit
    """:func:`_grid_energy` of a window grid: labels from ``first`` (no gather over the
    candidates), regularisers from :func:`_label_table`; each row summed in the same order
    (unary, right edge, lower edge)."""
    height, width, count = unary.shape
    table, reach = _label_table(first, count, slope, truncation)
    per_row = np.zeros(height)
    for y in range(height):
        total = 0.0
        below, lower = min(y + 1, height - 1), y + 1 < height
        for x in range(width):
            label = labels[y, x]
            here = first[y, x] + label + reach
            total += unary[y, x, label]
            if x + 1 < width:
                total += weight_h[y, x] * table[np.uintp(here - first[y, x + 1] - labels[y, x + 1])]
            if lower:
                total += weight_v[y, x] * table[np.uintp(here - first[below, x] - labels[below, x])]
        per_row[y] = total
    return per_row


@numba.njit(cache=True, nogil=True)
def _grid_energy(
    unary, candidates, first, windows, weight_h, weight_v, slope, truncation, labels
):  # pragma: no cover - jit
    """E(x) of a labelling: each row's unary, horizontal and downward vertical terms."""
    if windows:
        return _grid_energy_windows(unary, first, weight_h, weight_v, slope, truncation, labels)
    height, width, _ = unary.shape
    table = _regulariser_table(slope, truncation)
    per_row = np.zeros(height)
    for y in range(height):
        total = 0.0
        for x in range(width):
            here = candidates[y, x, labels[y, x]]
            total += unary[y, x, labels[y, x]]
            if x + 1 < width:
                there = candidates[y, x + 1, labels[y, x + 1]]
                total += weight_h[y, x] * _tabled(table, here - there, slope, truncation)
            if y + 1 < height:
                there = candidates[y + 1, x, labels[y + 1, x]]
                total += weight_v[y, x] * _tabled(table, here - there, slope, truncation)
        per_row[y] = total
    return per_row


@numba.njit(cache=True, nogil=True, inline="always")
def _put(labels, turned, chain, x, label):  # pragma: no cover - jit
    """A chain kernel's label of (chain, x): at ``labels[chain, x]``, or ``labels[x, chain]``
    when ``turned`` (a transposed grid's labels in the original layout, without a copy)."""
    if turned:
        labels[x, chain] = label
    else:
        labels[chain, x] = label


@numba.njit(cache=True, nogil=True, inline="always")
def _chain_end(messages, chain, energies, labels, turned):  # pragma: no cover - jit
    """The chain's best last label (the first of equal messages), where both chain kernels'
    read-back starts: written to ``labels`` (:func:`_put`), its message to ``energies`` as the
    optimum."""
    length, count = messages.shape
    arg = 0
    for k in range(1, count):
        if messages[length - 1, k] < messages[length - 1, arg]:
            arg = k
    energies[chain] = messages[length - 1, arg]
    _put(labels, turned, chain, length - 1, arg)
    return arg


@numba.njit(cache=True, nogil=True, inline="always")
def _window_message(
    messages, x, envelope, step, ceiling, shift, base, scale, extra, sign, chain
):  # pragma: no cover - jit
    """``messages[x]``: the cone envelope of ``messages[x - 1]`` (``envelope``) at the window's
    labels (``shift`` apart), capped at ``ceiling``, plus the unary of (chain, x)."""
    count = envelope.shape[0]
    if shift == 0:  # the same window (most positions): one loop LLVM compiles tighter
        for k in range(count):
            value = envelope[k]
            messages[x, k] = (
                min(value, ceiling) + scale * base[chain, x, k] + sign * extra[chain, x, k]
            )
        return
    # t = k + shift below 0, inside the window, beyond it: three loops without a branch
    low = min(max(-shift, 0), count)
    high = max(min(count - shift, count), low)
    for k in range(low):
        value = envelope[0] - step * (k + shift)
        messages[x, k] = min(value, ceiling) + scale * base[chain, x, k] + sign * extra[chain, x, k]
    for k in range(low, high):
        value = envelope[k + shift]
        messages[x, k] = min(value, ceiling) + scale * base[chain, x, k] + sign * extra[chain, x, k]
    for k in range(high, count):
        value = envelope[count - 1] + step * (k + shift - count + 1)
        messages[x, k] = min(value, ceiling) + scale * base[chain, x, k] + sign * extra[chain, x, k]


@numba.njit(cache=True, nogil=True)
def _chains_windows(
    base, scale, extra, sign, first, weight, slope, truncation, labels, turned
):  # pragma: no cover - jit
    """Min-sum DP of every chain ``[chain, position]`` of the arrays, unary ``scale * base +
    sign * extra``, candidates the consecutive windows ``first + 0..K-1``: each message a distance
    transform in O(K). The messages are kept and the labels read back from them (no
    back-pointers in the hot loop). Writes ``labels`` (transposed when ``turned``:
    :func:`_put`); returns each chain's optimum.

    Two chains at a time, a and b (the last alone repeats itself: the same floats): their
    envelope passes, chains of dependent additions, interleaved in one loop."""
    chains, length, count = base.shape
    energies = np.empty(chains)
    table, reach = _label_table(first, count, slope, truncation)
    ma, mb = np.empty((length, count)), np.empty((length, count))
    ea, eb = np.empty(count), np.empty(count)
    for a in range(0, chains, 2):
        b = min(a + 1, chains - 1)
        for k in range(count):
            ma[0, k] = scale * base[a, 0, k] + sign * extra[a, 0, k]
            mb[0, k] = scale * base[b, 0, k] + sign * extra[b, 0, k]
        for x in range(1, length):
            wa, wb = weight[a, x - 1], weight[b, x - 1]
            sa, sb = wa * slope, wb * slope
            # lower envelope of the cones s w |j - t|; the running values in registers
            la, lb = ma[x - 1, 0], mb[x - 1, 0]
            ra, rb = la, lb
            ea[0], eb[0] = ra, rb
            for j in range(1, count):
                va, vb = ma[x - 1, j], mb[x - 1, j]
                la, lb = min(la, va), min(lb, vb)
                ra, rb = min(va, ra + sa), min(vb, rb + sb)
                ea[j], eb[j] = ra, rb
            for j in range(count - 2, -1, -1):
                ra, rb = min(ea[j], ra + sa), min(eb[j], rb + sb)
                ea[j], eb[j] = ra, rb
            shift_a = first[a, x] - first[a, x - 1]
            shift_b = first[b, x] - first[b, x - 1]
            ca, cb = la + wa * truncation, lb + wb * truncation
            _window_message(ma, x, ea, sa, ca, shift_a, base, scale, extra, sign, a)
            _window_message(mb, x, eb, sb, cb, shift_b, base, scale, extra, sign, b)
        arg_a = _chain_end(ma, a, energies, labels, turned)
        arg_b = _chain_end(mb, b, energies, labels, turned)
        for x in range(length - 1, 0, -1):  # the predecessor that gave each message its value
            wa, wb = weight[a, x - 1], weight[b, x - 1]
            # the table's index of the label difference at j = 0
            offset_a = first[a, x - 1] - first[a, x] - arg_a + reach
            offset_b = first[b, x - 1] - first[b, x] - arg_b + reach
            best_a, best_b = np.inf, np.inf
            for j in range(count):  # the first of equal values
                value_a = ma[x - 1, j] + wa * table[np.uintp(offset_a + j)]
                value_b = mb[x - 1, j] + wb * table[np.uintp(offset_b + j)]
                if value_a < best_a:
                    best_a, arg_a = value_a, j
                if value_b < best_b:
                    best_b, arg_b = value_b, j
            _put(labels, turned, a, x - 1, arg_a)
            _put(labels, turned, b, x - 1, arg_b)
    return energies


@numba.njit(cache=True, nogil=True)
def _chains_general(
    base, scale, extra, sign, candidates, weight, slope, truncation, labels, turned
):  # pragma: no cover - jit
    """:func:`_chains_windows` for any candidate labels: each message in O(K^2)."""
    chains, length, count = base.shape
    energies = np.empty(chains)
    for chain in range(chains):
        messages = np.empty((length, count))
        for k in range(count):
            messages[0, k] = scale * base[chain, 0, k] + sign * extra[chain, 0, k]
        for x in range(1, length):
            w = weight[chain, x - 1]
            lowest = messages[x - 1, 0]
            for j in range(count):
                lowest = min(lowest, messages[x - 1, j])
            ceiling = lowest + w * truncation
            for k in range(count):
                here = candidates[chain, x, k]
                value = ceiling
                for j in range(count):
                    penalty = _regulariser(candidates[chain, x - 1, j], here, slope, truncation)
                    value = min(value, messages[x - 1, j] + w * penalty)
                messages[x, k] = value + scale * base[chain, x, k] + sign * extra[chain, x, k]
        arg = _chain_end(messages, chain, energies, labels, turned)
        for x in range(length - 1, 0, -1):
            w = weight[chain, x - 1]
            here = candidates[chain, x, arg]
            best = np.inf
            for j in range(count):
                penalty = _regulariser(candidates[chain, x - 1, j], here, slope, truncation)
                value = messages[x - 1, j] + w * penalty
                if value < best:
                    best = value
                    arg = j
            _put(labels, turned, chain, x - 1, arg)
    return energies


@numba.njit(cache=True, nogil=True)
def _neighbour_costs(
    candidates, first, windows, weight_h, weight_v, slope, truncation, labels, vertical, out
):  # pragma: no cover - jit
    """``out[y, x, k]``: the cost of candidate k of (y, x) for its edges to the fixed labels of
    its vertical (or horizontal) neighbours (the one before, then the one after)."""
    if windows:
        _neighbour_costs_windows(
            first, weight_h, weight_v, slope, truncation, labels, vertical, out
        )
        return
    height, width, count = out.shape
    table = _regulariser_table(slope, truncation)
    for y in range(height):
        for x in range(width):
            # the two neighbours' labels and edge weights, once per pixel (not per candidate)
            has_before, has_after = (y > 0, y + 1 < height) if vertical else (x > 0, x + 1 < width)
            before, after, weight_before, weight_after = 0, 0, 0.0, 0.0
            if vertical:
                if has_before:
                    before = _label(candidates, first, windows, y - 1, x, labels[y - 1, x])
                    weight_before = weight_v[y - 1, x]
                if has_after:
                    after = _label(candidates, first, windows, y + 1, x, labels[y + 1, x])
                    weight_after = weight_v[y, x]
            else:
                if has_before:
                    before = _label(candidates, first, windows, y, x - 1, labels[y, x - 1])
                    weight_before = weight_h[y, x - 1]
                if has_after:
                    after = _label(candidates, first, windows, y, x + 1, labels[y, x + 1])
                    weight_after = weight_h[y, x]
            for k in range(count):
                here = _label(candidates, first, windows, y, x, k)
                total = 0.0
                if has_before:
                    total += weight_before * _tabled(table, here - before, slope, truncation)
                if has_after:
                    total += weight_after * _tabled(table, here - after, slope, truncation)
                out[y, x, k] = total


@numba.njit(cache=True, nogil=True)
def _neighbour_costs_windows(
    first, weight_h, weight_v, slope, truncation, labels, vertical, out
):  # pragma: no cover - jit
    """:func:`_neighbour_costs` of a window grid without a branch per candidate: candidate k's
    label difference to a neighbour's label is d + k, its regulariser ``table[d + k + reach]``
    (:func:`_label_table`); a
    missing neighbour is weight 0 (0 + w r and w r + 0 are the same floats: r is finite)."""
    height, width, count = out.shape
    table, reach = _label_table(first, count, slope, truncation)
    for y in range(height):
        for x in range(width):
            here = first[y, x]
            before, after, weight_before, weight_after = here, here, 0.0, 0.0
            if vertical:
                if y > 0:
                    before, weight_before = first[y - 1, x] + labels[y - 1, x], weight_v[y - 1, x]
                if y + 1 < height:
                    after, weight_after = first[y + 1, x] + labels[y + 1, x], weight_v[y, x]
            else:
                if x > 0:
                    before, weight_before = first[y, x - 1] + labels[y, x - 1], weight_h[y, x - 1]
                if x + 1 < width:
                    after, weight_after = first[y, x + 1] + labels[y, x + 1], weight_h[y, x]
            offset_before, offset_after = here - before + reach, here - after + reach
            for k in range(count):
                ahead = weight_after * table[np.uintp(offset_after + k)]
                out[y, x, k] = weight_before * table[np.uintp(offset_before + k)] + ahead


@numba.njit(cache=True, nogil=True)
def _disagreements(row_labels, column_labels):  # pragma: no cover - jit
    """Pixels whose row label differs from their column label (both (h, w): read in the same
    order; the transposed layout's strided reads cost more than the transpose)."""
    height, width = row_labels.shape
    count = 0
    for y in range(height):
        for x in range(width):
            if row_labels[y, x] != column_labels[y, x]:
                count += 1
    return count


@numba.njit(cache=True, nogil=True)
def _subgradient_step(
    multipliers, multipliers_turned, row_labels, column_labels, step
):  # pragma: no cover - jit
    """Where row and column labels (both (h, w)) disagree: + step on the row label's
    multiplier, - step on the column label's, in both copies of the multipliers (by rows, and
    transposed for the column chains); float32 like numpy's in-place update. The labels are read
    in row order; only the disagreeing pixels (a few %) touch the transposed copy."""
    height, width = row_labels.shape
    for y in range(height):
        for x in range(width):
            here, there = row_labels[y, x], column_labels[y, x]
            if here != there:
                multipliers[y, x, here] += step
                multipliers[y, x, there] -= step
                multipliers_turned[x, y, here] += step
                multipliers_turned[x, y, there] -= step
