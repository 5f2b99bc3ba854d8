"""The MRF of one pyramid level as cost arrays, and its energy.

For candidate index l of pixel p = (y, x) with disparity d = C[y, x, l] (left view):

    unary[y, x, l]      = (I_L(y, x) - I_R(y, x - d))^2          (x - d clamped to the image)
    pair_h[y, x, l, s]  = w(p, q) * R(|C[p, l] - C[q, s]|)         q = (y, x + 1)
    pair_v[y, x, l, s]  = w(p, q) * R(|C[p, l] - C[q, s]|)         q = (y + 1, x)

with R(t) = min(trunc, s t) and w = m where |I_L(p) - I_L(q)| > thr, else 1 ("truncated"), or
R(t) = s t and w = 1 ("linear"), or R = 0 ("none"). All costs are non-negative, which the
rectifier proofs in :mod:`shared.encodings` rely on. These arrays are the one description of the
level: the exact row DP, both QUBO codecs and the reported energies all read them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shared.config import LevelConfig, Regularizer


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

    def rows(self, start: int, stop: int) -> Costs:
        """The costs of rows [start, stop): edges leaving the block are dropped."""
        return Costs(
            candidates=self.candidates[start:stop],
            unary=self.unary[start:stop],
            pair_h=self.pair_h[start:stop],
            pair_v=self.pair_v[start : max(start, stop - 1)],
        )


def data_costs(left: np.ndarray, right: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """(I_L(y, x) - I_R(y, x - d))^2 for every candidate d; x - d is clamped at the border."""
    height, width, _ = candidates.shape
    columns = np.arange(width)[None, :, None] - candidates
    np.clip(columns, 0, width - 1, out=columns)
    rows = np.arange(height)[:, None, None]
    diff = left[:, :, None].astype(np.float64) - right[rows, columns]
    return diff * diff


def smoothness(
    delta: np.ndarray, intensity_step: np.ndarray, level: LevelConfig, regularizer: Regularizer
) -> np.ndarray:
    """R(|delta|) times the edge weight; ``intensity_step`` broadcasts against ``delta``."""
    if regularizer is Regularizer.NONE:
        return np.zeros(delta.shape, dtype=np.float64)
    penalty = level.slope * np.abs(delta).astype(np.float64)
    if regularizer is Regularizer.LINEAR:
        return penalty
    np.minimum(penalty, level.truncation, out=penalty)
    weight = np.where(intensity_step > level.edge_threshold, level.edge_factor, 1.0)
    return penalty * weight


def level_costs(
    left: np.ndarray,
    right: np.ndarray,
    candidates: np.ndarray,
    level: LevelConfig,
    regularizer: Regularizer,
) -> Costs:
    """All cost arrays of a level (or of a block of its rows: pass the rows' image slices)."""
    candidates = np.asarray(candidates, dtype=np.int32)
    step_h = np.abs(left[:, 1:] - left[:, :-1])[:, :, None, None]
    step_v = np.abs(left[1:, :] - left[:-1, :])[:, :, None, None]
    delta_h = candidates[:, :-1, :, None] - candidates[:, 1:, None, :]
    delta_v = candidates[:-1, :, :, None] - candidates[1:, :, None, :]
    return Costs(
        candidates=candidates,
        unary=data_costs(left, right, candidates),
        pair_h=smoothness(delta_h, step_h, level, regularizer),
        pair_v=smoothness(delta_v, step_v, level, regularizer),
    )


def mrf_energy(costs: Costs, labels: np.ndarray) -> float:
    """Energy of a labelling (h, w) of candidate indices under ``costs``."""
    labels = np.asarray(labels, dtype=np.intp)
    height, width = labels.shape
    rows, cols = np.ogrid[:height, :width]
    total = costs.unary[rows, cols, labels].sum()
    if width > 1:
        total += costs.pair_h[rows, cols[:, :-1], labels[:, :-1], labels[:, 1:]].sum()
    if height > 1:
        total += costs.pair_v[rows[:-1], cols, labels[:-1], labels[1:]].sum()
    return float(total)


def disparities(costs: Costs, labels: np.ndarray) -> np.ndarray:
    """The disparity each pixel's label stands for (float32, level pixels)."""
    picked = np.take_along_axis(costs.candidates, labels[:, :, None].astype(np.intp), axis=2)
    return picked[:, :, 0].astype(np.float32)
