"""Stereo scenes with ground truth: the Middlebury copies beside the repo and synthetic scenes.

A ``Scene`` knows its files and its evaluation protocol (ground-truth scale, ignored border,
masks, the disparity search range). ``find_scenes`` accepts the ``left/right/gt_left`` layout of
``../shared/data/middlebury`` as well as the layouts Middlebury distributes (2001:
``im2.ppm/im6.ppm/disp2.pgm``, Tsukuba's ``scene1.row3.col3.ppm``; 2003 quarter size:
``im2.png/im6.png/disp2.png``).

The protocol of a scene is resolved, first match wins, from: explicit overrides (CLI flags), a
``protocol.json`` in the scene folder (``{"scale": 8, "border": 10, "max_disparity": 20}``, any
subset), ``KNOWN_PROTOCOLS`` by scene name, and finally the default of the detected layout.

``fetch`` downloads a Middlebury set from its official file URLs (or any mirror with the same
relative paths, e.g. ``file:///srv/middlebury/``) and checks every file against the manifest's
sha256 where one is known; files without a known checksum are reported as *unverified*, never
silently trusted under an invented checksum.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from collections.abc import Callable
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
    name: str
    left: Path
    right: Path
    gt: Path | None
    scale: float = 1.0
    border: int = 0
    masks: dict[str, Path] = field(default_factory=dict)
    max_disparity: int = DEFAULT_MAX_DISPARITY
    layout: str = "shared"

    def load(self) -> tuple[np.ndarray, np.ndarray]:
        return load_pair(self.left, self.right)

    def ground_truth(self) -> np.ndarray:
        if self.gt is None:
            raise FileNotFoundError(f"scene {self.name} has no ground truth")
        return load_disparity_values(self.gt)

    def mask(self, name: str) -> np.ndarray | None:
        """Pixels of v2 mask ``name`` (bool). ``disc`` holds 255 near discontinuities and 128
        elsewhere in nonocc, so only its 255 pixels count; the other masks are non-zero ones."""
        if name not in self.masks:
            return None
        if name == "disc":
            raw = cv2.imread(str(self.masks[name]), cv2.IMREAD_GRAYSCALE)
            if raw is None:
                raise ImageError(f"{self.masks[name]}: not a readable mask image")
            return raw == DISC_VALUE
        return load_mask(self.masks[name])

    def protocol(self) -> dict:
        """The evaluation protocol as plain data (for results files)."""
        return {
            "layout": self.layout,
            "scale": self.scale,
            "border": self.border,
            "max_disparity": self.max_disparity,
            "masks": sorted(self.masks),
        }


def default_middlebury_dir() -> Path:
    """``../shared/data/middlebury`` beside the repository (override: QHSM_MIDDLEBURY_DIR)."""
    override = os.environ.get("QHSM_MIDDLEBURY_DIR")
    if override:
        return Path(override)
    return Path(__file__).resolve().parents[2] / "shared" / "data" / "middlebury"


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
    """Detect a scene's files in ``folder`` and resolve its protocol (see the module doc)."""
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

    ``overrides`` (scale, border, max_disparity) are passed to :func:`load_scene`.
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


# --- fetching -------------------------------------------------------------------------------


@dataclass(frozen=True)
class RemoteFile:
    """One file of a dataset: where it lives below the base URL and where it goes below DIR.

    ``sha256`` is ``None`` where no checksum is known; such files are reported as unverified.
    """

    source: str
    target: str
    sha256: str | None = None


@dataclass(frozen=True)
class Manifest:
    name: str
    base_url: str
    files: tuple[RemoteFile, ...]
    note: str = ""

    def scenes(self) -> list[str]:
        return sorted({f.target.split("/")[0] for f in self.files})


