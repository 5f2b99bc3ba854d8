"""A level's map and the run's final maps from solved labels: the per-level median, then at full
resolution the sub-pixel fit, the left-right check (the validity map) with its background fill,
and the final edge-preserving filter; the provenance map (:mod:`shared.provenance_map`) follows
each step."""

from __future__ import annotations

import numpy as np

from shared import filters, pyramid
from shared import provenance_map as pm
from shared.assembly import LevelSolution
from shared.config import MatchConfig
from shared.data_terms import VolumeBlock, cost_volume, window_reach
from shared.level_inputs import LevelInputs
from shared.pyramid import LevelPlan


def finish_level(inputs: LevelInputs, solution: LevelSolution, config: MatchConfig) -> np.ndarray:
    """The level's map (labels of the level: disparities or bins) from its solution, median-
    filtered view by view if enabled.

    Parameters
    ----------
    inputs : LevelInputs
        The level's inputs.
    solution : LevelSolution
        Its solution (candidate index per pixel).
    config : MatchConfig
        The run's configuration (median filter and its size).

    Returns
    -------
    numpy.ndarray
        The level map (views * h, w), float32.
    """
    level_map = inputs.picked(solution.labels).astype(np.float32)
    if config.median:
        height = inputs.view_height
        for view in range(inputs.views):
            rows = slice(view * height, (view + 1) * height)
            level_map[rows] = filters.median(level_map[rows], config.median_size)
    return level_map


def level_stages(inputs: LevelInputs, solution: LevelSolution, level_map: np.ndarray) -> np.ndarray:
    """The level's provenance codes (:class:`shared.provenance_map.Stage`) after
    :func:`finish_level`: the solution's, :attr:`~shared.provenance_map.Stage.FILTERED` where
    the median moved the label's value.

    Parameters
    ----------
    inputs : LevelInputs
        The level's inputs.
    solution : LevelSolution
        Its solution (``stages`` None: every pixel the host's).
    level_map : numpy.ndarray
        Its :func:`finish_level` map.

    Returns
    -------
    numpy.ndarray
        uint8 (views * h, w).
    """
    picked = inputs.picked(solution.labels)
    stages = (
        pm.filled(level_map.shape, pm.Stage.HOST) if solution.stages is None else solution.stages
    )
    return pm.moved(stages, picked.astype(np.float32), level_map)


def finish_maps(
    level_map: np.ndarray,
    left: np.ndarray,
    right: np.ndarray,
    config: MatchConfig,
    last: LevelPlan,
    views: int,
    left_volume: np.ndarray | None = None,
    stages: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """The full-resolution left disparity from the finest level's map (both views stacked when
    ``views`` is 2) and the pair's :func:`shared.pipeline.match_views`; ``left_volume`` is the
    left view's cost volume when already at hand (the sub-pixel fit reads it).

    The provenance map follows the finest level's codes (``stages``, :func:`level_stages`; the
    finest level decides, coarser levels' codes are not carried): upsampled nearest, the
    left-right check's filled pixels :attr:`~shared.provenance_map.Stage.FILLED`, the pixels a
    final filter moved by more than :data:`shared.provenance_map.MOVED` px
    :attr:`~shared.provenance_map.Stage.FILTERED`. The sub-pixel fit refines a label within
    its step and is not counted.

    Parameters
    ----------
    level_map : numpy.ndarray
        The finest level's :func:`finish_level` map.
    left, right : numpy.ndarray
        The pair's :func:`shared.pipeline.match_views`.
    config : MatchConfig
        The run's configuration (which filters run).
    last : LevelPlan
        The finest level.
    views : int
        Views stacked in ``level_map`` (1 or 2).
    left_volume : numpy.ndarray, optional
        The left view's cost volume (D + 1, h, w), if already computed.
    stages : numpy.ndarray, optional
        The finest level's :func:`level_stages` (both views stacked, as ``level_map``).

    Returns
    -------
    disparity : numpy.ndarray
        The left view's disparity (h, w), float32, full-resolution px.
    validity : numpy.ndarray or None
        Where the left-right check confirmed the pixel before it was filled, never in the
        last :func:`~shared.data_terms.window_reach` columns (None with one view).
    provenance : numpy.ndarray or None
        The provenance map (h, w) uint8 (None without ``stages``).
    """
    height = level_map.shape[0] // views
    valid = None
    disparity = level_map[:height]
    provenance = None if stages is None else pm.upsample(stages[:height], left.shape[:2])
    if config.subpixel:  # the cost of every disparity around the label
        if left_volume is None:
            block = VolumeBlock(last.max_disparity, 0, height)
            left_volume = cost_volume(config.data_term, left, right, block)
        disparity = filters.subpixel(disparity, left_volume)
    if disparity.shape != left.shape[:2]:
        disparity = pyramid.upsample_disparity(disparity, left.shape[:2])
    if views == 2:
        right_disparity = pyramid.upsample_disparity(level_map[height:, ::-1], left.shape[:2])
        valid = filters.left_right_check(disparity, right_disparity, config.lr_tolerance)
        valid[:, valid.shape[1] - window_reach(config.data_term) :] = False  # padding's labels
        disparity = filters.fill_from_background(disparity, valid)
        if provenance is not None:
            provenance = np.where(valid, provenance, np.uint8(pm.Stage.FILLED))
    if config.weighted_median:
        before = disparity
        disparity = filters.weighted_median(
            disparity, left, config.weighted_median_radius, config.weighted_median_sigma
        )
        provenance = None if provenance is None else pm.moved(provenance, before, disparity)
    if config.bilateral:
        before = disparity
        disparity = filters.bilateral(
            disparity,
            config.bilateral_diameter,
            config.bilateral_sigma_color,
            config.bilateral_sigma_space,
        )
        provenance = None if provenance is None else pm.moved(provenance, before, disparity)
    return disparity.astype(np.float32), valid, provenance
