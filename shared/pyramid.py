"""Coarse-to-fine pyramids: which levels a run has and each level's candidate labels.

Two kinds (``MatchConfig.pyramid``):

image (the paper)
    Level k works on the images downsampled by its factor; labels are disparities in that
    level's pixels. The coarsest level spreads its candidates evenly over [0, max disparity];
    each finer level looks at the window {2d-2, ..., 2d+1} around the upsampled coarser
    estimate d, shifted (not cropped) so that the whole window stays inside [0, max disparity].
bins (accurate)
    Every level works on the full-resolution grid (with ``coarse_grid``, the coarse levels on
    a grid downsampled by :func:`grid_factor`, costs pooled from the full-resolution bins);
    labels are disparity bins b = {b w, ..., b w + w - 1} of width w. The coarsest width is
    the smallest power of two giving at most ``max_coarse_bins`` bins over 0..D, and the width
    halves each level down to 1
    (16-20 px: widths 4, 2, 1; 60 px: 8, 4, 2, 1). The coarsest level takes every bin; a finer
    level takes ``K`` consecutive bins starting ``K/2 - 1`` below the lower child 2b of the
    coarser estimate b (for K = 6: {2b-2, ..., 2b+3}), shifted to stay in range, so both
    children of the coarser bin are always candidates. The finest level (width 1) may take a
    narrower window (``finest_candidates``; the accurate preset's 4: {2b-1, ..., 2b+2}).

Ground truth is never read here.
"""

from __future__ import annotations

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict

from shared.config import LevelConfig, MatchConfig, PyramidKind


class LevelPlan(BaseModel):
    """What level ``index`` of a run is: its image scale, label width and MRF parameters.

    ``downsample`` > 1 in the image pyramid, and in the bin pyramid's coarse levels with
    ``coarse_grid`` (:func:`grid_factor`); ``bin_width`` > 1 only in the bin pyramid.
    ``max_label`` is the largest label of the level (a disparity in level pixels, or a bin);
    ``max_disparity`` is the run's, in full-resolution pixels.
    """

    model_config = ConfigDict(frozen=True)

    index: int
    downsample: int
    bin_width: int
    candidates: int
    max_label: int
    max_disparity: int
    mrf: LevelConfig


def plan(config: MatchConfig, max_disparity: int) -> list[LevelPlan]:
    """The levels of a run, coarse to fine, for a resolved ``max_disparity`` (full-res px).

    Parameters
    ----------
    config : MatchConfig
        The run's configuration (pyramid kind, levels, coarse bin limit).
    max_disparity : int
        The run's resolved maximum disparity, full-resolution px.

    Returns
    -------
    list of LevelPlan
        One plan per level, coarsest first.
    """
    if config.pyramid is PyramidKind.IMAGE:
        return [
            LevelPlan(
                index=index,
                downsample=level.downsample,
                bin_width=1,
                candidates=level.candidates,
                max_label=level_max_disparity(max_disparity, level.downsample),
                max_disparity=max_disparity,
                mrf=level,
            )
            for index, level in enumerate(config.levels)
        ]
    template = config.levels[0]
    widths = bin_widths(max_disparity, config.max_coarse_bins)
    plans = []
    for index, width in enumerate(widths):
        bins = bin_count(max_disparity, width)
        window = template.candidates
        if width == 1 and template.finest_candidates is not None:
            window = template.finest_candidates
        count = bins if index == 0 else min(window, bins)
        mrf = template
        if template.coarse_slope is not None and index < template.coarse_levels:
            mrf = template.model_copy(update={"slope": template.coarse_slope})
        if index >= template.coarse_levels and template.coarse_prior:
            mrf = mrf.model_copy(update={"coarse_prior": 0.0})  # the finer levels take none
        factor = grid_factor(width, config.coarse_grid)
        if factor > 1:  # a block's mean cost against its f boundary pairs: the fine energy / f^2
            mrf = mrf.model_copy(
                update={"slope": mrf.slope / factor, "truncation": mrf.truncation / factor}
            )
        plans.append(
            LevelPlan(
                index=index,
                downsample=factor,
                bin_width=width,
                candidates=count,
                max_label=bins - 1,
                max_disparity=max_disparity,
                mrf=mrf,
            )
        )
    return plans


