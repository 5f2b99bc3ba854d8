"""A level's map and the run's final maps from solved labels: the per-level median, then at full
resolution the sub-pixel fit, the left-right check (the validity map) with its background fill,
and the final edge-preserving filter."""

from __future__ import annotations

import numpy as np

from shared import filters, pyramid
from shared.assembly import LevelSolution
from shared.config import MatchConfig
from shared.data_terms import cost_volume
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
    picked = np.take_along_axis(inputs.candidates, solution.labels[:, :, None], axis=2)[:, :, 0]
    level_map = picked.astype(np.float32)
    if config.median:
        height = inputs.view_height
        for view in range(inputs.views):
            rows = slice(view * height, (view + 1) * height)
            level_map[rows] = filters.median(level_map[rows], config.median_size)
    return level_map


def finish_maps(
    level_map: np.ndarray,
    left: np.ndarray,
    right: np.ndarray,
    config: MatchConfig,
    last: LevelPlan,
    views: int,
    left_volume: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """The full-resolution left disparity from the finest level's map (both views stacked when
    ``views`` is 2) and the pair's :func:`shared.pipeline.match_views`; ``left_volume`` is the
    left view's cost volume when already at hand (the sub-pixel fit reads it).

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

    Returns
    -------
    disparity : numpy.ndarray
        The left view's disparity (h, w), float32, full-resolution px.
    validity : numpy.ndarray or None
        Where the left-right check confirmed the pixel before it was filled (None with one
        view).
    """
    height = level_map.shape[0] // views
    valid = None
    disparity = level_map[:height]
    if config.subpixel:  # the cost of every disparity around the label
        if left_volume is None:
            left_volume = cost_volume(config.data_term, left, right, last.max_disparity, 0, height)
        disparity = filters.subpixel(disparity, left_volume)
    if disparity.shape != left.shape[:2]:
        disparity = pyramid.upsample_disparity(disparity, left.shape[:2])
    if views == 2:
        right_disparity = pyramid.upsample_disparity(level_map[height:, ::-1], left.shape[:2])
        valid = filters.left_right_check(disparity, right_disparity, config.lr_tolerance)
        disparity = filters.fill_from_background(disparity, valid)
    if config.weighted_median:
        disparity = filters.weighted_median(
            disparity, left, config.weighted_median_radius, config.weighted_median_sigma
        )
    if config.bilateral:
        disparity = filters.bilateral(
            disparity,
            config.bilateral_diameter,
            config.bilateral_sigma_color,
            config.bilateral_sigma_space,
        )
    return disparity.astype(np.float32), valid
