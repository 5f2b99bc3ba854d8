"""Scene discovery: stereo scenes with ground truth found on disk, with their evaluation protocol.

A ``Scene`` knows its files and its evaluation protocol (ground-truth scale, ignored border,
masks, the disparity search range, which pixels are non-occluded). ``find_scenes`` accepts the
``left/right/gt_left[/gt_right]`` layout of ``../shared/data/*`` as well as the layouts Middlebury
distributes (2001: ``im2.ppm/im6.ppm/disp2.pgm``, Tsukuba's ``scene1.row3.col3.ppm``; 2003
quarter size: ``im2.png/im6.png/disp2.png``; 2005/2006: ``view1.png/view5.png/disp1.png``;
MiddEval3: ``im0.png/im1.png/disp0GT.pfm``); ``find_datasets`` finds the dataset folders (one
folder of scenes each: ``middlebury2005/``, ``middlebury2006/``, ...) below a folder.

The protocol of a scene is resolved as :mod:`shared.datasets.protocols` says, first match wins,
from explicit overrides down to the layout's default.

Non-occluded pixels (the main figure of ``benchmarks/generalisation.py``) are the dataset's
``nonocc`` mask where the scene has one; else the pixels whose ground truth is confirmed by the
right view's ground truth within 1 px (a left-right check of the ground truth itself); else,
without a right-view ground truth, every pixel with known ground truth.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from shared.datasets.calibration import CalibrationError, read_calibration, scene_calibration
from shared.datasets.protocols import (
    DEFAULT_MAX_DISPARITY,
    GT_CONSISTENCY_TOLERANCE,
    KNOWN_MAX_DISPARITY,
    KNOWN_PROTOCOLS,
    LAYOUT_BY_LEFT,
    LAYOUTS,
    MASK_FILES,
    MASK_VALUE,
    default_scale,
    first_given,
    protocol_file,
)
from shared.filters import left_right_check
from shared.images import ImageError, load_disparity_values, load_pair

#: The range source of a scene whose range nothing states but its ground truth.
GROUND_TRUTH_RANGE = "the ground truth's maximum"
#: ... and of one with neither.
DEFAULT_RANGE = (
    f"default: {DEFAULT_MAX_DISPARITY} px assumed (no protocol.json, calib.txt or ground truth; "
    "give the range, or estimate it with auto)"
)


@dataclass
class Scene:
    """A stereo pair on disk with its ground truth, masks and evaluation protocol."""

    name: str
    left: Path
    right: Path
    #: The ground-truth disparity file (values are disparities times ``scale``), if any.
    gt: Path | None = None
    #: The right view's ground truth (same scale), if any: non-occlusion where no mask says.
    gt_right: Path | None = None
    #: Ground-truth scale: stored value / disparity in pixels.
    scale: float = 1.0
    #: Pixels ignored along every image edge when scoring.
    border: int = 0
    #: The v2 evaluation masks found, by name (``all``, ``nonocc``, ``disc``).
    masks: dict[str, Path] = field(default_factory=dict)
    max_disparity: int = DEFAULT_MAX_DISPARITY
    #: Where ``max_disparity`` comes from (given, protocol.json, calib.txt, known scene, ground
    #: truth, or the stated default): never a silent guess.
    max_disparity_source: str = "default"
    #: The scene's calibration file (Middlebury calib.txt), if any.
    calibration: Path | None = None
    #: The :class:`Layout` name the files were recognised by.
    layout: str = "shared"
    #: The dataset folder the scene is in (its parent folder's name, lower case).
    dataset: str = ""

    @property
    def range_is_stated(self) -> bool:
        """Whether the range was stated (given, protocol.json, calib.txt, a known scene) rather
        than taken from the ground truth or the default: what a matcher may be told."""
        return self.max_disparity_source not in (GROUND_TRUTH_RANGE, DEFAULT_RANGE)

    @property
    def qualified_name(self) -> str:
        """``dataset/name``: unique across datasets (2003's Teddy and MiddEval3's are not one)."""
        return f"{self.dataset}/{self.name}" if self.dataset else self.name

    def load(self) -> tuple[np.ndarray, np.ndarray]:
        """Read the two views.

        Returns
        -------
        tuple of numpy.ndarray
            Left and right view as :func:`shared.images.load_pair` reads them.
        """
        return load_pair(self.left, self.right)

    def ground_truth(self) -> np.ndarray:
        """Read the ground truth (``FileNotFoundError`` where the scene has none).

        Returns
        -------
        numpy.ndarray
            The stored values: disparities in pixels times ``scale``, 0 where unknown.
        """
        if self.gt is None:
            raise FileNotFoundError(f"scene {self.name} has no ground truth")
        return load_disparity_values(self.gt)

    def ground_truth_range(self) -> int:
        """The largest ground-truth disparity, rounded up: the range "given" to a matcher.

        Returns
        -------
        int
            ceil of the ground truth's maximum, in pixels of the scene's images.
        """
        return math.ceil(float(self.ground_truth().max()) / self.scale)

    def mask(self, name: str) -> np.ndarray | None:
        """Pixels of an evaluation mask on disk (palette PNGs decoded through their palette).

        ``disc`` and ``nonocc`` count only their 255 pixels (``disc``: 128 is the rest of
        nonocc; MiddEval3's nocc: 128 is occluded); ``all`` its non-zero pixels.

        Parameters
        ----------
        name
            ``all``, ``nonocc`` or ``disc``.

        Returns
        -------
        numpy.ndarray or None
            A boolean mask, or None where the scene has no such mask.
        """
        if name not in self.masks:
            return None
        raw = cv2.imread(str(self.masks[name]), cv2.IMREAD_GRAYSCALE)
        if raw is None:
            raise ImageError(f"{self.masks[name]}: not a readable mask image")
        value = MASK_VALUE.get(name)
        return raw > 0 if value is None else raw == value

    @property
    def non_occlusion(self) -> str:
        """Where the scene's non-occluded pixels come from (see :meth:`non_occluded`).

        Returns
        -------
        str
            ``mask`` (a nonocc mask on disk), ``left-right`` (the ground truth's left-right
            check) or ``none`` (no way to tell: every pixel with known ground truth).
        """
        if "nonocc" in self.masks:
            return "mask"
        if self.gt is not None and self.gt_right is not None:
            return "left-right"
        return "none"

    def non_occluded(self, gt: np.ndarray | None = None) -> np.ndarray | None:
        """The non-occluded pixels: the nonocc mask, else the ground truth's left-right check.

        Without a mask, the left ground truth's pixels that the right view's ground truth
        confirms (:func:`confirmed_by_right_view`).

        Parameters
        ----------
        gt
            The left ground truth as stored, if already loaded.

        Returns
        -------
        numpy.ndarray or None
            (h, w) bool, or None where the scene can tell neither way (``non_occlusion ==
            "none"``).
        """
        source = self.non_occlusion
        if source == "mask":
            return self.mask("nonocc")
        if source == "none":
            return None
        assert self.gt_right is not None
        left = (self.ground_truth() if gt is None else gt) / self.scale
        right = load_disparity_values(self.gt_right) / self.scale
        if right.shape != left.shape:
            raise ValueError(
                f"{self.gt_right}: {right.shape[::-1]} (w x h), the left ground truth is "
                f"{left.shape[::-1]}"
            )
        return confirmed_by_right_view(left, right)

    def protocol(self) -> dict:
        """The evaluation protocol as plain data.

        Returns
        -------
        dict
            ``dataset``, ``layout``, ``scale``, ``border``, ``max_disparity``,
            ``non_occlusion`` and the ``masks`` found (for results files and ``qhsm datasets
            list``).
        """
        fields = (
            "dataset",
            "layout",
            "scale",
            "border",
            "max_disparity",
            "max_disparity_source",
            "non_occlusion",
        )
        return {**{key: getattr(self, key) for key in fields}, "masks": sorted(self.masks)}


def confirmed_by_right_view(
    left: np.ndarray, right: np.ndarray, tolerance: float = GT_CONSISTENCY_TOLERANCE
) -> np.ndarray:
    """Non-occluded pixels from the two views' ground truths: the GT's own left-right check.

    A left pixel with known disparity d is confirmed when the right view's ground truth at
    x - d (rounded) is known and within ``tolerance`` of d
    (:func:`shared.filters.left_right_check`); a pixel whose match falls outside the image or on
    another surface is occluded.

    Parameters
    ----------
    left, right
        Ground-truth disparities (h, w) of the left and the right view, pixels; 0 = unknown.
    tolerance
        Largest accepted difference, pixels.

    Returns
    -------
    numpy.ndarray
        (h, w) bool, False also where the left ground truth is unknown.
    """
    unknown_as_nan = np.where(right > 0, right, np.nan)  # NaN is never within the tolerance
    return (left > 0) & left_right_check(left, unknown_as_nan, tolerance)


def default_middlebury_dir() -> Path:
    """Where the Middlebury copies are.

    Returns
    -------
    Path
        ``QHSM_MIDDLEBURY_DIR`` if set, else ``../shared/data/middlebury`` beside the repository.
    """
    override = os.environ.get("QHSM_MIDDLEBURY_DIR")
    if override:
        return Path(override)
    return Path(__file__).resolve().parents[3] / "shared" / "data" / "middlebury"


def _first(folder: Path, names: list[str]) -> Path | None:
    return next((folder / n for n in names if (folder / n).is_file()), None)


def load_scene(
    folder: str | Path,
    name: str | None = None,
    *,
    scale: float | None = None,
    border: int | None = None,
    max_disparity: int | None = None,
) -> Scene:
    """Detect a scene's files in ``folder`` and resolve its protocol (see the module doc).

    Parameters
    ----------
    folder
        The scene's folder; its parent is the scene's dataset folder.
    name
        The scene's name (default: the folder's, lower case); known names have known protocols.
    scale, border, max_disparity
        Overrides of the protocol (None: the ``protocol.json`` files, the known dataset and
        scene, the layout).

    Returns
    -------
    Scene
        Its files and protocol; ``FileNotFoundError`` where the folder holds no stereo pair.
    """
    folder = Path(folder)
    name = name or folder.name.lower()
    dataset = folder.resolve().parent.name.lower()
    left, right = _first(folder, LAYOUTS["left"]), _first(folder, LAYOUTS["right"])
    if left is None or right is None:
        raise FileNotFoundError(
            f"{folder}: no stereo pair found (looked for {LAYOUTS['left']} and {LAYOUTS['right']})"
        )
    layout = LAYOUT_BY_LEFT[left.name]
    gt = _first(folder, LAYOUTS["gt"])
    own, shared = protocol_file(folder), protocol_file(folder.resolve().parent)
    known_border = KNOWN_PROTOCOLS[name][1] if name in KNOWN_PROTOCOLS else layout.border
    given: dict[str, Any] = {"scale": scale, "border": border, "max_disparity": max_disparity}
    protocol = {key: first_given(given[key], own.get(key), shared.get(key)) for key in given}
    masks = {}
    for key, files in MASK_FILES.items():
        found = _first(folder, files)
        if found is not None:
            masks[key] = found
    calibration = scene_calibration(folder)
    scene = Scene(
        name=name,
        left=left,
        right=right,
        gt=gt,
        gt_right=_first(folder, LAYOUTS["gt_right"]) if gt is not None else None,
        scale=float(
            protocol["scale"]
            if protocol["scale"] is not None
            else default_scale(name, dataset, layout, left, gt)
        ),
        border=int(first_given(protocol["border"], known_border)),
        masks=masks,
        calibration=calibration,
        layout=layout.name,
        dataset=dataset,
    )
    given_range = (
        (max_disparity, "given"),
        (own.get("max_disparity"), "the scene's protocol.json"),
        (shared.get("max_disparity"), "the dataset's protocol.json"),
        (_calibrated_range(calibration), f"{calibration} (ndisp)" if calibration else ""),
        (KNOWN_MAX_DISPARITY.get(name), "the known scene's search range"),
    )
    top, source = next(((v, s) for v, s in given_range if v is not None), (None, ""))
    if top is None and gt is not None:
        top, source = max(1, scene.ground_truth_range()), GROUND_TRUTH_RANGE
    if top is None:
        top, source = DEFAULT_MAX_DISPARITY, DEFAULT_RANGE
    scene.max_disparity, scene.max_disparity_source = int(top), source
    return scene


def _calibrated_range(calibration: Path | None) -> int | None:
    """Middlebury's ndisp of a calib.txt (None without one or when unreadable)."""
    if calibration is None:
        return None
    try:
        return read_calibration(calibration).ndisp
    except CalibrationError:
        return None


