"""Synthetic stereo scenes with exact ground truth, for tests and demos on machines without the
Middlebury data.

A scene is a stack of textured surfaces seen by two rectified cameras: a background (fronto-parallel
or a slanted plane d(x) = a + b x) and fronto-parallel rectangles in front of it. Each surface
carries its own texture in left-view coordinates u; the left camera sees texture(u = x), the right
camera sees texture(u) where x' = u - d(u). Nearer surfaces (larger disparity) occlude farther ones
in each view, so the right view has genuine occlusions. Ground truth is the left view's disparity.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class SyntheticScene:
    left: np.ndarray  # float32 gray in [0, 1]
    right: np.ndarray
    disparity: np.ndarray  # float32, left view, pixels
    right_disparity: np.ndarray  # float32, right view: right pixel x matches left x + d

    def ground_truth_values(self, scale: float = 1.0) -> np.ndarray:
        """Ground truth as stored values (disparity x scale), Middlebury style.

        Parameters
        ----------
        scale : float, optional
            Stored value per pixel of disparity (Middlebury's GT PNGs: e.g. 16 for Tsukuba).

        Returns
        -------
        numpy.ndarray
            (h, w) float32.
        """
        return (self.disparity * scale).astype(np.float32)


@dataclass(frozen=True)
class _Surface:
    texture: np.ndarray  # (h, w + margin) in left-view coordinates
    disparity_at: tuple[float, float]  # d(u) = a + b u
    box: tuple[int, int, int, int] | None  # (top, bottom, left, right) in left coords; None = all


def _texture(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """Band-limited random texture in [0.05, 0.95]: enough contrast to match, no aliasing."""
    noise = cv2.GaussianBlur(rng.random(shape), (0, 0), sigmaX=1.0, borderType=cv2.BORDER_REFLECT)
    noise -= noise.min()
    return (0.05 + 0.9 * noise / max(float(noise.max()), 1e-9)).astype(np.float32)


def _render(surfaces: list[_Surface], shape: tuple[int, int], view: str):
    """Intensity and disparity of the nearest surface at every pixel of ``view``."""
    height, width = shape
    ys, xs = np.mgrid[:height, :width].astype(np.float32)
    image = np.zeros(shape, np.float32)
    depth = np.full(shape, -np.inf, np.float32)
    for surface in surfaces:
        a, b = surface.disparity_at
        # left view: u = x; right view: x' = u - (a + b u)  =>  u = (x' + a) / (1 - b)
        u = xs if view == "left" else (xs + a) / (1.0 - b)
        disparity = (a + b * u).astype(np.float32)
        covered = (u >= 0) & (u <= surface.texture.shape[1] - 1)
        if surface.box is not None:
            top, bottom, left, right = surface.box
            covered &= (ys >= top) & (ys < bottom) & (u >= left) & (u < right)
        value = cv2.remap(
            surface.texture,
            u.astype(np.float32),
            ys,
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REFLECT,
        )
        nearer = covered & (disparity > depth)
        image = np.where(nearer, value, image)
        depth = np.where(nearer, disparity, depth)
    return image, depth


def make_scene(
    height: int = 48,
    width: int = 64,
    max_disparity: int = 12,
    slanted: bool = True,
    layers: int = 2,
    seed: int = 0,
) -> SyntheticScene:
    """A random scene with disparities in [1, max_disparity] (full-resolution pixels).

    The background is a slanted plane (or fronto-parallel with ``slanted=False``) at small
    disparities; ``layers`` rectangles float in front of it at larger integer disparities.

    Parameters
    ----------
    height, width : int, optional
        Size of the views.
    max_disparity : int, optional
        Largest disparity, px.
    slanted : bool, optional
        Slanted (default) or fronto-parallel background.
    layers : int, optional
        Rectangles in front of the background.
    seed : int, optional
        Seed of the textures and the layout.

    Returns
    -------
    SyntheticScene
        Both views and both views' ground truth.
    """
    rng = np.random.default_rng(seed)
    margin = 2 * max_disparity + 4
    tex_shape = (height, width + margin)
    low = max(1.0, 0.15 * max_disparity)
    if slanted:
        high = max(low, 0.45 * max_disparity)
        background = (low, (high - low) / max(width - 1, 1))
    else:
        background = (float(np.ceil(low)), 0.0)
    surfaces = [_Surface(_texture(rng, tex_shape), background, None)]
    for _ in range(layers):
        d = float(rng.integers(int(np.ceil(0.55 * max_disparity)), max_disparity + 1))
        h = int(rng.integers(height // 4, height // 2 + 1))
        w = int(rng.integers(width // 5, width // 3 + 1))
        top = int(rng.integers(0, height - h + 1))
        left = int(rng.integers(int(d), max(int(d) + 1, width - w + 1)))
        surfaces.append(
            _Surface(_texture(rng, tex_shape), (d, 0.0), (top, top + h, left, left + w))
        )
    left_image, disparity = _render(surfaces, (height, width), "left")
    right_image, right_disparity = _render(surfaces, (height, width), "right")
    return SyntheticScene(
        left=left_image, right=right_image, disparity=disparity, right_disparity=right_disparity
    )
