"""Middlebury-style evaluation: RMSE and bad-pixel percentage (|d - gt| > 1 px).

Conventions (see the scenes' PROVENANCE.md): stored ground-truth values are disparity x scale;
0 means unknown; a frame of ``border`` pixels is ignored; an optional mask (``all``, ``nonocc``,
``disc``) restricts the evaluated pixels to its non-zero entries.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

BAD_PIXEL_THRESHOLD = 1.0


@dataclass(frozen=True)
class Scores:
    rmse: float
    bpp: float
    pixels: int

    def as_dict(self) -> dict[str, float]:
        """The scores as a JSON-friendly dict (CLI output, job results, bench tables).

        Returns
        -------
        dict
            ``rmse`` (px), ``bpp`` (percent) and ``pixels`` (how many were evaluated).
        """
        return asdict(self)


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
    disparity = np.asarray(disparity, dtype=np.float64)
    if disparity.shape != gt_values.shape:
        raise ValueError(
            f"disparity is {disparity.shape[::-1]} (w x h), ground truth is {gt_values.shape[::-1]}"
        )
    keep = evaluation_mask(gt_values, border, mask)
    count = int(keep.sum())
    if count == 0:
        raise ValueError("no pixel left to evaluate (check border, mask and scale)")
    error = np.abs(disparity[keep] - gt_values[keep].astype(np.float64) / scale)
    return Scores(
        rmse=float(np.sqrt(np.mean(error**2))),
        bpp=float(100.0 * np.mean(error > threshold)),
        pixels=count,
    )


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
    error = np.abs(np.asarray(disparity, np.float32) - gt_values.astype(np.float32) / scale)
    return np.where(keep, error, np.nan).astype(np.float32)