def _is_scene(folder: Path) -> bool:
    return _first(folder, LAYOUTS["left"]) is not None


def find_scenes(root: str | Path, **overrides) -> dict[str, Scene]:
    """Every scene folder directly below ``root`` (sorted by name); ``root`` itself if it is one.

    Parameters
    ----------
    root
        A dataset folder, or one scene's folder.
    **overrides
        ``scale``, ``border``, ``max_disparity``: passed to :func:`load_scene`.

    Returns
    -------
    dict
        Scene name (lower case) to :class:`Scene`; folders without a stereo pair are skipped.
    """
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: no such directory")
    if _is_scene(root):
        scene = load_scene(root, **overrides)
        return {scene.name: scene}
    scenes = {}
    for folder in sorted(p for p in root.iterdir() if p.is_dir()):
        try:
            scenes[folder.name.lower()] = load_scene(folder, **overrides)
        except FileNotFoundError:
            continue
    return scenes


def find_datasets(root: str | Path, **overrides) -> dict[str, dict[str, Scene]]:
    """The dataset folders at or below ``root`` and their scenes, by folder layout alone.

    ``root`` is a dataset when it is a scene folder or has scene folders directly below it;
    otherwise every sub-folder is searched the same way (``../shared/data`` gives
    ``middlebury``, ``middlebury2005`` and ``middlebury2006``).

    Parameters
    ----------
    root
        A folder of datasets, one dataset folder, or one scene's folder.
    **overrides
        ``scale``, ``border``, ``max_disparity``: passed to :func:`load_scene`.

    Returns
    -------
    dict
        Dataset folder name (lower case) to its scenes as :func:`find_scenes` returns them, sorted
        by the folders' paths; empty where no scene is found.
    """
    root = Path(root)
    scenes = find_scenes(root, **overrides)
    if scenes:
        dataset = next(iter(scenes.values())).dataset
        return {dataset: scenes}
    datasets: dict[str, dict[str, Scene]] = {}
    for folder in sorted(p for p in root.iterdir() if p.is_dir()):
        for name, found in find_datasets(folder, **overrides).items():
            if name in datasets:
                raise ValueError(f"two dataset folders are named {name!r} below {root}")
            datasets[name] = found
    return datasets
