"""Bench test fixtures: tiny synthetic scenes written the way Middlebury distributes them."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from shared.synthetic import make_scene

#: Per layout: left, right and ground-truth file names and the ground-truth scale it implies.
LAYOUT_FILES = {
    "shared": ("left.png", "right.png", "gt_left.png", 1.0),
    "middlebury2001": ("im2.ppm", "im6.ppm", "disp2.pgm", 8.0),
    "middlebury2001-tsukuba": (
        "scene1.row3.col3.ppm",
        "scene1.row3.col4.ppm",
        "truedisp.row3.col3.pgm",
        16.0,
    ),
    "middlebury2003": ("im2.png", "im6.png", "disp2.png", 4.0),
}


def write_scene(
    folder: Path,
    layout: str,
    *,
    seed: int = 0,
    height: int = 32,
    width: int = 48,
    max_disparity: int = 8,
    protocol: dict | None = None,
    masks: tuple[str, ...] = (),
) -> np.ndarray:
    """Write a synthetic scene in ``layout`` to ``folder``; returns the true disparity."""
    scene = make_scene(height, width, max_disparity=max_disparity, seed=seed)
    left_name, right_name, gt_name, scale = LAYOUT_FILES[layout]
    folder.mkdir(parents=True, exist_ok=True)
    to_bgr = lambda image: cv2.cvtColor(  # noqa: E731
        np.rint(image * 255).astype(np.uint8), cv2.COLOR_GRAY2BGR
    )
    cv2.imwrite(str(folder / left_name), to_bgr(scene.left))
    cv2.imwrite(str(folder / right_name), to_bgr(scene.right))
    gt = np.clip(np.rint(scene.disparity * scale), 0, 255).astype(np.uint8)
    cv2.imwrite(str(folder / gt_name), gt)
    for name in masks:
        mask = np.full(gt.shape, 255, np.uint8)
        if name == "disc":
            mask[:, : width // 2] = 128  # only the 255 pixels are "near discontinuities"
        cv2.imwrite(str(folder / f"{name}.png"), mask)
    if protocol is not None:
        (folder / "protocol.json").write_text(json.dumps(protocol))
    return scene.disparity


@pytest.fixture
def scene_writer():
    """:func:`write_scene`, for tests that lay out their own scenes."""
    return write_scene


@pytest.fixture
def layout_files() -> dict:
    return LAYOUT_FILES


@pytest.fixture
def tiny_dataset(tmp_path: Path) -> Path:
    """Two scenes: one named like a paper scene (2001 layout), one in the 2003 layout."""
    root = tmp_path / "data"
    write_scene(
        root / "tsukuba",
        "middlebury2001-tsukuba",
        seed=1,
        protocol={"border": 2, "max_disparity": 8},
        masks=("nonocc", "all", "disc"),
    )
    write_scene(root / "cones", "middlebury2003", seed=2, protocol={"max_disparity": 8})
    return root
