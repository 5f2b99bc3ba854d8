"""The quick dense match of a pair: ``max_disparity: auto`` (the disparity range estimated from
it), and a check that the views are what the matcher expects (left first, rectified).

Both views are shrunk to about :data:`TARGET_WIDTH` pixels and matched densely by the same
AD-census cost the accurate preset uses, over a generous range (:data:`SEARCH_SHARE` of the
width), winner takes all, in both directions. Only disparities that pass the left-right check and
are unambiguous (the best cost clearly below the best one more than a pixel away) are kept: these
sample the scene's true disparities, including small or weakly textured foreground objects that
sparse feature matches miss. The estimate is a high percentile of them widened by a relative and
an absolute margin. Too wide a range costs time and a little accuracy; too narrow a range loses
the nearest objects, so the margins err on the wide side.

The same match with the views in the other order checks them: a rectified pair with the left
view first confirms 3-7x more pixels in its own order than in the other (20 Middlebury scenes,
``benchmarks/view_checks.py``), where chance agreement confirms 10-30 %. Far more in the other
order means the views are swapped; about as many in both (noise, unrelated images, a vertical
offset or rotation) means they are not rectified, or have too little texture to tell. Either
way the matcher would return garbage, so the run goes on with a :class:`ViewsWarning` that
says what to do (and the same text in :attr:`RangeEstimate.warning`).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass, replace
from typing import Annotated

import cv2
import numpy as np
from pydantic import Field

from shared.data_terms import VolumeBlock, ad_census_volume
from shared.filters import lowest
from shared.images import to_gray
from shared.threads import beside

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
#: The other order of the views confirms this many times more pixels: they are swapped.
SWAPPED_RATIO = 2.0
#: The given order confirms fewer than this many times the other's: they are not rectified.
RECTIFIED_RATIO = 2.0
#: Mean absolute difference (of [0, 1] grey) below which the two views are one image.
SAME_IMAGE_DIFFERENCE = 0.5 / 255


class ViewsWarning(UserWarning):
    """The views do not look like a rectified pair with the left view first."""


class ViewsRefusedError(ValueError):
    """A run stopped because its views failed the check (the message is the check's warning);
    ``qhsm match --force`` / ``qhsm.match(force=True)`` run anyway."""

    def __str__(self) -> str:
        return f"{self.args[0]}; stopped before the run (--force to run anyway)"


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
    warning: Annotated[
        str,
        Field(
            description="Empty, or why the views do not look like a rectified pair with the "
            "left view first (swapped, not rectified, one image twice) and what to do"
        ),
    ] = ""

    def as_dict(self) -> dict:
        """The estimate as a JSON-friendly dict (run reports, API responses).

        Returns
        -------
        dict
            The dataclass's fields by name.
        """
        return asdict(self)


@dataclass(frozen=True)
class QuickMatch:
    """The quick dense match of a pair at its shrunk size.

    Attributes
    ----------
    disparity : numpy.ndarray
        Winner-takes-all disparity of every shrunk pixel, full-resolution px (int).
    confirmed : numpy.ndarray
        Pixels whose match is unambiguous and left-right consistent (bool, same shape).
    factor : int
        How much the views were shrunk before matching.
    """

    disparity: np.ndarray
    confirmed: np.ndarray
    factor: int

    @property
    def share(self) -> float:
        """Share of the shrunk pixels whose match is confirmed."""
        return float(self.confirmed.mean()) if self.confirmed.size else 0.0

    def values(self) -> np.ndarray:
        """The confirmed pixels' disparities, full-resolution px (1-D)."""
        return self.disparity[self.confirmed]


def quick_match(left: np.ndarray, right: np.ndarray) -> QuickMatch:
    """Dense AD-census match of the pair shrunk to about :data:`TARGET_WIDTH` px, positive
    disparities up to :data:`SEARCH_SHARE` of the width, with its left-right check and
    uniqueness test.

    Parameters
    ----------
    left, right : numpy.ndarray
        A rectified pair (h, w) or (h, w, 3) in [0, 1].

    Returns
    -------
    QuickMatch
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
    block = VolumeBlock(search, 0, rows)
    volume = ad_census_volume(left, right, block)
    mirrored = ad_census_volume(right[:, ::-1], left[:, ::-1], block)
    disparity, best = lowest(volume)
    right_disparity = lowest(mirrored)[0][:, ::-1]
    runner_up = lowest(volume, outside=disparity)[1]
    target = np.arange(columns)[None, :] - disparity
    back = right_disparity[np.arange(rows)[:, None], np.clip(target, 0, columns - 1)]
    confirmed = (
        (disparity > 0)
        & (target >= 0)
        & (np.abs(back - disparity) <= 1)
        & (best < UNIQUENESS * runner_up)
    )
    return QuickMatch(disparity * factor, confirmed, factor)


def views_warning(
    left: np.ndarray,
    right: np.ndarray,
    forward: QuickMatch | None = None,
    reverse: QuickMatch | None = None,
) -> str:
    """Why the pair does not look like rectified views with the left one first, and what to
    do; empty when it does.

    Parameters
    ----------
    left, right : numpy.ndarray
        The views as given (h, w) or (h, w, 3) in [0, 1].
    forward : QuickMatch, optional
        :func:`quick_match` of ``(left, right)`` when already at hand.
    reverse : QuickMatch, optional
        :func:`quick_match` of ``(right, left)`` when already at hand.

    Returns
    -------
    str
        ``""``, or a sentence for the user (swapped views, not rectified, one image twice).
    """
    if float(np.mean(np.abs(to_gray(left) - to_gray(right)))) < SAME_IMAGE_DIFFERENCE:
        return (
            "the left and right views are the same image: there is no disparity to find; "
            "give the two views of the stereo pair"
        )
    forward = forward or quick_match(left, right)
    reverse = reverse or quick_match(right, left)
    given, other = 100 * forward.share, 100 * reverse.share
    if reverse.share >= SWAPPED_RATIO * forward.share:
        return (
            f"the views look swapped: {other:.0f} % of the pixels match consistently with "
            f"the right view taken as the left one, {given:.0f} % as given; pass the left "
            "view first (the one whose objects appear further right)"
        )
    if forward.share < RECTIFIED_RATIO * reverse.share:
        return (
            f"the views do not look rectified: only {given:.0f} % of the pixels match "
            f"consistently along the image rows ({other:.0f} % with the views swapped, which "
            "is chance), so corresponding points are not on the same row, or there is too "
            "little texture; rectify the pair first (e.g. OpenCV's stereoRectify)"
        )
    return ""


def estimate_max_disparity(
    left: np.ndarray, right: np.ndarray, match: QuickMatch | None = None
) -> RangeEstimate:
    """The maximum disparity of a rectified pair, estimated without any ground truth.

    Parameters
    ----------
    left, right : numpy.ndarray
        The rectified views, gray or BGR, float in [0, 1].
    match : QuickMatch, optional
        :func:`quick_match` of the pair when already at hand.

    Returns
    -------
    RangeEstimate
        Source ``"auto"``, or ``"auto-fallback"`` (a quarter of the width, with a note saying why)
        when too few pixels matched reliably.
    """
    width = left.shape[1]
    ceiling = max(1, min(LIMIT, width - 1))
    match = match or quick_match(left, right)
    share = match.share
    if share < MIN_CONFIRMED:
        guess = max(1, min(ceiling, math.ceil(FALLBACK_WIDTH_SHARE * width)))
        return RangeEstimate(
            guess,
            "auto-fallback",
            share,
            f"only {100 * share:.1f} % of the pixels matched reliably; assumed a quarter of "
            "the width. Give --max-disparity if you know the range",
        )
    high = float(np.percentile(match.values(), PERCENTILE))
    value = math.ceil(RELATIVE_MARGIN * high + ABSOLUTE_MARGIN)
    return RangeEstimate(max(1, min(ceiling, value)), "auto", share)


def resolve_max_disparity(
    left: np.ndarray, right: np.ndarray, max_disparity: int | str, *, warn: bool = True
) -> RangeEstimate:
    """The run's maximum disparity: the given one, or the estimate when it is ``auto``; with
    the check of the views either way (:func:`views_warning`, also issued as a
    :class:`ViewsWarning` when ``warn``: the service hands it to the job's submitter instead,
    and a process-wide warnings filter would silence the CLI's in the same process).

    Parameters
    ----------
    left, right : numpy.ndarray
        A rectified pair (h, w) or (h, w, 3) in [0, 1].
    max_disparity : int or str
        Full-resolution px, or ``"auto"``.

    Returns
    -------
    RangeEstimate
        Source ``"given"`` for an int, else :func:`estimate_max_disparity`'s; its ``warning``
        from :func:`views_warning`.
    """
    # the views' two directions side by side (OpenCV and NumPy release the GIL): the check is
    # on the path to the first level on small pairs (Tsukuba: 56 ms of CPU in one thread)
    reverse = beside(quick_match, right, left)
    match = quick_match(left, right)
    if isinstance(max_disparity, int):
        estimate = RangeEstimate(max_disparity, "given", match.share)
    else:
        estimate = estimate_max_disparity(left, right, match)
    warning = views_warning(left, right, match, reverse())
    if not warning:
        return estimate
    if warn:
        warnings.warn(warning, ViewsWarning, stacklevel=2)
    return replace(estimate, warning=warning)