def grid_factor(bin_width: int, coarse_grid: int) -> int:
    """The spatial downsampling of a bin level (``MatchConfig.coarse_grid``): a quarter of its
    bin width, at most ``coarse_grid``, so a level's cells stay well finer than its labels (a
    bin of w disparities places a surface within w px). Cells of w / 2 px lost thin structures
    where a width-4 level decided them (Tsukuba at 16 px: all-pixel BPP 2.28 -> 2.81 %,
    docs/benchmarks.md "Coarse levels on a smaller grid").

    Parameters
    ----------
    bin_width : int
        Disparities per bin of the level.
    coarse_grid : int
        The largest factor (1: full resolution).

    Returns
    -------
    int
        The factor, at least 1: 1 for widths 1, 2 and 4.
    """
    return max(1, min(coarse_grid, bin_width // 4))


def upsample_labels(level_map: np.ndarray, views: int, shape: tuple[int, int]) -> np.ndarray:
    """A coarser level's map (views * h', w') on the finer grid (views * h, w), view by view
    (no block straddles the seam of the stacked views), nearest neighbour: bin labels count
    disparities, not pixels, so their values are kept.

    Parameters
    ----------
    level_map : numpy.ndarray
        The coarser level's map, ``views`` views stacked.
    views : int
        1 or 2.
    shape : tuple of int
        (height, width) of one view of the finer level.

    Returns
    -------
    numpy.ndarray
        (views * height, width), the map's dtype.
    """
    height, width = shape
    if level_map.shape == (views * height, width):
        return level_map
    coarse = level_map.shape[0] // views
    return np.concatenate(
        [
            cv2.resize(
                level_map[view * coarse : (view + 1) * coarse],
                (width, height),
                interpolation=cv2.INTER_NEAREST,
            )
            for view in range(views)
        ]
    )


def bin_widths(max_disparity: int, max_coarse_bins: int) -> list[int]:
    """Bin widths coarse to fine: powers of two from the coarsest that fits, down to 1.

    Parameters
    ----------
    max_disparity : int
        The run's maximum disparity, px.
    max_coarse_bins : int
        Most bins the coarsest level may have.

    Returns
    -------
    list of int
        Widths, e.g. ``[8, 4, 2, 1]``.
    """
    width = 1
    while bin_count(max_disparity, width) > max_coarse_bins:
        width *= 2
    widths = [width]
    while widths[-1] > 1:
        widths.append(widths[-1] // 2)
    return widths


def bin_count(max_disparity: int, width: int) -> int:
    """Bins of ``width`` disparities covering 0..max_disparity (the last one may be partial).

    Parameters
    ----------
    max_disparity : int
        The run's maximum disparity, px.
    width : int
        Disparities per bin.

    Returns
    -------
    int
        Number of bins.
    """
    return max_disparity // width + 1


def refined_bins(coarse_bins: np.ndarray, count: int, max_bin: int) -> np.ndarray:
    """Candidate bins (h, w, count) of the next finer level from the coarser bin map (h, w).

    Parameters
    ----------
    coarse_bins : numpy.ndarray
        The coarser level's bin map (h, w).
    count : int
        Candidates per pixel at the finer level.
    max_bin : int
        Largest bin of the finer level.

    Returns
    -------
    numpy.ndarray
        Consecutive candidate bins (h, w, count), int32, within [0, max_bin].
    """
    return window_starts(coarse_bins, count, max_bin)[:, :, None] + np.arange(count, dtype=np.int32)


def window_starts(coarse_bins: np.ndarray, count: int, max_bin: int) -> np.ndarray:
    """Each pixel's first candidate bin (h, w) int32 of :func:`refined_bins`: the whole window
    of a bin level in one label per pixel (``LevelInputs.first``)."""
    start = 2 * np.rint(coarse_bins).astype(np.int32) - (count // 2 - 1)
    return np.clip(start, 0, max(0, max_bin + 1 - count))


#: Pixels within this many pixels of a change of the coarser level's bin take no coarse prior
#: (:func:`prior_bins`): the coarser map is blocky there (a coarse grid's cells are 2 px), and
#: an object's edge may need bins beyond the coarser one. Books at 2005's third size: 9.71 %
#: bad with the prior everywhere, 9.58 % with it off within 2 px (8.93 % without a prior).
PRIOR_EDGE_RADIUS = 2


def prior_bins(coarse_map: np.ndarray, views: int) -> np.ndarray:
    """Each pixel's coarser bin for the coarse-to-fine prior (``LevelConfig.coarse_prior``),
    -1 (no prior) within :data:`PRIOR_EDGE_RADIUS` px of a change of bin, view by view.

    Parameters
    ----------
    coarse_map : numpy.ndarray
        The coarser level's map on this level's grid (views * h, w), bins.
    views : int
        1 or 2 (stacked top to bottom).

    Returns
    -------
    numpy.ndarray
        (views * h, w) int32.
    """
    bins = np.rint(coarse_map).astype(np.int32)
    size = 2 * PRIOR_EDGE_RADIUS + 1
    kernel = np.ones((size, size), dtype=np.uint8)
    for view in np.split(bins, views):  # views of ``bins``: written in place
        values = view.astype(np.float32)
        view[cv2.dilate(values, kernel) != cv2.erode(values, kernel)] = -1
    return bins


def outside_coarse_bin(labels: np.ndarray, coarse_bins: np.ndarray) -> np.ndarray:
    """How many bins each candidate label lies outside its coarser bin: 0 for the bin's two
    children (2c and 2c + 1), 1 for the labels next to them, and so on; 0 where the coarser bin
    is -1 (:func:`prior_bins`). The level's ``coarse_prior`` is paid per bin of it.

    Parameters
    ----------
    labels : numpy.ndarray
        (h, w, K) candidate bins of a level.
    coarse_bins : numpy.ndarray
        (h, w) the coarser level's bin of each pixel (integers), or -1.

    Returns
    -------
    numpy.ndarray
        (h, w, K) int32, at least 0.
    """
    coarse = coarse_bins.astype(np.int32)[:, :, None]
    low = 2 * coarse
    outside = np.maximum(np.maximum(low - labels, labels - (low + 1)), 0)
    return np.where(coarse < 0, 0, outside).astype(np.int32)


def nearest_in_window(target: np.ndarray, start: np.ndarray, count: int) -> np.ndarray:
    """Index (h, w) of the candidate nearest ``target`` among ``count`` consecutive labels from
    ``start``, the first of two as near: the argmin of ``|candidates - target|`` without the
    (h, w, count) differences (a 2000 x 2000 pair's two views: 0.8 GB of temporaries).

    Parameters
    ----------
    target : numpy.ndarray
        The labels to approach (h, w), any real values.
    start : numpy.ndarray
        The first candidate of each pixel (h, w), integers.
    count : int
        Candidates per pixel.

    Returns
    -------
    numpy.ndarray
        Candidate index (h, w), int32, in [0, count).
    """
    offset = target.astype(np.float64) - start
    # nearest integer, a tie going down (the first of two as near): ceil(x - 1/2)
    return np.clip(np.ceil(offset - 0.5), 0, count - 1).astype(np.int32)


def level_shape(shape: tuple[int, int], downsample: int) -> tuple[int, int]:
    """(height, width) of an image of ``shape`` downsampled by an integer factor.

    Parameters
    ----------
    shape : tuple of int
        (height, width) at full resolution.
    downsample : int
        The factor.

    Returns
    -------
    tuple of int
        (height, width), each at least 1.
    """
    height, width = shape
    return max(1, round(height / downsample)), max(1, round(width / downsample))


def downsample(image: np.ndarray, factor: int) -> np.ndarray:
    """Anti-aliased downsampling (area averaging) by an integer factor.

    Parameters
    ----------
    image : numpy.ndarray
        (h, w) or (h, w, 3).
    factor : int
        Downsampling factor; 1 returns the image itself.

    Returns
    -------
    numpy.ndarray
        The image at :func:`level_shape`.
    """
    if factor == 1:
        return image
    height, width = level_shape(image.shape[:2], factor)
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)


class RangeWarning(UserWarning):
    """A range the preset's pyramid does not serve (the CLI shows it as one warning line)."""


def served_range(config: MatchConfig) -> int | None:
    """The largest range the image pyramid's coarsest level can hand on without gaps (None for
    the bin pyramid, whose coarsest level takes every bin of any range).

    The coarsest level's candidates are spread evenly over [0, D / f]; after doubling, the next
    level's window {2d - K/2, ..., 2d + K/2 - 1} must reach the true disparity on either side,
    so the spacing may be at most the window's shorter reach (1 for the paper's 4 candidates):
    D <= f (K0 - 1) reach + f - 1, 23 px for the paper's 1/4-resolution level with 6
    candidates (its scenes' range is 20). Beyond it the coarse estimate misses surfaces that
    finer levels cannot recover (synthetic scenes, exact: 10 % bad pixels at 24 px, 26 % at 40,
    50 % at 56, against 1.7, 6.0 and 6.7 % for the accurate preset).
    """
    if config.pyramid is not PyramidKind.IMAGE or len(config.levels) < 2:
        return None
    coarsest, finer = config.levels[0], config.levels[1]
    reach = max(1, finer.candidates - finer.candidates // 2 - 1)
    factor = coarsest.downsample
    return factor * (coarsest.candidates - 1) * reach + factor - 1


def range_warning(config: MatchConfig, max_disparity: int) -> str:
    """What to tell a user whose range exceeds :func:`served_range` ("" when it does not)."""
    served = served_range(config)
    if served is None or max_disparity <= served:
        return ""
    return (
        f"the range {max_disparity} px exceeds the {served} px the {config.preset.value} "
        "preset's image pyramid serves (its coarsest level's candidates are too far apart to "
        "be refined): expect many bad pixels; use --preset accurate (the bin pyramid serves "
        "any range)"
    )


def level_max_disparity(max_disparity: int, downsample_factor: int) -> int:
    """Largest disparity of a level, in that level's pixels.

    Parameters
    ----------
    max_disparity : int
        Full-resolution px.
    downsample_factor : int
        The level's factor.

    Returns
    -------
    int
        At least 1.
    """
    return max(1, max_disparity // downsample_factor)


def initial_candidates(shape: tuple[int, int], count: int, max_disparity: int) -> np.ndarray:
    """Candidates of the coarsest level: ``count`` integers spread evenly over [0, max].

    With the paper's defaults (max 20 px, 1/4 resolution, 6 candidates) these are 0..5.
    Returns an int32 array of shape (h, w, count).

    Parameters
    ----------
    shape : tuple of int
        (height, width) of the level.
    count : int
        Candidates per pixel.
    max_disparity : int
        Largest disparity of the level, level px.

    Returns
    -------
    numpy.ndarray
        The same candidates at every pixel.
    """
    values = np.rint(np.linspace(0, max_disparity, count)).astype(np.int32)
    if max_disparity + 1 < count:  # fewer distinct disparities than candidates: repeat the top
        values = np.minimum(np.arange(count, dtype=np.int32), max_disparity)
    return np.broadcast_to(values, (*shape, count)).copy()


def refined_candidates(
    coarse_disparity: np.ndarray, shape: tuple[int, int], count: int, max_disparity: int
) -> np.ndarray:
    """Candidates of a finer level from the coarser level's (filtered) disparity map.

    The coarse map is upsampled to ``shape`` (nearest neighbour) and doubled; the window
    starts at 2d - 2 (for 4 candidates: {2d-2, ..., 2d+1}) and is shifted into [0, max].

    Parameters
    ----------
    coarse_disparity : numpy.ndarray
        The coarser level's disparity map (h', w'), its px.
    shape : tuple of int
        (height, width) of the finer level.
    count : int
        Candidates per pixel.
    max_disparity : int
        Largest disparity of the finer level, its px.

    Returns
    -------
    numpy.ndarray
        Candidates (h, w, count), int32, consecutive and within [0, max_disparity].
    """
    height, width = shape
    upsampled = cv2.resize(
        np.asarray(coarse_disparity, dtype=np.float32),
        (width, height),
        interpolation=cv2.INTER_NEAREST,
    )
    start = np.rint(2.0 * upsampled).astype(np.int32) - count // 2
    start = np.clip(start, 0, max(0, max_disparity - count + 1))
    candidates = start[:, :, None] + np.arange(count, dtype=np.int32)
    return np.minimum(candidates, max_disparity)


def upsample_disparity(disparity: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Scale a level's disparity map to ``shape`` and to that resolution's pixel units.

    Parameters
    ----------
    disparity : numpy.ndarray
        A level's map (h', w'), level px.
    shape : tuple of int
        Target (height, width).

    Returns
    -------
    numpy.ndarray
        (height, width) float32, target px (nearest neighbour, scaled by the width ratio).
    """
    height, width = shape
    factor = width / disparity.shape[1]
    resized = cv2.resize(
        np.asarray(disparity, dtype=np.float32), (width, height), interpolation=cv2.INTER_NEAREST
    )
    return resized * np.float32(factor)
