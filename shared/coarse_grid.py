"""Coarse bin levels on a smaller grid (``MatchConfig.coarse_grid``): a level whose bins span
several disparities does not need every pixel. Its grid is the images downsampled by
:func:`shared.pyramid.grid_factor`; its data term is the full-resolution bin costs averaged
over each block (area resampling, every bin at once), so a block's cost is the mean of its
pixels' costs for one label, what the fine grid's energy of a block-constant map charges per
pixel; its edge weights are the downsampled image's. The level's map is upsampled (nearest) to
the finer grid, where the next level's windows are centred (:func:`shared.pyramid.upsample_labels`).
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from shared.config import DataTerm
from shared.data_terms import bin_minimum
from shared.level_inputs import LevelInputs
from shared.pyramid import LevelPlan
from shared.threads import each_beside

#: Most planes :func:`pool` resamples in one call (OpenCV's area resampling takes at most 4
#: channels when the factor is not an integer, 641 -> 320 columns).
POOL_PLANES = 4


def pool(costs: np.ndarray, shape: tuple[int, int], ratio: int = 1) -> np.ndarray:
    """(bins, H, W) costs averaged over blocks onto (bins, h, w), float32 (INTER_AREA: exact
    block means for an integer factor, area weights otherwise); with ``ratio`` > 1, of the
    minima of every ``ratio`` bins (:func:`shared.data_terms.bin_minimum`), taken
    :data:`POOL_PLANES` at a time: the wider bins of a whole view are never held.

    Parameters
    ----------
    costs : numpy.ndarray
        One view's bin costs at full resolution.
    shape : tuple of int
        (h, w) of the coarse grid.
    ratio : int, optional
        Bins of ``costs`` per pooled bin (the last may hold fewer).

    Returns
    -------
    numpy.ndarray
        (ceil(bins / ratio), h, w) float32.
    """
    height, width = shape
    bins = -(-costs.shape[0] // ratio)
    out = np.empty((bins, height, width), dtype=np.float32)
    for start in range(0, bins, POOL_PLANES):
        wider = bin_minimum(costs[start * ratio : (start + POOL_PLANES) * ratio], ratio)
        planes = wider.astype(np.float32, copy=False)
        stacked = np.ascontiguousarray(planes.transpose(1, 2, 0))
        resized = cv2.resize(stacked, (width, height), interpolation=cv2.INTER_AREA)
        out[start : start + len(planes)] = resized.reshape(height, width, -1).transpose(2, 0, 1)
    return out


def fine_inputs(left: np.ndarray, right: np.ndarray, views: int, plan: LevelPlan) -> LevelInputs:
    """The full-resolution views of a bin pyramid as a level without candidates: what the
    run's cached volumes and a coarse grid's pooled costs are built from.

    Parameters
    ----------
    left, right : numpy.ndarray
        The stacked full-resolution views (:func:`shared.pipeline.level_views` at factor 1).
    views : int
        1 or 2.
    plan : LevelPlan
        Any level of the run (its range; the grid factor is set to 1).

    Returns
    -------
    LevelInputs
    """
    return LevelInputs(
        plan=plan.model_copy(update={"downsample": 1}),
        left=left,
        right=right,
        candidates=np.empty((0, 0, 0), dtype=np.int32),
        views=views,
    )


def pooled_costs(
    fine: LevelInputs, plan: LevelPlan, data_term: DataTerm, shape: tuple[int, int]
) -> np.ndarray:
    """A coarse-grid level's bin costs (views, bins, h, w) from the full-resolution views.

    Parameters
    ----------
    fine : LevelInputs
        :func:`fine_inputs`, with the run's cached volumes when there are (in process).
    plan : LevelPlan
        The coarse level (its bin width).
    data_term : DataTerm
        The run's data term.
    shape : tuple of int
        (h, w) of one view of the coarse grid.

    Returns
    -------
    numpy.ndarray
        float32 (views, bins, h, w).
    """
    if fine.volumes is not None and plan.bin_width % fine.volume_bin_width == 0:
        # the run's cache, pooled a few of the level's bins at a time
        ratio = plan.bin_width // fine.volume_bin_width
        return np.stack(each_beside(pool, [(v, shape, ratio) for v in fine.volumes]))
    level = replace(fine, plan=plan.model_copy(update={"downsample": 1}))
    views = [(costs, shape) for costs in level.level_bin_costs(data_term)]
    return np.stack(each_beside(pool, views))
