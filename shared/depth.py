"""Depth maps and coloured point clouds from a disparity map and the pair's calibration
(:mod:`shared.datasets.calibration`): OpenCV's ``reprojectImageTo3D`` with the calibration's Q
matrix, written as binary PLY (x, y, z float32 in the baseline's unit; red, green, blue)."""

from __future__ import annotations

import cv2
import numpy as np

from shared.datasets.calibration import Calibration

PLY_VERTEX = np.dtype(
    [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")]
)


def point_cloud(
    disparity: np.ndarray,
    calibration: Calibration,
    image: np.ndarray | None = None,
    valid: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The 3-D points of the pixels with a depth (d + doffs > 0, finite, inside ``valid``) and
    their colours.

    Parameters
    ----------
    disparity : numpy.ndarray
        (h, w) px.
    calibration : Calibration
        The pair's cameras.
    image : numpy.ndarray, optional
        The left view (h, w) or (h, w, 3) BGR in [0, 1]; default: grey 128.
    valid : numpy.ndarray, optional
        (h, w) bool: only these pixels (e.g. the left-right check's).

    Returns
    -------
    points : numpy.ndarray
        (n, 3) float32, x right, y down, z forward.
    colours : numpy.ndarray
        (n, 3) uint8 RGB.
    """
    disparity = np.asarray(disparity, np.float32)
    xyz = cv2.reprojectImageTo3D(disparity, calibration.q_matrix().astype(np.float32))
    keep = np.isfinite(disparity) & (disparity + calibration.doffs > 0)
    keep &= np.isfinite(xyz).all(axis=2)
    if valid is not None:
        keep &= valid.astype(bool)
    if image is None:
        colours = np.full((int(keep.sum()), 3), 128, np.uint8)
    else:
        rgb = image[..., ::-1] if image.ndim == 3 else np.repeat(image[..., None], 3, axis=2)
        colours = np.clip(np.rint(rgb[keep] * 255), 0, 255).astype(np.uint8)
    return xyz[keep].astype(np.float32), colours


def ply_bytes(points: np.ndarray, colours: np.ndarray) -> bytes:
    """A binary little-endian PLY of coloured vertices (what Open3D, MeshLab and CloudCompare
    read)."""
    vertices = np.empty(len(points), PLY_VERTEX)
    for index, axis in enumerate("xyz"):
        vertices[axis] = points[:, index]
    for index, channel in enumerate(("red", "green", "blue")):
        vertices[channel] = colours[:, index]
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(points)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    )
    return header.encode() + vertices.tobytes()
