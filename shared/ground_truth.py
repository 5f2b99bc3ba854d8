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

import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from shared.disparity_range import QuickMatch, quick_match
from shared.images import is_pfm, load_disparity, load_disparity_values
from shared.metrics import BAD_PIXEL_THRESHOLD, Scores, evaluate_regions

if TYPE_CHECKING:
    from shared.datasets.scenes import Scene

#: The scales ground-truth formats use (stored value per pixel of disparity).
CONVENTIONAL_SCALES = (1, 2, 3, 4, 5, 6, 8, 10, 16, 32, 64, 100, 128, 256, 512, 1000, 1024)
#: The measured ratio must be within this relative distance of a conventional scale.
TOLERANCE = 0.1
#: Matched disparities below this many shrunk pixels are too coarse to divide by.
MIN_DISPARITY = 2
#: Largest relative difference between a given and an inferred scale that is not warned about.
SCALE_AGREEMENT = 1e-3
#: A PNG's bit depth is this byte of the file (in its IHDR chunk).
PNG_BIT_DEPTH_OFFSET = 24
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


class ScaleWarning(UserWarning):
    """A given ground-truth scale that the file's format or dataset contradicts (the CLI shows
    it as one ``qhsm: warning:`` line)."""


@dataclass(frozen=True)
class FormatScale:
    """A ground-truth scale that the file's format or its dataset's convention states."""

    scale: float
    source: str  # why: the format or the convention

    def disagreement(self, given: float) -> str:
        """The warning when ``given`` is not this scale ("" when they agree)."""
        if abs(given / self.scale - 1) <= SCALE_AGREEMENT:
            return ""
        factor = max(given, self.scale) / min(given, self.scale)
        return (
            f"ground-truth scale {given:g} given, but {self.source} says {self.scale:g}: the "
            f"scores use {given:g} (wrong by {factor:.3g}x if the file is what it says)"
        )


def scale_of_format(data: bytes) -> FormatScale | None:
    """The scale a ground-truth file's format implies: PFM holds disparities (1), a 16-bit PNG
    KITTI's disparity x 256; None for 8-bit images, whose scale is the dataset's, and for
    .npy, which follows no convention (arrays of scaled values are common)."""
    if is_pfm(data):
        return FormatScale(1.0, "PFM (disparities in pixels; its header scale is the byte order)")
    depth = data[PNG_BIT_DEPTH_OFFSET : PNG_BIT_DEPTH_OFFSET + 1]
    if data.startswith(b"\x89PNG") and depth == b"\x10":
        return FormatScale(256.0, "a 16-bit PNG (KITTI's convention, disparity x 256)")
    return None


def scene_of_ground_truth(path: str | Path) -> Scene | None:
    """The scene whose ground truth is the file ``path`` when its folder is one that
    :mod:`shared.datasets` recognises and states the scale of (protocol.json, a known dataset or
    scene, a Middlebury layout; our own left/right/gt_left layout alone states nothing)."""
    from shared.datasets.protocols import KNOWN_DATASETS, KNOWN_PROTOCOLS, protocol_file
    from shared.datasets.scenes import load_scene

    path = Path(path)
    try:
        scene = load_scene(path.parent)
        stated = any(protocol_file(f).get("scale") for f in (path.parent, path.parent.parent))
    except (FileNotFoundError, ValueError):
        return None
    if scene.gt is None or scene.gt.resolve() != path.resolve():
        return None
    known = stated or scene.name in KNOWN_PROTOCOLS or scene.dataset in KNOWN_DATASETS
    return scene if known or scene.layout != "shared" else None


def scale_of_file(path: str | Path) -> FormatScale | None:
    """The scale of the ground-truth file ``path``: its scene's protocol when it is the
    ground truth of a scene folder (:func:`scene_of_ground_truth`: Middlebury 2001-2006's 8-bit
    conventions, protocol.json), else its format's (:func:`scale_of_format`); None when
    neither tells."""
    scene = scene_of_ground_truth(path)
    if scene is not None:
        source = f"the {scene.qualified_name} scene's protocol ({scene.layout})"
        return FormatScale(scene.scale, source)
    with Path(path).open("rb") as stream:
        return scale_of_format(stream.read(64))


