"""Scene discovery: stereo scenes with ground truth found on disk, with their evaluation protocol.

A ``Scene`` knows its files and its evaluation protocol (ground-truth scale, ignored border,
masks, the disparity search range). ``find_scenes`` accepts the ``left/right/gt_left`` layout of
``../shared/data/middlebury`` as well as the layouts Middlebury distributes (2001:
``im2.ppm/im6.ppm/disp2.pgm``, Tsukuba's ``scene1.row3.col3.ppm``; 2003 quarter size:
``im2.png/im6.png/disp2.png``).

The protocol of a scene is resolved, first match wins, from: explicit overrides (CLI flags), a
``protocol.json`` in the scene folder (``{"scale": 8, "border": 10, "max_disparity": 20}``, any
subset), ``KNOWN_PROTOCOLS`` by scene name (PROVENANCE.md), and finally the default of the
detected layout.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from shared.images import ImageError, load_disparity_values, load_mask, load_pair

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

#: Candidate file names per role, in order of preference.
LAYOUTS = {
    "left": ["left.png", "left.ppm", "im2.ppm", "im2.png", "scene1.row3.col3.ppm", "im0.png"],
    "right": ["right.png", "right.ppm", "im6.ppm", "im6.png", "scene1.row3.col4.ppm", "im1.png"],
    "gt": ["gt_left.png", "gt_left.pgm", "disp2.pgm", "disp2.png", "truedisp.row3.col3.pgm"],
}
#: Mask files per mask name: ours first, then the v2 evaluation's original names.
MASK_FILES = {
    "all": ["mask_all.png", "all.png"],
    "nonocc": ["mask_nonocc.png", "nonocc.png"],
    "disc": ["mask_disc.png", "disc.png"],
}
MASKS = {key: files[0] for key, files in MASK_FILES.items()}
PROTOCOL_FILE = "protocol.json"
#: Value of the pixels near depth discontinuities in the v2 ``disc`` masks.
DISC_VALUE = 255


@dataclass(frozen=True)
class Layout:
    """A way scenes are laid out on disk, recognised by its left-view file name."""

    name: str
    left: str
    right: str
    scale: float  # default ground-truth scale when the scene's name is not known
    border: int


#: Recognised layouts, keyed by the left view's file name.
LAYOUT_BY_LEFT: dict[str, Layout] = {
    layout.left: layout
    for layout in [
        Layout("shared", "left.png", "right.png", 1.0, 0),
        Layout("shared", "left.ppm", "right.ppm", 1.0, 0),
        Layout("middlebury2001", "im2.ppm", "im6.ppm", 8.0, 10),
        Layout("middlebury2001-tsukuba", "scene1.row3.col3.ppm", "scene1.row3.col4.ppm", 16.0, 18),
        Layout("middlebury2003", "im2.png", "im6.png", 4.0, 0),
        Layout("middlebury2014", "im0.png", "im1.png", 1.0, 0),
    ]
}


@dataclass
class Scene:
    """A stereo pair on disk with its ground truth, masks and evaluation protocol."""

    name: str
    left: Path
    right: Path
    #: The ground-truth disparity file (values are disparities times ``scale``), if any.
    gt: Path | None = None
    #: Ground-truth scale: stored value / disparity in pixels.
    scale: float = 1.0
    #: Pixels ignored along every image edge when scoring.
    border: int = 0
    #: The v2 evaluation masks found, by name (``all``, ``nonocc``, ``disc``).
    masks: dict[str, Path] = field(default_factory=dict)
    max_disparity: int = DEFAULT_MAX_DISPARITY
    #: The :class:`Layout` name the files were recognised by.
    layout: str = "shared"

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

    def mask(self, name: str) -> np.ndarray | None:
        """Pixels of a v2 evaluation mask.

        ``disc`` holds 255 near discontinuities and 128 elsewhere in nonocc, so only its 255
        pixels count; the other masks are their non-zero pixels.

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
        if name == "disc":
            raw = cv2.imread(str(self.masks[name]), cv2.IMREAD_GRAYSCALE)
            if raw is None:
                raise ImageError(f"{self.masks[name]}: not a readable mask image")
            return raw == DISC_VALUE
        return load_mask(self.masks[name])

    def protocol(self) -> dict:
        """The evaluation protocol as plain data.

        Returns
        -------
        dict
            ``layout``, ``scale``, ``border``, ``max_disparity`` and the ``masks`` found (for
            results files and ``qhsm datasets list``).
        """
        fields = ("layout", "scale", "border", "max_disparity")
        return {**{key: getattr(self, key) for key in fields}, "masks": sorted(self.masks)}


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


def _protocol_file(folder: Path) -> dict:
    path = folder / PROTOCOL_FILE
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise ValueError(f"{path}: not valid JSON ({error})") from None
    unknown = set(data) - {"scale", "border", "max_disparity"}
    if not isinstance(data, dict) or unknown:
        raise ValueError(f"{path}: expected keys scale, border, max_disparity; got {sorted(data)}")
    return data


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
        The scene's folder.
    name
        The scene's name (default: the folder's, lower case); known names have known protocols.
    scale, border, max_disparity
        Overrides of the protocol (None: ``protocol.json``, the known scene, the layout).

    Returns
    -------
    Scene
        Its files and protocol; ``FileNotFoundError`` where the folder holds no stereo pair.
    """
    folder = Path(folder)
    name = name or folder.name.lower()
    left, right = _first(folder, LAYOUTS["left"]), _first(folder, LAYOUTS["right"])
    if left is None or right is None:
        raise FileNotFoundError(
            f"{folder}: no stereo pair found (looked for {LAYOUTS['left']} and {LAYOUTS['right']})"
        )
    layout = LAYOUT_BY_LEFT[left.name]
    from_file = _protocol_file(folder)
    known_scale, known_border = KNOWN_PROTOCOLS.get(name, (layout.scale, layout.border))
    masks = {}
    for key, files in MASK_FILES.items():
        found = _first(folder, files)
        if found is not None:
            masks[key] = found
    return Scene(
        name=name,
        left=left,
        right=right,
        gt=_first(folder, LAYOUTS["gt"]),
        scale=float(scale if scale is not None else from_file.get("scale", known_scale)),
        border=int(border if border is not None else from_file.get("border", known_border)),
        masks=masks,
        max_disparity=int(
            max_disparity
            if max_disparity is not None
            else from_file.get(
                "max_disparity", KNOWN_MAX_DISPARITY.get(name, DEFAULT_MAX_DISPARITY)
            )
        ),
        layout=layout.name,
    )


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
    if _first(root, LAYOUTS["left"]) is not None:
        scene = load_scene(root, **overrides)
        return {scene.name: scene}
    scenes = {}
    for folder in sorted(p for p in root.iterdir() if p.is_dir()):
        try:
            scenes[folder.name.lower()] = load_scene(folder, **overrides)
        except FileNotFoundError:
            continue
    return scenes
