r"""One-hot encoding (the paper's): one binary x_{p,l} per pixel p and candidate l.

Energy of the QUBO:

    E(x) = sum_{p,l} u_p(l) x_pl + sum_{(p,q)} sum_{l,s} P_pq(l,s) x_pl x_qs
           + sum_p chi_p (sum_l x_pl - 1)^2

The constant of the penalty is kept in the BQM's offset, so on a one-hot x the BQM energy equals
the MRF energy exactly (the "known constant" is 0).

**Local rectifier.** With all costs non-negative (they are: squared differences and truncated
absolute differences times positive weights), take

    chi_p = min_l [ u_p(l) + sum_{q in N(p)} max_s P_pq(l, s) ] + epsilon,   epsilon > 0.

*Claim: every minimiser of E is one-hot.* Let x be any assignment that is not one-hot.

1. If some pixel p has n_p >= 2 active labels, switch all but one off. Unary and pairwise terms
   can only drop (they are non-negative), and the penalty falls from chi_p (n_p - 1)^2 > 0 to 0:
   E strictly decreases. Repeat until every pixel has n_p <= 1.
2. Now let p have n_p = 0 and switch on l*, the minimiser in chi_p. Each neighbour q has at most
   one active label s_q, so the cost added is u_p(l*) + sum_q P_pq(l*, s_q)
   <= u_p(l*) + sum_q max_s P_pq(l*, s) = chi_p - epsilon, while the penalty falls by chi_p * 1.
   E strictly decreases, and neighbours keep n_q <= 1, so step 2 repeats until all n_p = 1.

Hence x is not a minimiser; every minimiser is one-hot, and since E equals the MRF energy on
one-hot states, the QUBO minimiser is the MAP labelling. The ``global`` rectifier uses
max_p chi_p for every pixel (larger, hence also sufficient).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from shared.config import Rectifier
from shared.encodings.base import Decoded, pixel_index, quadratic_model, rectified_penalty, repair
from shared.energy import Costs

if TYPE_CHECKING:
    import dimod

NAME = "one-hot"


def variables_per_pixel(num_labels: int) -> int:
    """Binary variables per pixel for K candidates: one indicator each, K."""
    return num_labels


def variable_index(shape: tuple[int, int], num_labels: int) -> np.ndarray:
    """Variable numbers (h, w, K) of a (height, width) bundle: pixel-major, then label."""
    return pixel_index(shape)[:, :, None] * num_labels + np.arange(num_labels)


def rectifier_weights(costs: Costs, rectifier: Rectifier = Rectifier.LOCAL) -> np.ndarray:
    """chi_p (h, w) float64 from the docstring's bound: per pixel (``local``) or the largest
    for every pixel (``global``)."""
    edges = (costs.pair_h, costs.pair_v)
    return rectified_penalty(costs.unary.copy(), edges, np.max, _cheapest, rectifier)


def _cheapest(worst: np.ndarray) -> np.ndarray:
    return worst.min(axis=2)


def encode(costs: Costs, rectifier: Rectifier = Rectifier.LOCAL) -> dimod.BinaryQuadraticModel:
    """The QUBO of one bundle, built from arrays.

    Parameters
    ----------
    costs : Costs
        The bundle's MRF.
    rectifier : Rectifier, optional
        How the one-hot penalty chi is chosen (:func:`rectifier_weights`).

    Returns
    -------
    dimod.BinaryQuadraticModel
        Binary, variables numbered as :func:`variable_index`; on one-hot samples its energy equals
        the MRF energy.
    """
    height, width, labels = costs.unary.shape
    index = variable_index((height, width), labels)
    chi = rectifier_weights(costs, rectifier)

    linear = (costs.unary - chi[:, :, None]).ravel()
    upper_l, upper_s = np.triu_indices(labels, k=1)
    penalty = (
        index[:, :, upper_l].ravel(),
        index[:, :, upper_s].ravel(),
        np.repeat(2.0 * chi.ravel(), upper_l.size),
    )
    return quadratic_model(linear, penalty, index, (costs.pair_h, costs.pair_v), float(chi.sum()))


def encode_labels(labels: np.ndarray, num_labels: int) -> np.ndarray:
    """The one-hot bits (h * w * K, int8, in variable order) of a labelling (h, w) of K
    candidates."""
    return (labels[:, :, None] == np.arange(num_labels)).astype(np.int8).ravel()


def decode(costs: Costs, sample: np.ndarray) -> Decoded:
    """Labels from h * w * K bits in variable order; pixels with zero or several active bits are
    repaired to their cheapest label given their valid neighbours."""
    height, width, labels = costs.unary.shape
    bits = np.asarray(sample).reshape(height, width, labels)
    valid = bits.sum(axis=2) == 1
    return repair(costs, bits.argmax(axis=2).astype(np.int32), valid)