# Checksums below are the sha256 of the copies in ../shared/data/middlebury (PROVENANCE.md):
# byte copies of the distributed files (Venus: identical to the members of the official zip).
# Everything else is unknown here and stays None (reported as unverified) until someone records
# the sha256 of an official download (`qhsm datasets fetch` prints them).
_2001 = "stereo/data/scenes2001/data/"
_2003 = "stereo/data/scenes2003/newdata/"
_EVAL = "stereo/eval/newEval/"
_MASK_SHA256 = {
    "tsukuba": {
        "nonocc": "826a3b8521c9fdcb8f05401e4676262c68d85251adbae1507e2c984c19d5b211",
        "all": "17630759fd7f99aba9b8d17ec66973974b30a938c9c542ce8ec4f497e3ea64ca",
        "disc": "5cc99c325e09f24f5f812ccd8022ea25014a2f85a84731c899199e26d3c16cfc",
    },
    "venus": {
        "nonocc": "fb2db205bb6a83e00fd360a1b7580886d2c65b6c2f4a0f43b36dc710d2eb2db6",
        "all": "47415362ed6c2ca7bd61d52f7cc68e858098b581b591dc0cb0fc019e331a70ba",
        "disc": "b449e1cdc7ed573f1c98e4359102b97a51761da8d3bc675cad45b3969005990d",
    },
    "cones": {
        "nonocc": "0fd35104fcc1acb21840a5a87187d571584fff3bf0b01bb5a087bc4a1e324d0f",
        "all": "d9a367fe82b2da6d1c91a8287804bace86b878bcac8bafcc43d011d11268be37",
        "disc": "b512f4ee425202a501dea3ca4aa666a33c541484d334659e705de9132bcc8008",
    },
}


def _masks(scene: str) -> list[RemoteFile]:
    known = _MASK_SHA256.get(scene, {})
    return [
        RemoteFile(f"{_EVAL}{scene}/{mask}.png", f"{scene}/{mask}.png", known.get(mask))
        for mask in ("nonocc", "all", "disc")
    ]


MANIFESTS: dict[str, Manifest] = {
    "middlebury2001": Manifest(
        name="middlebury2001",
        base_url="https://vision.middlebury.edu/",
        note="Scharstein & Szeliski 2001 scenes with the v2 evaluation masks (Tsukuba, Venus)",
        files=(
            RemoteFile(
                f"{_2001}tsukuba/scene1.row3.col3.ppm",
                "tsukuba/scene1.row3.col3.ppm",
                "1d326401c70e4bce95f0415a612dd00fa2984db89754f28d490b816aa731361a",
            ),
            RemoteFile(
                f"{_2001}tsukuba/scene1.row3.col4.ppm",
                "tsukuba/scene1.row3.col4.ppm",
                "c8048c2e0d834488adfae1c2525f4c004907b369dc90730ca11bf1f6dd8d925d",
            ),
            RemoteFile(
                f"{_2001}tsukuba/truedisp.row3.col3.pgm",
                "tsukuba/truedisp.row3.col3.pgm",
                "3192e1b8a1ad50fa6ac743cbe93aea54066bc93d2ebee432a04e7cd759450296",
            ),
            *_masks("tsukuba"),
            RemoteFile(
                f"{_2001}venus/im2.ppm",
                "venus/im2.ppm",
                "fef870c1e2471fe5b3b2bac9ca71810e8503e1489e4203288a982b40355b9172",
            ),
            RemoteFile(
                f"{_2001}venus/im6.ppm",
                "venus/im6.ppm",
                "b2fca7b6f3aa7e1a34bc5eac2d99cbbc5dfc77ce531777b71153e2ed73290004",
            ),
            RemoteFile(
                f"{_2001}venus/disp2.pgm",
                "venus/disp2.pgm",
                "7d7b78ba89b1a8b8973cfebd61f2ef35b5adec70b2fb50817c2bd66e06a10170",
            ),
            *_masks("venus"),
            *(
                RemoteFile(f"{_2001}{scene}/{file}", f"{scene}/{file}")
                for scene in ("sawtooth", "bull")
                for file in ("im2.ppm", "im6.ppm", "disp2.pgm")
            ),
        ),
    ),
    "middlebury2003": Manifest(
        name="middlebury2003",
        base_url="https://vision.middlebury.edu/",
        note="Scharstein & Szeliski 2003 quarter-size scenes with the v2 evaluation masks",
        files=(
            RemoteFile(
                f"{_2003}cones/im2.png",
                "cones/im2.png",
                "e9875cec273b9c7a36ab8a0556b5c8451dd90cf50b5c8f30f4ab3bc8f201da92",
            ),
            RemoteFile(
                f"{_2003}cones/im6.png",
                "cones/im6.png",
                "a3795d564445b1e041a88fec490d4140efec87c9a4c64c1b56f7240c3a4fc727",
            ),
            RemoteFile(
                f"{_2003}cones/disp2.png",
                "cones/disp2.png",
                "d082b192d7893ef597dfaa9af5c7fea9cb0196808be42d40b80fbf47bb96f561",
            ),
            *_masks("cones"),
            *(
                RemoteFile(f"{_2003}teddy/{file}", f"teddy/{file}")
                for file in ("im2.png", "im6.png", "disp2.png")
            ),
            *_masks("teddy"),
        ),
    ),
}


