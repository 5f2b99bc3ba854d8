"""Stereo scenes with ground truth: the Middlebury copies beside the repo and synthetic scenes.

A ``Scene`` knows its files and its evaluation protocol (ground-truth scale, ignored border,
masks). ``find_scenes`` accepts the ``left/right/gt_left`` layout of ``../shared/data/middlebury``
as well as the layouts Middlebury distributes (2001: ``im2.ppm/im6.ppm/disp2.pgm``, Tsukuba's
``scene1.row3.col3.ppm``; 2003 quarter size: ``im2.png/im6.png/disp2.png``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from shared.images import load_disparity_values, load_mask, load_pair

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

#: Candidate file names per role, in order of preference.
LAYOUTS = {
    "left": ["left.png", "left.ppm", "im2.ppm", "im2.png", "scene1.row3.col3.ppm", "im0.png"],
    "right": ["right.png", "right.ppm", "im6.ppm", "im6.png", "scene1.row3.col4.ppm", "im1.png"],
    "gt": ["gt_left.png", "gt_left.pgm", "disp2.pgm", "disp2.png", "truedisp.row3.col3.pgm"],
}
MASKS = {"all": "mask_all.png", "nonocc": "mask_nonocc.png", "disc": "mask_disc.png"}


@dataclass
class Scene:
    name: str
    left: Path
    right: Path
    gt: Path | None
    scale: float = 1.0
    border: int = 0
    masks: dict[str, Path] = field(default_factory=dict)

    def load(self) -> tuple[np.ndarray, np.ndarray]:
        return load_pair(self.left, self.right)

    def ground_truth(self) -> np.ndarray:
        if self.gt is None:
            raise FileNotFoundError(f"scene {self.name} has no ground truth")
        return load_disparity_values(self.gt)

    def mask(self, name: str) -> np.ndarray | None:
        return load_mask(self.masks[name]) if name in self.masks else None


def default_middlebury_dir() -> Path:
    """``../shared/data/middlebury`` beside the repository (override: QHSM_MIDDLEBURY_DIR)."""
    override = os.environ.get("QHSM_MIDDLEBURY_DIR")
    if override:
        return Path(override)
    return Path(__file__).resolve().parents[2] / "shared" / "data" / "middlebury"


def _first(folder: Path, names: list[str]) -> Path | None:
    return next((folder / n for n in names if (folder / n).is_file()), None)


def load_scene(folder: str | Path, name: str | None = None) -> Scene:
    """Detect a scene's files in ``folder``; protocol from ``KNOWN_PROTOCOLS`` by name."""
    folder = Path(folder)
    name = name or folder.name.lower()
    left, right = _first(folder, LAYOUTS["left"]), _first(folder, LAYOUTS["right"])
    if left is None or right is None:
        raise FileNotFoundError(
            f"{folder}: no stereo pair found (looked for {LAYOUTS['left']} and {LAYOUTS['right']})"
        )
    scale, border = KNOWN_PROTOCOLS.get(name, (1.0, 0))
    masks = {key: folder / file for key, file in MASKS.items() if (folder / file).is_file()}
    return Scene(
        name=name,
        left=left,
        right=right,
        gt=_first(folder, LAYOUTS["gt"]),
        scale=scale,
        border=border,
        masks=masks,
    )


def find_scenes(root: str | Path) -> dict[str, Scene]:
    """Every scene folder directly below ``root`` (sorted by name)."""
    root = Path(root)
    scenes = {}
    for folder in sorted(p for p in root.iterdir() if p.is_dir()):
        try:
            scenes[folder.name.lower()] = load_scene(folder)
        except FileNotFoundError:
            continue
    return scenes
