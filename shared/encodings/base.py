"""What every QUBO codec shares: the decoded result and the repair of invalid pixels."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shared.energy import Costs

#: Margin added to a provably sufficient penalty weight: relative part and absolute floor.
PENALTY_MARGIN = 1e-3
PENALTY_FLOOR = 1e-9


def with_margin(bound: np.ndarray) -> np.ndarray:
    """A penalty strictly above ``bound`` (the proofs need a strict inequality).

    Parameters
    ----------
    bound : numpy.ndarray
        Sufficient penalty weights, any shape.

    Returns
    -------
    numpy.ndarray
        ``bound`` raised by a relative margin and an absolute floor.
    """
    return bound * (1.0 + PENALTY_MARGIN) + PENALTY_FLOOR


@dataclass(frozen=True)
class Decoded:
    """Labels (h, w) of candidate indices and how many pixels had to be repaired."""

    labels: np.ndarray
    repaired: int


def conditional_costs(costs: Costs, labels: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Cost (h, w, K) of each label of each pixel given the labels of its *known* neighbours.

    Parameters
    ----------
    costs : Costs
        The bundle's MRF.
    labels : numpy.ndarray
        Candidate index (h, w) of every pixel.
    known : numpy.ndarray
        Mask (h, w) of the pixels whose labels count; the others' edges are left out.

    Returns
    -------
    numpy.ndarray
        Costs (h, w, K): unary plus the pairwise terms to known neighbours.
    """
    height, width = labels.shape
    total = costs.unary.copy()
    rows, cols = np.ogrid[:height, :width]
    lab = labels.astype(np.intp)
    if width > 1:
        # Right neighbour q = (y, x+1): pair_h[y, x, :, l_q]; left neighbour: pair_h[y, x-1, l_q, :]
        right = costs.pair_h[rows, cols[:, :-1], :, lab[:, 1:]] * known[:, 1:, None]
        left = costs.pair_h[rows, cols[:, :-1], lab[:, :-1], :] * known[:, :-1, None]
        total[:, :-1] += right
        total[:, 1:] += left
    if height > 1:
        below = costs.pair_v[rows[:-1], cols, :, lab[1:]] * known[1:, :, None]
        above = costs.pair_v[rows[:-1], cols, lab[:-1], :] * known[:-1, :, None]
        total[:-1] += below
        total[1:] += above
    return total


def repair(costs: Costs, labels: np.ndarray, valid: np.ndarray) -> Decoded:
    """Give each invalid pixel its cheapest label given its valid neighbours' labels.

    Parameters
    ----------
    costs : Costs
        The bundle's MRF.
    labels : numpy.ndarray
        Decoded candidate index (h, w) of every pixel (any value where invalid).
    valid : numpy.ndarray
        Mask (h, w) of the pixels whose bits were a valid code.

    Returns
    -------
    Decoded
        The repaired labels (int32) and the number of repaired pixels.
    """
    invalid = ~valid
    count = int(invalid.sum())
    if count == 0:
        return Decoded(labels=labels, repaired=0)
    best = conditional_costs(costs, labels, valid).argmin(axis=2)
    return Decoded(labels=np.where(invalid, best, labels).astype(np.int32), repaired=count)


def pixel_index(shape: tuple[int, int]) -> np.ndarray:
    """Flat pixel numbers (h, w) in raster order.

    Parameters
    ----------
    shape : tuple of int
        (height, width).

    Returns
    -------
    numpy.ndarray
        0 .. h*w - 1 as an (h, w) array.
    """
    return np.arange(shape[0] * shape[1]).reshape(shape)
