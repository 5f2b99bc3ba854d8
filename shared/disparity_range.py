"""``max_disparity: auto``: the disparity range estimated from a quick dense match.

Both views are shrunk to about :data:`TARGET_WIDTH` pixels and matched densely by the same
AD-census cost the accurate preset uses, over a generous range (:data:`SEARCH_SHARE` of the
width), winner takes all, in both directions. Only disparities that pass the left-right check and
are unambiguous (the best cost clearly below the best one more than a pixel away) are kept: these
sample the scene's true disparities, including small or weakly textured foreground objects that
sparse feature matches miss. The estimate is a high percentile of them widened by a relative and
an absolute margin. Too wide a range costs time and a little accuracy; too narrow a range loses
the nearest objects, so the margins err on the wide side.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Annotated

import cv2
import numpy as np
from pydantic import Field

from shared.data_terms import ad_census_volume
from shared.images import to_gray

TARGET_WIDTH = 256
SEARCH_SHARE = 0.4
UNIQUENESS = 0.95
PERCENTILE = 99.0
RELATIVE_MARGIN = 1.25
ABSOLUTE_MARGIN = 4.0
#: Fewer confirmed pixels than this share and the estimate falls back to a share of the width.
MIN_CONFIRMED = 0.01
FALLBACK_WIDTH_SHARE = 0.25
LIMIT = 1024


@dataclass(frozen=True)
class RangeEstimate:
    """The chosen maximum disparity (full-resolution px) and how it was found; also the job
    status's ``disparity_range`` (the descriptions are the API's)."""

    max_disparity: Annotated[int, Field(description="Largest disparity, full-resolution px")]
    source: Annotated[str, Field(description="given, auto or auto-fallback")]
    confirmed: Annotated[
        float, Field(description="Share of pixels whose quick match passed both checks")
    ] = 0.0
    note: str = ""

    def as_dict(self) -> dict:
        """The estimate as a JSON-friendly dict (run reports, API responses).

        Returns
        -------
        dict
            The dataclass's fields by name.
        """
        return asdict(self)


def confirmed_disparities(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, int, int]:
    """Positive disparities (full-resolution px) of the pixels whose quick dense match is
    unambiguous and left-right consistent, with the shrink factor and the pixels examined.

    Parameters
    ----------
    left, right : numpy.ndarray
        A rectified pair (h, w) or (h, w, 3) in [0, 1].

    Returns
    -------
    disparities : numpy.ndarray
        The confirmed pixels' disparities, full-resolution px (1-D, int).
    factor : int
        How much the views were shrunk before matching.
    examined : int
        Pixels of the shrunk views.
    """
    left, right = to_gray(left), to_gray(right)
    height, width = left.shape
    factor = max(1, math.ceil(width / TARGET_WIDTH))
    if factor > 1:
        size = (max(1, round(width / factor)), max(1, round(height / factor)))
        left = cv2.resize(left, size, interpolation=cv2.INTER_AREA)
        right = cv2.resize(right, size, interpolation=cv2.INTER_AREA)
    rows, columns = left.shape
    search = max(1, int(SEARCH_SHARE * columns))
    volume = ad_census_volume(left, right, search, 0, rows)
    mirrored = ad_census_volume(right[:, ::-1], left[:, ::-1], search, 0, rows)
    disparity = volume.argmin(axis=0)
    right_disparity = mirrored.argmin(axis=0)[:, ::-1]
    best = volume.min(axis=0)
    near = np.abs(np.arange(search + 1)[:, None, None] - disparity[None]) <= 1
    runner_up = np.where(near, np.inf, volume).min(axis=0)
    target = np.arange(columns)[None, :] - disparity
    back = right_disparity[np.arange(rows)[:, None], np.clip(target, 0, columns - 1)]
    confirmed = (
        (disparity > 0)
        & (target >= 0)
        & (np.abs(back - disparity) <= 1)
        & (best < UNIQUENESS * runner_up)
    )
    return disparity[confirmed] * factor, factor, rows * columns


def estimate_max_disparity(left: np.ndarray, right: np.ndarray) -> RangeEstimate:
    """The maximum disparity of a rectified pair, estimated without any ground truth.

    Parameters
    ----------
    left, right : numpy.ndarray
        The rectified views, gray or BGR, float in [0, 1].

    Returns
    -------
    RangeEstimate
        Source ``"auto"``, or ``"auto-fallback"`` (a quarter of the width, with a note saying why)
        when too few pixels matched reliably.
    """
    width = left.shape[1]
    ceiling = max(1, min(LIMIT, width - 1))
    values, _, examined = confirmed_disparities(left, right)
    share = values.size / max(examined, 1)
    if share < MIN_CONFIRMED:
        guess = max(1, min(ceiling, math.ceil(FALLBACK_WIDTH_SHARE * width)))
        return RangeEstimate(
            guess,
            "auto-fallback",
            share,
            f"only {100 * share:.1f} % of the pixels matched reliably (are the views swapped, "
            "or not rectified?); assumed a quarter of the width. Give --max-disparity if you "
            "know the range",
        )
    high = float(np.percentile(values, PERCENTILE))
    value = math.ceil(RELATIVE_MARGIN * high + ABSOLUTE_MARGIN)
    return RangeEstimate(max(1, min(ceiling, value)), "auto", share)


def resolve_max_disparity(
    left: np.ndarray, right: np.ndarray, max_disparity: int | str
) -> RangeEstimate:
    """The run's maximum disparity: the given one, or the estimate when it is ``auto``.

    Parameters
    ----------
    left, right : numpy.ndarray
        A rectified pair (h, w) or (h, w, 3) in [0, 1].
    max_disparity : int or str
        Full-resolution px, or ``"auto"``.

    Returns
    -------
    RangeEstimate
        Source ``"given"`` for an int, else :func:`estimate_max_disparity`'s.
    """
    if isinstance(max_disparity, int):
        return RangeEstimate(max_disparity, "given")
    return estimate_max_disparity(left, right)
