"""Evaluation with the benchmarks' own measures: Middlebury's RMSE, avgerr and bad-0.5/1/2/4
(percent of pixels with |d - gt| above 0.5, 1, 2, 4 px) and KITTI's D1 (percent of pixels whose
error exceeds both 3 px and 5 % of the true disparity), plus ``bpp`` at a chosen threshold.

Conventions (see the scenes' PROVENANCE.md): stored ground-truth values are disparity x scale;
0 means unknown; a frame of ``border`` pixels is ignored; an optional mask (``all``, ``nonocc``,
``disc``) restricts the evaluated pixels to its non-zero entries.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

BAD_PIXEL_THRESHOLD = 1.0
#: Middlebury's bad-pixel thresholds (px), the ``bad_*`` fields of :class:`Scores`.
MIDDLEBURY_THRESHOLDS = (0.5, 1.0, 2.0, 4.0)
#: KITTI's D1: a pixel is an outlier when its error exceeds both (px, share of the truth).
KITTI_D1 = (3.0, 0.05)


class Scores(BaseModel):
    """Scores of a disparity map: the one definition (``qhsm eval``, the bench and, with
    numbers that are not finite as null, the API's job metrics)."""

    model_config = ConfigDict(frozen=True)

    rmse: float = Field(description="Root-mean-square error, pixels")
    bpp: float = Field(description="Bad-pixel percentage, |d - gt| > threshold (1 px default)")
    pixels: int = Field(description="Pixels evaluated")
    threshold: float = Field(BAD_PIXEL_THRESHOLD, description="bpp's threshold, pixels")
    avgerr: float | None = Field(None, description="Mean |d - gt|, pixels (Middlebury avgerr)")
    bad_0_5: float | None = Field(None, description="Percent |d - gt| > 0.5 px (Middlebury)")
    bad_1: float | None = Field(None, description="Percent |d - gt| > 1 px (Middlebury)")
    bad_2: float | None = Field(None, description="Percent |d - gt| > 2 px (Middlebury)")
    bad_4: float | None = Field(None, description="Percent |d - gt| > 4 px (Middlebury)")
    d1: float | None = Field(None, description="Percent |d - gt| > 3 px and > 5 % of gt (KITTI D1)")

    def as_dict(self) -> dict[str, Any]:
        """The scores as a JSON-friendly dict (CLI output, job results, bench tables).

        Returns
        -------
        dict
            ``rmse`` (px), ``bpp`` (percent), ``pixels`` (how many were evaluated), and the
            Middlebury and KITTI measures.
        """
        return self.model_dump()


@dataclass(frozen=True)
class Truth:
    """Where and against what a map is scored: the stored ground truth ``values`` (h, w),
    disparity x ``scale``, 0 where unknown; a frame of ``border`` pixels ignored; with a
    ``mask`` (h, w), only its non-zero pixels count. The scores (:meth:`scores`) and the error
    map (:meth:`error_map`) read the same pixels with the same formula."""

    values: np.ndarray
    #: Stored value per pixel of disparity.
    scale: float = 1.0
    #: Width of the ignored frame, pixels.
    border: int = 0
    mask: np.ndarray | None = None

    def kept(self) -> np.ndarray:
        """(h, w) bool, True where a pixel is scored: known ground truth, outside the border,
        inside the mask (``ValueError`` if the mask's shape is not the ground truth's)."""
        keep = np.asarray(self.values) > 0
        if self.border > 0:
            frame = np.zeros_like(keep)
            frame[self.border : -self.border, self.border : -self.border] = True
            keep &= frame
        if self.mask is not None:
            if self.mask.shape != keep.shape:
                raise ValueError(f"mask is {self.mask.shape}, ground truth is {keep.shape}")
            keep &= self.mask.astype(bool)
        return keep

    def errors(self, disparity: np.ndarray, keep: np.ndarray, dtype=np.float64) -> np.ndarray:
        """|d - gt| in pixels of the ``keep`` pixels (one formula for scores and error map)."""
        truth = np.asarray(self.values)[keep].astype(dtype) / self.scale
        return np.abs(np.asarray(disparity, dtype)[keep] - truth)

    def scores(self, disparity: np.ndarray, threshold: float = BAD_PIXEL_THRESHOLD) -> Scores:
        """Scores of ``disparity`` (h, w), px; ``threshold``: error above which a pixel is bad
        (``ValueError`` if the shapes differ or no pixel is left to evaluate)."""
        if np.shape(disparity) != np.shape(self.values):
            raise ValueError(
                f"disparity is {np.shape(disparity)[::-1]} (w x h), ground truth is "
                f"{np.shape(self.values)[::-1]}"
            )
        keep = self.kept()
        error = self.errors(disparity, keep)
        if error.size == 0:
            raise ValueError("no pixel left to evaluate (check border, mask and scale)")
        truth = np.asarray(self.values)[keep].astype(np.float64) / self.scale

        def percent(bad: np.ndarray) -> float:
            return float(100.0 * np.mean(bad))

        pixels, share = KITTI_D1
        return Scores(
            rmse=float(np.sqrt(np.mean(error**2))),
            bpp=percent(error > threshold),
            pixels=error.size,
            threshold=threshold,
            avgerr=float(np.mean(error)),
            **{
                f"bad_{limit:g}".replace(".", "_"): percent(error > limit)
                for limit in MIDDLEBURY_THRESHOLDS
            },
            d1=percent((error > pixels) & (error > share * np.abs(truth))),
        )

    def error_map(self, disparity: np.ndarray) -> np.ndarray:
        """|d - gt| in pixels where scored, NaN elsewhere (for error-map images): (h, w)
        float32."""
        keep = self.kept()
        errors = np.full(keep.shape, np.nan, np.float32)
        errors[keep] = self.errors(disparity, keep, np.float32)
        return errors


def evaluate(
    disparity: np.ndarray,
    gt_values: np.ndarray,
    scale: float = 1.0,
    border: int = 0,
    mask: np.ndarray | None = None,
    threshold: float = BAD_PIXEL_THRESHOLD,
) -> Scores:
    """Scores of ``disparity`` against stored ground truth ``gt_values`` (disparity x scale):
    :meth:`Truth.scores` of ``Truth(gt_values, scale, border, mask)``.

    Parameters
    ----------
    disparity : numpy.ndarray
        The map to score (h, w), px.
    gt_values : numpy.ndarray
        Stored ground truth (h, w), disparity x ``scale``; 0 means unknown.
    scale : float, optional
        Stored value per pixel of disparity.
    border : int, optional
        Width of the ignored frame, pixels.
    mask : numpy.ndarray, optional
        (h, w); only its non-zero pixels count.
    threshold : float, optional
        Error above which a pixel is bad, px.

    Returns
    -------
    Scores

    Raises
    ------
    ValueError
        If the shapes differ or no pixel is left to evaluate.
    """
    return Truth(gt_values, scale, border, mask).scores(disparity, threshold)


def evaluate_regions(
    disparity: np.ndarray,
    gt_values: np.ndarray,
    regions: dict[str, np.ndarray | None],
    scale: float = 1.0,
    border: int = 0,
    threshold: float = BAD_PIXEL_THRESHOLD,
    mask: np.ndarray | None = None,
) -> dict[str, Scores]:
    """:func:`evaluate` on every pixel (``all``, within ``mask`` if given) and on each named
    region within it (e.g. ``nonocc``, KITTI's ``bg`` / ``fg``); regions that are None or hold
    no known pixel are left out."""
    base = np.ones(np.shape(gt_values), bool) if mask is None else mask.astype(bool)
    scores = {"all": evaluate(disparity, gt_values, scale, border, base, threshold)}
    for name, region in regions.items():
        if region is None:
            continue
        inside = Truth(gt_values, scale, border, base & region.astype(bool))
        if inside.kept().any():
            scores[name] = inside.scores(disparity, threshold)
    return scores
