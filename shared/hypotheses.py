"""A second hypothesis per pixel for the bin pyramid (``MatchConfig.second_bins``).

A finer level normally sees only the ``K`` bins around the coarser level's choice, so a wall
whose coarse bin came out wrong can never get its true bin back. With ``second_bins`` the finer
level's candidates also take the two children of each pixel's second-best coarse bin: the bin,
at least two away from the chosen one (its neighbours' children are in the window already),
of the lowest coarse data term box-averaged over ``second_bins_radius`` pixels, so that the
runner-up is a region's, not one noisy pixel's. The finer level's MRF then decides between the
two; the candidates are no longer one consecutive window (the grid's general message path).
An option under trial (off by default; docs/benchmarks.md, issue 28): the coarser level's bins
are built again from the views, not read from the pipeline's cached volumes (on a coarse grid's
level, :mod:`shared.coarse_grid`, they are the pooled full-resolution bins).
"""

from __future__ import annotations

import cv2
import numpy as np

from shared.config import DataTerm
from shared.level_inputs import LevelInputs


def second_bins(costs: np.ndarray, chosen: np.ndarray, radius: int) -> np.ndarray:
    """Each pixel's runner-up bin: the least box-averaged cost among the bins at least two away
    from ``chosen`` (``chosen`` itself where there is none).

    Parameters
    ----------
    costs : numpy.ndarray
        The coarse level's bin costs (bins, h, w).
    chosen : numpy.ndarray
        Its bin map (h, w), integers.
    radius : int
        Half the side of the box the costs are averaged over (0: each pixel's own).

    Returns
    -------
    numpy.ndarray
        (h, w) int32 bins.
    """
    per_pixel: np.ndarray = np.ascontiguousarray(np.moveaxis(costs, 0, -1), dtype=np.float32)
    if radius > 0:
        side = 2 * radius + 1
        averaged = cv2.boxFilter(per_pixel, -1, (side, side), borderType=cv2.BORDER_REFLECT)
        per_pixel = averaged.reshape(per_pixel.shape)  # one bin: cv2 drops the axis
    bins = np.arange(costs.shape[0], dtype=np.int32)
    near = np.abs(bins - chosen[:, :, None]) <= 1
    per_pixel[near] = np.inf
    second = per_pixel.argmin(axis=2).astype(np.int32)
    return np.where(near.all(axis=2), chosen, second).astype(np.int32)


def with_second_bins(
    inputs: LevelInputs,
    previous: np.ndarray,
    data_term: DataTerm,
    radius: int,
    coarse: list[np.ndarray] | None = None,
) -> np.ndarray:
    """The level's candidates (rows, w, K + 2): its window plus the two children of each pixel's
    :func:`second_bins` at the coarser level (bins of twice this level's width).

    Parameters
    ----------
    inputs : LevelInputs
        The level (its images, views and window candidates).
    previous : numpy.ndarray
        The coarser level's finished bin map (views * h, w).
    data_term : DataTerm
        The run's data term.
    radius : int
        :func:`second_bins`' box radius.
    coarse : list of numpy.ndarray, optional
        Each view's coarser bin costs on this level's grid (bins, h, w); default: built from
        the level's views (a coarse grid's level passes its pooled ones,
        :mod:`shared.coarse_grid`).

    Returns
    -------
    numpy.ndarray
        int32 candidates, the window's first.
    """
    height = inputs.view_height
    if coarse is None:
        coarse = inputs.binned_view_volumes(data_term, 2 * inputs.plan.bin_width)
    window = inputs.candidate_labels()
    extra = np.empty((*window.shape[:2], 2), dtype=np.int32)
    for view, costs in enumerate(coarse):
        rows = slice(view * height, (view + 1) * height)
        chosen = np.rint(previous[rows]).astype(np.int32)
        children = 2 * second_bins(costs, chosen, radius)[:, :, None] + np.arange(2)
        extra[rows] = np.minimum(children, inputs.plan.max_label)
    return np.concatenate([window, extra], axis=2)
