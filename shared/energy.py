"""The MRF of one pyramid level as cost arrays, and its energy.

For candidate index l of pixel p = (y, x) standing for label C[y, x, l] (a disparity, or a
disparity bin in the bin pyramid):

    unary[y, x, l]      = the data term of that label (:mod:`shared.data_terms`)
    pair_h[y, x, l, s]  = w(p, q) * R(|C[p, l] - C[q, s]|)         q = (y, x + 1)
    pair_v[y, x, l, s]  = w(p, q) * R(|C[p, l] - C[q, s]|)         q = (y + 1, x)

with R(t) = min(trunc, s t) and w = m where the gray step |I_L(p) - I_L(q)| > thr, else 1
("truncated"), or R(t) = s t and w = 1 ("linear"), or R = 0 ("none"). All costs are
non-negative, which the rectifier proofs in :mod:`shared.encodings` rely on. These arrays are the
one description of the level: the exact row DP, both QUBO codecs and the reported energies all
read them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shared.config import LevelConfig, Regularizer
from shared.data_terms import squared_difference


@dataclass(frozen=True)
class Costs:
    """MRF costs of a block of rows. Shapes: unary (h, w, K), pair_h (h, w-1, K, K),
    pair_v (h-1, w, K, K); candidates (h, w, K) are the disparities the labels stand for."""

    candidates: np.ndarray
    unary: np.ndarray
    pair_h: np.ndarray
    pair_v: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return self.unary.shape[0], self.unary.shape[1]

    @property
    def num_labels(self) -> int:
        return self.unary.shape[2]

    @staticmethod
    def stack(blocks: list[Costs]) -> Costs:
        """Blocks of rows one below the other, with no vertical edge between two blocks.

        Parameters
        ----------
        blocks : list of Costs
            Blocks of the same width and label count, top to bottom.

        Returns
        -------
        Costs
            The stacked costs (the block itself when there is one).
        """
        if len(blocks) == 1:
            return blocks[0]
        seam = np.zeros((1, *blocks[0].pair_v.shape[1:]), dtype=blocks[0].pair_v.dtype)
        pair_v = [part for block in blocks for part in (seam, block.pair_v)][1:]
        return Costs(
            candidates=np.concatenate([block.candidates for block in blocks]),
            unary=np.concatenate([block.unary for block in blocks]),
            pair_h=np.concatenate([block.pair_h for block in blocks]),
            pair_v=np.concatenate(pair_v),
        )

    def rows(self, start: int, stop: int) -> Costs:
        """The costs of a block of rows (views): :meth:`block` along axis 0.

        Parameters
        ----------
        start, stop : int
            First row kept and the row after the last.

        Returns
        -------
        Costs
        """
        return self.block(0, start, stop)

    def columns(self, start: int, stop: int) -> Costs:
        """The costs of a segment of columns (views): :meth:`block` along axis 1.

        Parameters
        ----------
        start : int
            First column kept.
        stop : int
            One past the last column kept.

        Returns
        -------
        Costs
            The segment's costs; horizontal edges that cross its ends are dropped.
        """
        return self.block(1, start, stop)

    def block(self, axis: int, start: int, stop: int) -> Costs:
        """The costs of pixels [start, stop) along ``axis``: edges leaving the block are dropped.

        Parameters
        ----------
        axis : int
            0 for a block of rows, 1 for a block of columns.
        start, stop : int
            The range kept along ``axis``.

        Returns
        -------
        Costs
            Views into this object's arrays.
        """
        pixels = (slice(None),) * axis + (slice(start, stop),)
        # the edges along the axis join pixel i to i + 1: the block keeps those with both ends in it
        inner = (slice(None),) * axis + (slice(start, max(start, stop - 1)),)
        along, across = (self.pair_v, self.pair_h) if axis == 0 else (self.pair_h, self.pair_v)
        kept_along, kept_across = along[inner], across[pixels]
        pair_v, pair_h = (kept_along, kept_across) if axis == 0 else (kept_across, kept_along)
        return Costs(
            candidates=self.candidates[pixels],
            unary=self.unary[pixels],
            pair_h=pair_h,
            pair_v=pair_v,
        )


def smoothness(
    delta: np.ndarray, intensity_step: np.ndarray, level: LevelConfig, regularizer: Regularizer
) -> np.ndarray:
    """R(|delta|) times the edge weight; ``intensity_step`` broadcasts against ``delta``.

    Parameters
    ----------
    delta : numpy.ndarray
        Disparity differences of the edge's two ends, any shape.
    intensity_step : numpy.ndarray
        Gray-level steps across the edges (for the truncated regulariser's edge weight).
    level : LevelConfig
        Slope, truncation, edge threshold and edge factor.
    regularizer : Regularizer
        ``none``, ``linear`` or ``truncated``.

    Returns
    -------
    numpy.ndarray
        Pairwise costs, float64, of the broadcast shape.
    """
    if regularizer is Regularizer.NONE:
        return np.zeros(delta.shape, dtype=np.float64)
    penalty = np.abs(delta).astype(np.float64)
    penalty *= level.slope
    if regularizer is Regularizer.LINEAR:
        return penalty
    np.minimum(penalty, level.truncation, out=penalty)
    penalty *= np.where(intensity_step > level.edge_threshold, level.edge_factor, 1.0)
    return penalty


def mrf_costs(
    unary: np.ndarray,
    candidates: np.ndarray,
    guide: np.ndarray,
    level: LevelConfig,
    regularizer: Regularizer,
    vertical: bool = True,
) -> Costs:
    """The unary and pairwise :class:`Costs` of a block of rows: data costs ``unary`` (h, w, K)
    of the disparities ``candidates`` (h, w, K), and the smoothness of ``regularizer`` with the
    ``level``'s parameters, its weight dropping to m where the gray ``guide`` (h, w) in [0, 1]
    steps. Without ``vertical`` the vertical edges are left at zero: single-row bundles never read
    them.
    """
    candidates = np.asarray(candidates, dtype=np.int32)
    step_h = np.abs(guide[:, 1:] - guide[:, :-1])[:, :, None, None]
    delta_h = candidates[:, :-1, :, None] - candidates[:, 1:, None, :]
    if vertical:
        step_v = np.abs(guide[1:, :] - guide[:-1, :])[:, :, None, None]
        delta_v = candidates[:-1, :, :, None] - candidates[1:, :, None, :]
        pair_v = smoothness(delta_v, step_v, level, regularizer)
    else:
        height, width, labels = candidates.shape
        pair_v = np.zeros((max(height - 1, 0), width, labels, labels))
    return Costs(
        candidates=candidates,
        unary=unary,
        pair_h=smoothness(delta_h, step_h, level, regularizer),
        pair_v=pair_v,
    )


def level_costs(
    left: np.ndarray,
    right: np.ndarray,
    candidates: np.ndarray,
    level: LevelConfig,
    regularizer: Regularizer,
) -> Costs:
    """The paper's level costs: squared gray difference at the candidate disparities (a block
    of rows: pass the rows' image slices).

    Parameters
    ----------
    left, right : numpy.ndarray
        Gray rows (h, w) of the two views in [0, 1].
    candidates : numpy.ndarray
        Disparities (h, w, K) the labels stand for.
    level : LevelConfig
        The level's regulariser parameters.
    regularizer : Regularizer
        ``none``, ``linear`` or ``truncated``.

    Returns
    -------
    Costs
        Unary and pairwise costs of the block.
    """
    candidates = np.asarray(candidates, dtype=np.int32)
    unary = squared_difference(left, right, candidates)
    return mrf_costs(unary, candidates, left, level, regularizer)


def mrf_energy(costs: Costs, labels: np.ndarray) -> float:
    """Energy of a labelling (h, w) of candidate indices under ``costs``.

    Parameters
    ----------
    costs : Costs
        The MRF.
    labels : numpy.ndarray
        Candidate index (h, w) of every pixel.

    Returns
    -------
    float
        Sum of the unary, horizontal and vertical terms.
    """
    labels = np.asarray(labels, dtype=np.intp)
    height, width = labels.shape
    rows, cols = np.ogrid[:height, :width]
    total = costs.unary[rows, cols, labels].sum()
    if width > 1:
        total += costs.pair_h[rows, cols[:, :-1], labels[:, :-1], labels[:, 1:]].sum()
    if height > 1:
        total += costs.pair_v[rows[:-1], cols, labels[:-1], labels[1:]].sum()
    return float(total)


def row_energies(costs: Costs, labels: np.ndarray) -> np.ndarray:
    """Energy of each row of a labelling (h, w) as a chain (unary and horizontal terms): the
    energies of single-row bundles, all at once.

    Parameters
    ----------
    costs : Costs
        The MRF (its vertical terms are not read).
    labels : numpy.ndarray
        Candidate index (h, w) of every pixel.

    Returns
    -------
    numpy.ndarray
        One energy (float64) per row, shape (h,).
    """
    labels = np.asarray(labels, dtype=np.intp)
    height, width = labels.shape
    rows, cols = np.ogrid[:height, :width]
    total = costs.unary[rows, cols, labels].sum(axis=1)
    if width > 1:
        total += costs.pair_h[rows, cols[:, :-1], labels[:, :-1], labels[:, 1:]].sum(axis=1)
    return total
