"""What every QUBO codec shares: penalty bounds, the BQM assembly, the decoded result and the
repair of invalid pixels."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from shared.config import Rectifier
from shared.energy import Costs

if TYPE_CHECKING:  # dimod is imported where a BQM is built, not by the exact row path
    import dimod

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
    """Labels (h, w) of candidate indices and how many pixels had to be repaired (``invalid``:
    which, None when none was)."""

    labels: np.ndarray
    repaired: int
    invalid: np.ndarray | None = None


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
    return Decoded(
        labels=np.where(invalid, best, labels).astype(np.int32), repaired=count, invalid=invalid
    )


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


def rectified_penalty(
    own: np.ndarray,
    edges: tuple[np.ndarray, np.ndarray],
    reduce: Callable[..., np.ndarray],
    per_pixel: Callable[[np.ndarray], np.ndarray],
    rectifier: Rectifier,
) -> np.ndarray:
    """The penalty weight of every pixel (h, w), strictly above a codec's sufficient bound.

    The bound is ``per_pixel`` of the pixel's ``own`` (h, w, n) terms plus, from each of its
    four neighbours, the edge term ``reduce(matrix, axis=...)`` folds to p's n variables (the
    (n, n) ``edges`` matrices, horizontal then vertical, hold the first pixel's variables along
    axis -2). With the ``global`` rectifier every pixel gets the largest weight.
    """
    edge_h, edge_v = edges
    total = own
    if edge_h.size:
        total[:, :-1] += reduce(edge_h, axis=3)  # p's right neighbour
        total[:, 1:] += reduce(edge_h, axis=2)  # p's left neighbour
    if edge_v.size:
        total[:-1] += reduce(edge_v, axis=3)
        total[1:] += reduce(edge_v, axis=2)
    weights = with_margin(per_pixel(total))
    if rectifier is Rectifier.GLOBAL:
        weights = np.full_like(weights, weights.max())
    return weights


def _edge_terms(first: np.ndarray, second: np.ndarray, weights: np.ndarray):
    """Quadratic terms x_{p,i} x_{q,j} weighted weights[..., i, j] (p from first, q from second)."""
    rows = np.broadcast_to(first[..., :, None], weights.shape)
    cols = np.broadcast_to(second[..., None, :], weights.shape)
    return rows.ravel(), cols.ravel(), weights.ravel()


def quadratic_model(
    linear: np.ndarray,
    penalty: tuple[np.ndarray, np.ndarray, np.ndarray],
    index: np.ndarray,
    edges: tuple[np.ndarray, np.ndarray],
    offset: float,
) -> dimod.BinaryQuadraticModel:
    """A codec's binary BQM from arrays (no per-term Python loop).

    Parameters
    ----------
    linear : numpy.ndarray
        Linear coefficients in variable order.
    penalty : tuple of numpy.ndarray
        The within-pixel penalty terms (rows, cols, weights).
    index : numpy.ndarray
        Variable numbers (h, w, n).
    edges : tuple of numpy.ndarray
        The (n, n) coupling matrices of the horizontal and of the vertical edges.
    offset : float
        The BQM's constant.

    Returns
    -------
    dimod.BinaryQuadraticModel
    """
    height, width = index.shape[:2]
    parts = [penalty]
    if width > 1:
        parts.append(_edge_terms(index[:, :-1], index[:, 1:], edges[0]))
    if height > 1:
        parts.append(_edge_terms(index[:-1], index[1:], edges[1]))
    rows, cols, data = (np.concatenate(column) for column in zip(*parts, strict=True))
    import dimod

    return dimod.BinaryQuadraticModel.from_numpy_vectors(
        linear, (rows, cols, data), offset, dimod.BINARY
    )
