r"""Domain-wall encoding: K - 1 binaries b_1..b_{K-1} per pixel hold one "wall".

A valid pixel has b_1 >= b_2 >= ... >= b_{K-1}; its label is the number of ones. With the
constants b_0 = 1 and b_K = 0, the indicator of label l is delta_l = b_l - b_{l+1}, i.e.
delta = D B with B = (1, b_1, ..., b_{K-1}) and D = I - (superdiagonal). Hence

    unary:     sum_l u(l) delta_l = u(0) + sum_{i>=1} (u(i) - u(i-1)) b_i
    pairwise:  delta_p^T P delta_q = B_p^T M B_q,   M = D^T P D,

which stays quadratic: M[0,0] is a constant, M[i,0] and M[0,j] are linear, M[i,j] (i,j >= 1)
quadratic. A broken wall is penalised by lambda_p * sum_{i=1}^{K-2} b_{i+1} (1 - b_i) (zero on
valid walls, at least lambda_p otherwise). A single bit flip at the end of the wall moves the
label by one step without crossing a penalty barrier, unlike one-hot where any move breaks the
one-hot constraint first.

**Sufficient per-vertex lambda_p.** The one-hot bound does not carry over: on broken walls the
indicators can be -1, so pairwise products can be negative. Fix all pixels but p. The energy
restricted to p's bits (penalty aside) is affine, sum_i g_i b_i + const, with
g_i = L_i + sum_{q in N(p)} sum_{j>=1} M_pq[i, j] b^q_j, where L_i collects p's linear
coefficients (unary difference plus the M[i, 0] terms). For q's bits in {0, 1},

    max(0, -g_i) <= G_i := max(0, -L_i + sum_q sum_{j>=1} max(0, -M_pq[i, j])),

a bound that does not depend on the other pixels' states. Let b be broken (>= 1 break) and b*
the best valid wall: g.b* = min over prefixes of g <= 0 (the empty prefix), and
g.b >= -sum_i max(0, -g_i) >= -sum_i G_i. So replacing b by b* changes the energy by at most
sum_i G_i - lambda_p * breaks(b) < 0 when lambda_p > sum_i G_i. The bound holds whatever the
neighbours are, so repairing broken pixels one at a time strictly lowers E each time: every
minimiser has only valid walls, and there E equals the MRF energy (the offset keeps the
constants). ``lambda_p = sum_i G_i`` plus a margin; ``global`` uses max_p lambda_p.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from shared.config import Rectifier
from shared.encodings.base import Decoded, pixel_index, quadratic_model, rectified_penalty, repair
from shared.energy import Costs

if TYPE_CHECKING:
    import dimod

NAME = "domain-wall"


def variables_per_pixel(num_labels: int) -> int:
    """Binary variables per pixel for K candidates: one per wall position, K - 1."""
    return num_labels - 1


def variable_index(shape: tuple[int, int], num_labels: int) -> np.ndarray:
    """Variable numbers (h, w, K - 1) of b_1..b_{K-1} of a (height, width) bundle, pixel-major."""
    bits = num_labels - 1
    return pixel_index(shape)[:, :, None] * bits + np.arange(bits)


def _wall_matrix(pair: np.ndarray) -> np.ndarray:
    """M = D^T P D for every edge: maps wall vectors B = (1, b_1, ...) to pair energy."""
    labels = pair.shape[-1]
    d = np.eye(labels) - np.eye(labels, k=1)
    return np.einsum("li,...ls,sj->...ij", d, pair, d)


def _terms(costs: Costs):
    """Linear (h, w, K-1) coefficients, offset, and the edge matrices M (horizontal, vertical)."""
    unary = costs.unary
    linear = np.diff(unary, axis=2)  # u(i) - u(i-1), i = 1..K-1
    offset = unary[:, :, 0].sum()
    m_h = _wall_matrix(costs.pair_h)
    m_v = _wall_matrix(costs.pair_v)
    for m, (first, second) in (
        (m_h, (np.s_[:, :-1], np.s_[:, 1:])),
        (m_v, (np.s_[:-1], np.s_[1:])),
    ):
        if m.size:
            offset += m[..., 0, 0].sum()
            linear[first] += m[..., 1:, 0]
            linear[second] += m[..., 0, 1:]
    return linear, float(offset), m_h, m_v


def _penalty_weights(
    linear: np.ndarray, m_h: np.ndarray, m_v: np.ndarray, rectifier: Rectifier
) -> np.ndarray:
    """lambda_p (h, w) from the docstring's bound (p's bits are rows of M with its right or
    lower neighbour and columns of M with its left or upper one)."""
    edges = (np.maximum(0.0, -m_h[..., 1:, 1:]), np.maximum(0.0, -m_v[..., 1:, 1:]))
    return rectified_penalty(-linear, edges, np.sum, _positive_sum, rectifier)


def _positive_sum(negative: np.ndarray) -> np.ndarray:
    return np.maximum(0.0, negative).sum(axis=2)


def rectifier_weights(costs: Costs, rectifier: Rectifier = Rectifier.LOCAL) -> np.ndarray:
    """The wall-breaking penalty lambda_p (h, w) float64 of every pixel, above the module
    docstring's bound: per pixel (``local``) or the largest for all (``global``)."""
    linear, _, m_h, m_v = _terms(costs)
    return _penalty_weights(linear, m_h, m_v, rectifier)


def encode(costs: Costs, rectifier: Rectifier = Rectifier.LOCAL) -> dimod.BinaryQuadraticModel:
    """The QUBO of one bundle, built from arrays.

    Parameters
    ----------
    costs : Costs
        The bundle's MRF, at least 2 candidates.
    rectifier : Rectifier, optional
        How the wall penalty is chosen (:func:`rectifier_weights`).

    Returns
    -------
    dimod.BinaryQuadraticModel
        Binary, variables numbered as :func:`variable_index`; on valid walls its energy equals the
        MRF energy.

    Raises
    ------
    ValueError
        If the bundle has fewer than 2 candidates per pixel.
    """
    height, width, labels = costs.unary.shape
    if labels < 2:
        raise ValueError("domain-wall encoding needs at least 2 candidates")
    index = variable_index((height, width), labels)
    linear, offset, m_h, m_v = _terms(costs)
    lam = _penalty_weights(linear, m_h, m_v, rectifier)

    # Penalty lambda (b_{i+1} - b_i b_{i+1}), i = 1..K-2 (array positions 0..K-3).
    linear = linear.copy()
    linear[:, :, 1:] += lam[:, :, None]
    penalty = (
        index[:, :, :-1].ravel(),
        index[:, :, 1:].ravel(),
        np.repeat(-lam.ravel(), labels - 2),
    )
    edges = (m_h[..., 1:, 1:], m_v[..., 1:, 1:])
    return quadratic_model(linear.ravel(), penalty, index, edges, offset)


def encode_labels(labels: np.ndarray, num_labels: int) -> np.ndarray:
    """The wall bits (h * w * (K - 1), int8, in variable order) of a labelling (h, w):
    b_i = 1 for i <= label."""
    return (labels[:, :, None] >= np.arange(1, num_labels)).astype(np.int8).ravel()


def decode(costs: Costs, sample: np.ndarray) -> Decoded:
    """Labels from h * w * (K - 1) bits in variable order; broken walls are repaired given
    valid neighbours."""
    height, width, labels = costs.unary.shape
    bits = np.asarray(sample).reshape(height, width, labels - 1)
    valid = np.all(bits[:, :, :-1] >= bits[:, :, 1:], axis=2)
    return repair(costs, bits.sum(axis=2).astype(np.int32), valid)
