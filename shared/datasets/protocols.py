"""Evaluation protocols: the ground-truth scale, ignored border, masks and disparity range of
the datasets and scenes we know, the layouts scenes come in, and a protocol's resolution.

The protocol of a scene is resolved, first match wins, from: explicit overrides (CLI flags), a
``protocol.json`` in the scene folder (``{"scale": 8, "border": 10, "max_disparity": 20}``, any
subset), a ``protocol.json`` in its dataset folder (the scene folder's parent), then for the
ground-truth scale a PFM ground truth (real disparities: 1) and the convention of a known dataset
folder (``KNOWN_DATASETS``: Middlebury 2005/2006 store full-size disparities at every size, KITTI
disparity x 256), then ``KNOWN_PROTOCOLS`` by scene name (PROVENANCE.md), and finally the default
of the detected layout (Middlebury's 2005/2006 file names: the 2005/2006 convention).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import imagesize

from shared.images import ImageError

#: Protocol per known scene: (ground-truth scale, ignored border), from PROVENANCE.md.
KNOWN_PROTOCOLS: dict[str, tuple[float, int]] = {
    "tsukuba": (16.0, 18),
    "venus": (8.0, 10),
    "sawtooth": (8.0, 10),
    "bull": (8.0, 10),
    "map": (8.0, 10),
    "cones": (4.0, 0),
    "teddy": (4.0, 0),
}

#: Largest disparity searched per known scene (full-resolution px): the paper's 20 for the 2001
#: scenes, Middlebury's published search range (60) for the 2003 quarter-size scenes.
KNOWN_MAX_DISPARITY: dict[str, int] = {
    "tsukuba": 20,
    "venus": 20,
    "sawtooth": 20,
    "bull": 20,
    "cones": 60,
    "teddy": 60,
}
DEFAULT_MAX_DISPARITY = 20

#: Candidate file names per role, in order of preference: ours (``../shared/data``), then
#: Middlebury's own (2001, Tsukuba, 2003, 2005/2006 ``view1/view5/disp1/disp5``, MiddEval3).
LAYOUTS = {
    "left": [
        "left.png",
        "left.ppm",
        "im2.ppm",
        "im2.png",
        "scene1.row3.col3.ppm",
        "view1.png",
        "im0.png",
    ],
    "right": [
        "right.png",
        "right.ppm",
        "im6.ppm",
        "im6.png",
        "scene1.row3.col4.ppm",
        "view5.png",
        "im1.png",
    ],
    "gt": [
        "gt_left.png",
        "gt_left.pgm",
        "gt_left.pfm",
        "disp2.pgm",
        "disp2.png",
        "truedisp.row3.col3.pgm",
        "disp1.png",
        "disp0GT.pfm",
    ],
    "gt_right": [
        "gt_right.png",
        "gt_right.pgm",
        "gt_right.pfm",
        "disp6.pgm",
        "disp6.png",
        "disp5.png",
        "disp1GT.pfm",
    ],
}
#: Mask files per mask name: ours first, then the v2 evaluation's original names, then
#: MiddEval3's (``mask0nocc.png``, ours ``mask_left_nocc.png``: 255 non-occluded, 128 occluded).
MASK_FILES = {
    "all": ["mask_all.png", "all.png"],
    "nonocc": ["mask_nonocc.png", "nonocc.png", "mask_left_nocc.png", "mask0nocc.png"],
    "disc": ["mask_disc.png", "disc.png"],
}
MASKS = {key: files[0] for key, files in MASK_FILES.items()}
PROTOCOL_FILE = "protocol.json"
PROTOCOL_KEYS = ("scale", "border", "max_disparity")
#: The value a mask pixel needs to count, per mask (``all``: any non-zero value). The v2 ``disc``
#: masks hold 255 near discontinuities and 128 elsewhere in nonocc; MiddEval3's nocc masks 255
#: where non-occluded and 128 where occluded.
MASK_VALUE = {"nonocc": 255, "disc": 255}
#: Largest difference (px) between a pixel's ground truth and the right view's ground truth at
#: its match for the pixel to count as non-occluded, where the dataset has no nonocc mask.
GT_CONSISTENCY_TOLERANCE = 1.0


@dataclass(frozen=True)
class DatasetConvention:
    """How a known dataset folder stores its ground truth."""

    #: Stored value per pixel of disparity.
    scale: float = 1.0
    #: Where set, the ground truth holds disparities of the full-size images, which are this many
    #: pixels high (Middlebury 2005/2006): a reduced size divides by its reduction factor.
    full_size_height: int | None = None

    def scale_for(self, height: int) -> float:
        """The ground-truth scale of a scene whose images are ``height`` pixels high.

        Parameters
        ----------
        height
            The scene's image height, pixels.

        Returns
        -------
        float
            ``scale``, or the reduction factor full size / ``height`` (rounded: 3 for third
            size, 2 for half size, 1 for full size).
        """
        if self.full_size_height is None:
            return self.scale
        return float(max(1, round(self.full_size_height / height)))


#: Ground-truth conventions by dataset folder name (the scene folder's parent, lower case), from
#: ``../shared/data/PROVENANCE-2005-2006.md``: Middlebury 2005/2006 8-bit PNGs hold the full-size
#: disparity (images 1110 px high) at every size; KITTI 16-bit PNGs hold disparity x 256.
MIDDLEBURY_2005_2006 = DatasetConvention(full_size_height=1110)
KNOWN_DATASETS: dict[str, DatasetConvention] = {
    "middlebury2005": MIDDLEBURY_2005_2006,
    "middlebury2006": MIDDLEBURY_2005_2006,
    "kitti2012": DatasetConvention(scale=256.0),
    "kitti2015": DatasetConvention(scale=256.0),
}


@dataclass(frozen=True)
class Layout:
    """A way scenes are laid out on disk, recognised by its left-view file name."""

    name: str
    left: str
    right: str
    #: How its ground truth is stored where the scene's name is not known.
    ground_truth: DatasetConvention
    border: int

    @property
    def scale(self) -> float:
        """The default ground-truth scale (1 where it depends on the image size)."""
        return self.ground_truth.scale


#: Recognised layouts, keyed by the left view's file name.
LAYOUT_BY_LEFT: dict[str, Layout] = {
    layout.left: layout
    for layout in [
        Layout("shared", "left.png", "right.png", DatasetConvention(1.0), 0),
        Layout("shared", "left.ppm", "right.ppm", DatasetConvention(1.0), 0),
        Layout("middlebury2001", "im2.ppm", "im6.ppm", DatasetConvention(8.0), 10),
        Layout(
            "middlebury2001-tsukuba",
            "scene1.row3.col3.ppm",
            "scene1.row3.col4.ppm",
            DatasetConvention(16.0),
            18,
        ),
        Layout("middlebury2003", "im2.png", "im6.png", DatasetConvention(4.0), 0),
        Layout("middlebury2005-2006", "view1.png", "view5.png", MIDDLEBURY_2005_2006, 0),
        Layout("middlebury2014", "im0.png", "im1.png", DatasetConvention(1.0), 0),
    ]
}


def protocol_file(folder: Path) -> dict[str, Any]:
    """The ``protocol.json`` of a scene or dataset folder ({} without one), refused with a
    message when it is not a JSON object of :data:`PROTOCOL_KEYS`."""
    path = folder / PROTOCOL_FILE
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise ValueError(f"{path}: not valid JSON ({error})") from None
    if not isinstance(data, dict) or set(data) - set(PROTOCOL_KEYS):
        got = sorted(data) if isinstance(data, dict) else type(data).__name__
        raise ValueError(f"{path}: expected keys {', '.join(PROTOCOL_KEYS)}; got {got}")
    return data


def first_given(*values: Any) -> Any:
    """The first value that is not None (None if all are)."""
    return next((value for value in values if value is not None), None)


def _scale_of(convention: DatasetConvention, left: Path) -> float:
    """The convention's scale for the scene whose left view is ``left``."""
    if convention.full_size_height is None:
        return convention.scale
    _, height = imagesize.get(str(left))  # the header only
    if height <= 0:
        raise ImageError(f"{left}: cannot read the image size")
    return convention.scale_for(height)


def default_scale(name: str, dataset: str, layout: Layout, left: Path, gt: Path | None) -> float:
    """The ground-truth scale no protocol file states: the file type, the known dataset, the
    known scene, the layout (see the module doc)."""
    if gt is not None and gt.suffix.lower() == ".pfm":
        return 1.0  # PFM holds real disparities
    if dataset in KNOWN_DATASETS:
        return _scale_of(KNOWN_DATASETS[dataset], left)
    if name in KNOWN_PROTOCOLS:
        return KNOWN_PROTOCOLS[name][0]
    return _scale_of(layout.ground_truth, left)