def resolve_gt_scale(path: str | Path, given: float | None = None) -> tuple[float, str]:
    """The scale to score against the ground-truth file ``path``, and where it comes from.

    ``given`` wins, with a :class:`ScaleWarning` when the file's format or its scene's protocol
    (:func:`scale_of_file`) says otherwise; not given, the scale is that one, and a
    :class:`ScaleNotInferredError` when nothing tells (an 8-bit image outside known scenes).
    """
    stated = scale_of_file(path)
    if given is not None:
        warning = stated.disagreement(given) if stated else ""
        if warning:
            warnings.warn(f"{path}: {warning}", ScaleWarning, stacklevel=2)
        return float(given), "given"
    if stated is None:
        raise ScaleNotInferredError(
            f"{path}: neither its format nor a known scene folder tells its scale; give it "
            "(stored value per pixel of disparity: Tsukuba 16, Venus 8, Cones 4, KITTI 256)"
        )
    return stated.scale, f"inferred from {stated.source}"


@dataclass(frozen=True)
class Evaluation:
    """Scores of a map against a ground truth, with the protocol they were computed under."""

    scores: dict[str, Scores]  # "all" and each region (nonocc, bg, fg) that has pixels
    scale: float
    scale_source: str
    border: int
    gt_values: np.ndarray  # the ground truth as stored
    warnings: list[str]  # a given scale that the file's format or scene contradicts

    def report(self) -> dict[str, Any]:
        """JSON-friendly: the all-pixel scores at the top level, ``scale``, ``scale_source``,
        ``border`` and ``regions`` (``qhsm eval --json``, :func:`qhsm.evaluate`)."""
        return {
            **self.scores["all"].as_dict(),
            "scale": self.scale,
            "scale_source": self.scale_source,
            "border": self.border,
            "regions": {k: v.as_dict() for k, v in self.scores.items() if k != "all"},
            "warnings": self.warnings,
        }


def evaluate_ground_truth(
    disparity: str | Path | np.ndarray,
    ground_truth: str | Path | np.ndarray,
    *,
    scale: float | None = None,
    border: int | None = None,
    mask: np.ndarray | None = None,
    nonocc: np.ndarray | None = None,
    foreground: np.ndarray | None = None,
    threshold: float = BAD_PIXEL_THRESHOLD,
) -> Evaluation:
    """Score ``disparity`` (a map or its file) against a ground-truth file (its scale from
    :func:`resolve_gt_scale`, its border and non-occluded pixels from its scene when recognised)
    or array (disparities times ``scale``, 1 by default): every pixel within ``mask``,
    ``nonocc`` and, with KITTI's object map as ``foreground``, ``bg`` / ``fg``."""
    if not isinstance(disparity, np.ndarray):
        disparity = load_disparity(disparity)
    scene = None
    notes: list[str] = []
    if isinstance(ground_truth, np.ndarray):
        values = np.asarray(ground_truth, np.float32)
        scale, source = (1.0, "default for an array") if scale is None else (scale, "given")
    else:
        values = load_disparity_values(ground_truth)
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always", ScaleWarning)
            scale, source = resolve_gt_scale(ground_truth, scale)
        for warning in seen:  # shown as usual, and kept in the report
            warnings.warn(warning.message, warning.category, stacklevel=2)
            notes.append(str(warning.message))
        scene = scene_of_ground_truth(ground_truth)
    border = border if border is not None else (scene.border if scene else 0)
    regions: dict[str, np.ndarray | None] = {}
    if nonocc is not None:
        regions["nonocc"] = nonocc
    elif scene is not None:
        regions["nonocc"] = scene.non_occluded(values)
    if foreground is not None:
        regions["bg"], regions["fg"] = ~foreground.astype(bool), foreground.astype(bool)
    scores = evaluate_regions(disparity, values, regions, scale, border, threshold, mask)
    return Evaluation(scores, float(scale), source, int(border), values, notes)


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