class ChecksumMismatch(ValueError):
    """A downloaded file differs from the manifest's checksum (nothing is kept)."""


@dataclass(frozen=True)
class FetchedFile:
    path: Path
    sha256: str
    status: str  # "verified", "unverified" (no known checksum) or "present" (already verified)


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as stream:
        for chunk in iter(lambda: stream.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def _download(url: str, target: Path, timeout: float) -> None:
    """Copy ``url`` (http(s) or file) to ``target`` via a temporary file in the same folder."""
    from urllib.error import URLError
    from urllib.request import urlopen

    target.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.")
    try:
        with os.fdopen(handle, "wb") as out, urlopen(url, timeout=timeout) as response:
            shutil.copyfileobj(response, out)
        os.replace(temporary, target)
    except (URLError, OSError) as error:
        Path(temporary).unlink(missing_ok=True)
        raise ConnectionError(f"could not download {url}: {error}") from None


def fetch(
    name: str,
    directory: str | Path,
    *,
    mirror: str | None = None,
    scenes: list[str] | None = None,
    timeout: float = 60.0,
    progress: Callable[[FetchedFile], None] | None = None,
) -> list[FetchedFile]:
    """Download dataset ``name`` into ``directory/<scene>/`` and check the known checksums.

    ``mirror`` replaces the manifest's base URL (same relative paths; ``file://`` works). A file
    already present with the expected checksum is not downloaded again. A checksum mismatch
    deletes the file and raises :class:`ChecksumMismatch`.
    """
    if name not in MANIFESTS:
        raise ValueError(f"unknown dataset {name!r}; known datasets: {', '.join(MANIFESTS)}")
    manifest = MANIFESTS[name]
    wanted = manifest.files
    if scenes:
        unknown = set(scenes) - set(manifest.scenes())
        if unknown:
            raise ValueError(
                f"{name} has no scene {', '.join(sorted(unknown))}; "
                f"it has {', '.join(manifest.scenes())}"
            )
        wanted = tuple(f for f in wanted if f.target.split("/")[0] in scenes)
    base = (mirror or manifest.base_url).rstrip("/") + "/"
    directory = Path(directory)
    fetched = []
    for remote in wanted:
        target = directory / remote.target
        if remote.sha256 and target.is_file() and _sha256(target) == remote.sha256:
            result = FetchedFile(target, remote.sha256, "present")
        else:
            _download(base + remote.source, target, timeout)
            digest = _sha256(target)
            if remote.sha256 is not None and digest != remote.sha256:
                target.unlink()
                raise ChecksumMismatch(
                    f"{base + remote.source}: sha256 {digest} differs from the expected "
                    f"{remote.sha256}; the file was deleted (check the mirror)"
                )
            result = FetchedFile(target, digest, "verified" if remote.sha256 else "unverified")
        fetched.append(result)
        if progress is not None:
            progress(result)
    return fetched
