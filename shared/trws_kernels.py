"""TRW-S's compiled kernel (:func:`shared.grid_inference.trws`): one pass of min-sum messages
over the row and column chains. Beside :mod:`shared.grid_kernels` (whose regulariser and label
helpers it shares) so that each module stays one minimiser's kernels; compiled into the same
ahead-of-time module (:mod:`shared.kernels`).
"""

from __future__ import annotations

import numba
import numpy as np

from shared.grid_kernels import _label, _regulariser, _regulariser_table, _tabled


@numba.njit(cache=True, nogil=True, inline="always")
def _send(
    source, candidates, first, windows, yp, xp, yq, xq, w, slope, truncation, envelope, out
):  # pragma: no cover - jit
    """``out[k] = min_j source[j] + w min(T, s |L_p(j) - L_q(k)|)`` and c, its minimum (returned):
    the message from pixel p to its neighbour q is ``out - c``; O(K) distance transform for
    windows."""
    count = source.shape[0]
    lowest = source[0]
    if windows:  # the minimum and the envelope's forward pass in one loop
        step = w * slope
        running = source[0]
        envelope[0] = running
        for j in range(1, count):
            value = source[j]
            lowest = min(lowest, value)
            running = min(value, running + step)
            envelope[j] = running
        ceiling = lowest + w * truncation
        for j in range(count - 2, -1, -1):
            running = min(envelope[j], running + step)
            envelope[j] = running
        shift = first[yq, xq] - first[yp, xp]
        smallest = 0.0
        for k in range(count):
            t = k + shift
            if t < 0:
                value = envelope[0] - step * t
            elif t >= count:
                value = envelope[count - 1] + step * (t - count + 1)
            else:
                value = envelope[t]
            out[k] = min(value, ceiling)
            smallest = out[k] if k == 0 else min(smallest, out[k])  # out's minimum, in order
        return smallest
    else:
        for j in range(1, count):
            lowest = min(lowest, source[j])
        ceiling = lowest + w * truncation
        for k in range(count):
            here = candidates[yq, xq, k]
            value = ceiling
            for j in range(count):
                penalty = _regulariser(candidates[yp, xp, j], here, slope, truncation)
                value = min(value, source[j] + w * penalty)
            out[k] = value
    smallest = out[0]
    for k in range(1, count):
        smallest = min(smallest, out[k])
    return smallest


@numba.njit(cache=True, nogil=True, inline="always")
def _pass_on(half, back, sent, yp, xp, yq, xq, w, edges, buffers):  # pragma: no cover - jit
    """TRW-S's message from pixel p to its neighbour q ahead: p's ``half`` less what q sent back
    (``back[p]``), through the edge (:func:`_send`; ``edges``: the grid's candidates and
    regulariser, ``buffers``: scratch) into ``sent[q]``; returns its normalisation constant."""
    candidates, first, windows, slope, truncation = edges
    source, envelope, out = buffers
    count = half.shape[0]
    for k in range(count):
        source[k] = half[k] - back[yp, xp, k]
    constant = _send(
        source, candidates, first, windows, yp, xp, yq, xq, w, slope, truncation, envelope, out
    )
    for k in range(count):
        sent[yq, xq, k] = out[k] - constant
    return constant


@numba.njit(cache=True, nogil=True)
def _trws_pass(
    unary,
    candidates,
    first,
    windows,
    weight_h,
    weight_v,
    slope,
    truncation,
    from_left,
    from_right,
    from_up,
    from_down,
    forward,
    labels,
):  # pragma: no cover - jit
    """One TRW-S pass (Kolmogorov 2006) over the row and column chains, each pixel in two chains
    (rho = 1/2): in raster order (``forward``) every pixel sends its messages right and down,
    else in reverse order left and up; ``from_*[y, x]`` is the message pixel (y, x) receives
    from that side. Writes ``labels`` (each pixel's best candidate given the labels already
    chosen in this pass and the messages from the others); returns the lower bound of the
    chain decomposition the messages define after the pass: the normalisation constants sent
    plus each chain's last min 1/2 theta-hat."""
    height, width, count = unary.shape
    table = _regulariser_table(slope, truncation)
    half = np.empty(count)
    source = np.empty(count)
    out = np.empty(count)
    envelope = np.empty(count)
    # along each axis: what a pixel receives from ahead (sent back to it in the last pass) and
    # where what it sends ahead arrives
    back_h, sent_h = (from_right, from_left) if forward else (from_left, from_right)
    back_v, sent_v = (from_down, from_up) if forward else (from_up, from_down)
    edges = (candidates, first, windows, slope, truncation)
    buffers = (source, envelope, out)
    bound = 0.0
    for step_y in range(height):
        y = step_y if forward else height - 1 - step_y
        for step_x in range(width):
            x = step_x if forward else width - 1 - step_x
            # the neighbours behind (labelled in this pass) and ahead along each axis
            xb, yb = (x - 1, y - 1) if forward else (x + 1, y + 1)
            xa, ya = (x + 1, y + 1) if forward else (x - 1, y - 1)
            has_xb, has_yb = 0 <= xb < width, 0 <= yb < height
            has_xa, has_ya = 0 <= xa < width, 0 <= ya < height
            # the labels behind and their edges' weights, once per pixel (not per candidate)
            there_x = _label(candidates, first, windows, y, xb, labels[y, xb]) if has_xb else 0
            w_x = weight_h[y, min(x, xb)] if has_xb else 0.0
            there_y = _label(candidates, first, windows, yb, x, labels[yb, x]) if has_yb else 0
            w_y = weight_v[min(y, yb), x] if has_yb else 0.0
            lowest = np.inf
            best, arg = np.inf, 0
            for k in range(count):
                total = (
                    unary[y, x, k]
                    + from_left[y, x, k]
                    + from_right[y, x, k]
                    + from_up[y, x, k]
                    + from_down[y, x, k]
                )
                half[k] = 0.5 * total
                lowest = min(lowest, half[k])
                # the label: the messages from ahead, the pairwise terms to the labels behind
                here = _label(candidates, first, windows, y, x, k)
                # float32 up to here, then float64: spelt out, for numba types a variable
                # assigned float32 then float64 differently just in time and ahead of time
                score = np.float64(unary[y, x, k] + (back_h[y, x, k] + back_v[y, x, k]))
                if has_xb:
                    score += w_x * _tabled(table, here - there_x, slope, truncation)
                if has_yb:
                    score += w_y * _tabled(table, here - there_y, slope, truncation)
                if score < best:
                    best, arg = score, k
            labels[y, x] = arg
            if has_xa:
                w = weight_h[y, min(x, xa)]
                bound += _pass_on(half, back_h, sent_h, y, x, y, xa, w, edges, buffers)
            else:
                bound += lowest  # the end of its row chain
            if has_ya:
                w = weight_v[min(y, ya), x]
                bound += _pass_on(half, back_v, sent_v, y, x, ya, x, w, edges, buffers)
            else:
                bound += lowest  # the end of its column chain
    return bound
