"""Middlebury-style evaluation: RMSE and bad-pixel percentage (|d - gt| > 1 px).

Conventions (see the scenes' PROVENANCE.md): stored ground-truth values are disparity x scale;
0 means unknown; a frame of ``border`` pixels is ignored; an optional mask (``all``, ``nonocc``,
``disc``) restricts the evaluated pixels to its non-zero entries.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

BAD_PIXEL_THRESHOLD = 1.0


class Scores(BaseModel):
    """Scores of a disparity map: the one definition (``qhsm eval``, the bench and, with
    numbers that are not finite as null, the API's job metrics)."""

    model_config = ConfigDict(frozen=True)

    rmse: float = Field(description="Root-mean-square error, pixels")
    bpp: float = Field(description="Bad-pixel percentage, |d - gt| > 1 px")
    pixels: int = Field(description="Pixels evaluated")

    def as_dict(self) -> dict[str, Any]:
        """The scores as a JSON-friendly dict (CLI output, job results, bench tables).

        Returns
        -------
        dict
            ``rmse`` (px), ``bpp`` (percent) and ``pixels`` (how many were evaluated).
        """
        return self.model_dump()


def evaluation_mask(
    gt_values: np.ndarray, border: int = 0, mask: np.ndarray | None = None
) -> np.ndarray:
    """Pixels that count: known ground truth, outside the border, inside the mask.

    Parameters
    ----------
    gt_values : numpy.ndarray
        Stored ground truth (h, w); 0 means unknown.
    border : int, optional
        Width of the ignored frame, pixels.
    mask : numpy.ndarray, optional
        (h, w); only its non-zero pixels count.

    Returns
    -------
    numpy.ndarray
        (h, w) bool, True where a pixel is scored.

    Raises
    ------
    ValueError
        If the mask's shape is not the ground truth's.
    """
    keep = np.asarray(gt_values) > 0
    if border > 0:
        frame = np.zeros_like(keep)
        frame[border:-border, border:-border] = True
        keep &= frame
    if mask is not None:
        if mask.shape != keep.shape:
            raise ValueError(f"mask is {mask.shape}, ground truth is {keep.shape}")
        keep &= mask.astype(bool)
    return keep


def evaluate(
    disparity: np.ndarray,
    gt_values: np.ndarray,
    scale: float = 1.0,
    border: int = 0,
    mask: np.ndarray | None = None,
    threshold: float = BAD_PIXEL_THRESHOLD,
) -> Scores:
    """Scores of ``disparity`` against stored ground truth ``gt_values`` (disparity x scale).

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
    if np.shape(disparity) != np.shape(gt_values):
        raise ValueError(
            f"disparity is {np.shape(disparity)[::-1]} (w x h), ground truth is "
            f"{np.shape(gt_values)[::-1]}"
        )
    error = _errors(disparity, gt_values, scale, evaluation_mask(gt_values, border, mask))
    if error.size == 0:
        raise ValueError("no pixel left to evaluate (check border, mask and scale)")
    return Scores(
        rmse=float(np.sqrt(np.mean(error**2))),
        bpp=float(100.0 * np.mean(error > threshold)),
        pixels=error.size,
    )


def _errors(
    disparity: np.ndarray, gt_values: np.ndarray, scale: float, keep: np.ndarray, dtype=np.float64
) -> np.ndarray:
    """|d - gt| in pixels of the kept pixels (one formula for the scores and the error map)."""
    truth = np.asarray(gt_values)[keep].astype(dtype) / scale
    return np.abs(np.asarray(disparity, dtype)[keep] - truth)


def error_map(
    disparity: np.ndarray,
    gt_values: np.ndarray,
    scale: float = 1.0,
    border: int = 0,
    mask: np.ndarray | None = None,
) -> np.ndarray:
    """|d - gt| in pixels where evaluated, NaN elsewhere (for error-map images).

    Parameters
    ----------
    disparity : numpy.ndarray
        The map (h, w), px.
    gt_values : numpy.ndarray
        Stored ground truth (h, w), disparity x ``scale``.
    scale : float, optional
        Stored value per pixel of disparity.
    border : int, optional
        Ignored frame, pixels.
    mask : numpy.ndarray, optional
        Pixels to show (non-zero).

    Returns
    -------
    numpy.ndarray
        (h, w) float32.
    """
    keep = evaluation_mask(gt_values, border, mask)
    errors = np.full(keep.shape, np.nan, np.float32)
    errors[keep] = _errors(disparity, gt_values, scale, keep, np.float32)
    return errors
