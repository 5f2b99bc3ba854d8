"""The scale of a ground truth that came without one, inferred from the views.

Ground-truth files store disparity x a scale (Tsukuba 16, Venus 8, Cones 4, Middlebury 2005
third size 3, 2006 half size 2, KITTI 256, PFM 1). Assuming 1 when none is given turns a good
result into an RMSE of 100 px, so the scale is measured instead: at the pixels whose quick dense
match (:mod:`shared.disparity_range`) is confirmed, the stored value divided by the matched
disparity is the scale, up to matching noise; the median over thousands of pixels is within 2 %
of the true scale on the 20 Middlebury scenes (``benchmarks/view_checks.py``). It is snapped to
the nearest conventional scale when within :data:`TOLERANCE`, else refused: a scale that is
wrong by a little would still give plausible-looking but wrong scores.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from shared.disparity_range import QuickMatch, quick_match

#: The scales ground-truth formats use (stored value per pixel of disparity).
CONVENTIONAL_SCALES = (1, 2, 3, 4, 5, 6, 8, 10, 16, 32, 64, 100, 128, 256, 512, 1000, 1024)
#: The measured ratio must be within this relative distance of a conventional scale.
TOLERANCE = 0.1
#: Matched disparities below this many shrunk pixels are too coarse to divide by.
MIN_DISPARITY = 2
#: Pixels needed (confirmed match, known ground truth) to trust the median.
MIN_PIXELS = 200
#: Largest interquartile range of the ratios, relative to their median.
MAX_SPREAD = 0.5


class ScaleNotInferredError(ValueError):
    """The views and the ground truth do not tell the scale; the message says why and asks
    for it."""


@dataclass(frozen=True)
class ScaleEstimate:
    """An inferred ground-truth scale and the evidence for it."""

    scale: float
    ratio: float  # the measured median of stored value / matched disparity
    pixels: int  # how many pixels it is the median of

    @property
    def note(self) -> str:
        """What the user is told: the scale was not given, what was assumed and why."""
        return (
            f"ground-truth scale not given: inferred {self.scale:g} (its values are "
            f"{self.ratio:.2f} x the disparities the views show, median of {self.pixels} "
            "pixels); give the scale if that is wrong"
        )


def infer_gt_scale(
    left: np.ndarray, right: np.ndarray, ground_truth: np.ndarray, match: QuickMatch | None = None
) -> ScaleEstimate:
    """The stored value per pixel of disparity of ``ground_truth`` (0 = unknown), measured
    against the quick dense match of the views.

    Parameters
    ----------
    left, right : numpy.ndarray
        The rectified views (h, w) or (h, w, 3) in [0, 1].
    ground_truth : numpy.ndarray
        The left view's stored ground-truth values (h, w); 0 or not finite = unknown.
    match : QuickMatch, optional
        :func:`shared.disparity_range.quick_match` of the views when already at hand.

    Returns
    -------
    ScaleEstimate

    Raises
    ------
    ScaleNotInferredError
        Too few pixels to compare, ratios too spread, or a ratio near no conventional scale.
    """
    match = match or quick_match(left, right)
    rows, columns = match.disparity.shape
    values = np.nan_to_num(np.asarray(ground_truth, dtype=np.float32), nan=0.0, posinf=0.0)
    shrunk = cv2.resize(values, (columns, rows), interpolation=cv2.INTER_NEAREST)
    usable = match.confirmed & (shrunk > 0) & (match.disparity >= MIN_DISPARITY * match.factor)
    ask = "give the ground truth's scale (stored value per pixel of disparity)"
    if int(usable.sum()) < MIN_PIXELS:
        raise ScaleNotInferredError(
            f"cannot infer the ground-truth scale: only {int(usable.sum())} pixels both match "
            f"reliably and have a ground truth; {ask}"
        )
    ratios = shrunk[usable] / match.disparity[usable]
    low, median, high = (float(q) for q in np.percentile(ratios, [25, 50, 75]))
    if median <= 0 or (high - low) / median > MAX_SPREAD:
        raise ScaleNotInferredError(
            f"cannot infer the ground-truth scale: its values do not follow the disparities "
            f"the views show (ratios {low:.2f} to {high:.2f}); is it this pair's left ground "
            f"truth? {ask}"
        )
    nearest = min(CONVENTIONAL_SCALES, key=lambda scale: abs(np.log(median / scale)))
    if abs(median / nearest - 1) > TOLERANCE:
        raise ScaleNotInferredError(
            f"cannot infer the ground-truth scale: its values are {median:.2f} x the "
            f"disparities the views show, which is no usual scale; {ask}"
        )
    return ScaleEstimate(float(nearest), median, int(usable.sum()))
