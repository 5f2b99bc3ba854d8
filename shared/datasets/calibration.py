"""Camera calibration of a rectified pair, read from the datasets' files or given as options:
what turns a disparity into depth and a point cloud, and Middlebury's disparity range.

Middlebury 2014 (and MiddEval3) ``calib.txt``: ``cam0=[f 0 cx; 0 f cy; 0 0 1]``, ``cam1=...``,
``doffs`` (cx1 - cx0, px), ``baseline`` (mm), ``ndisp`` (a bound on the disparities). KITTI:
``P2:`` / ``P3:`` (object and 2012 ``calib/*.txt``) or ``P_rect_02:`` / ``P_rect_03:`` (2015
``calib_cam_to_cam/*.txt``), 3x4 projection matrices whose x-translations give the baseline
(m). Depth is Z = f B / (d + doffs), in the baseline's unit.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Calibration file names looked for in a scene folder, in order.
CALIBRATION_FILES = ("calib.txt",)


class CalibrationError(ValueError):
    """A calibration file that cannot be read; the message names the file and what is missing."""


@dataclass(frozen=True)
class Calibration:
    """What depth needs from a rectified pair's cameras."""

    focal: float  # px
    cx: float  # the left camera's principal point, px
    cy: float
    baseline: float  # in ``unit``
    doffs: float = 0.0  # cx(right) - cx(left), px
    unit: str = "mm"
    ndisp: int | None = None  # Middlebury's bound on the disparities, px
    source: str = "options"

    def q_matrix(self) -> np.ndarray:
        """OpenCV's 4x4 reprojection matrix (``cv2.reprojectImageTo3D``): W = (d + doffs) / B,
        Z = f / W."""
        return np.array(
            [
                [1.0, 0.0, 0.0, -self.cx],
                [0.0, 1.0, 0.0, -self.cy],
                [0.0, 0.0, 0.0, self.focal],
                [0.0, 0.0, 1.0 / self.baseline, self.doffs / self.baseline],
            ]
        )

    def depth(self, disparity: np.ndarray) -> np.ndarray:
        """Z = f B / (d + doffs) in the baseline's unit; NaN where d + doffs <= 0 or d is not
        finite (no depth)."""
        shifted = np.asarray(disparity, np.float64) + self.doffs
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = np.where(shifted > 0, self.focal * self.baseline / shifted, np.nan)
        return depth.astype(np.float32)


def _numbers(text: str) -> list[float]:
    return [float(v) for v in re.findall(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?", text)]


def read_middlebury(path: str | Path) -> Calibration:
    """A Middlebury ``calib.txt`` (``key=value`` lines)."""
    return middlebury_text(Path(path).read_text(), str(path))


def middlebury_text(text: str, source: str) -> Calibration:
    """Middlebury's ``calib.txt`` content; ``source`` names it in errors."""
    fields = dict(line.split("=", 1) for line in text.splitlines() if "=" in line)
    try:
        cam0 = _numbers(fields["cam0"])
        focal, cx, cy = cam0[0], cam0[2], cam0[5]
        baseline = float(fields["baseline"])
        doffs = float(fields.get("doffs", "0"))
    except (KeyError, IndexError, ValueError) as error:
        raise CalibrationError(
            f"{source}: not a Middlebury calib.txt (needs cam0=[f 0 cx; 0 f cy; 0 0 1], "
            f"baseline; {error})"
        ) from None
    ndisp = int(float(fields["ndisp"])) if "ndisp" in fields else None
    return Calibration(focal, cx, cy, baseline, doffs, "mm", ndisp, source)


def read_kitti(path: str | Path) -> Calibration:
    """A KITTI calibration file (``P2:``/``P3:`` or ``P_rect_02:``/``P_rect_03:``)."""
    return kitti_text(Path(path).read_text(), str(path))


def kitti_text(text: str, source: str) -> Calibration:
    """A KITTI calibration file's content; ``source`` names it in errors."""
    rows: dict[str, list[float]] = {}
    for line in text.splitlines():
        key, sep, value = line.partition(":")
        if sep:
            rows[key.strip()] = _numbers(value)
    for left, right in (("P2", "P3"), ("P_rect_02", "P_rect_03")):
        if left in rows and right in rows and len(rows[left]) == len(rows[right]) == 12:
            p2, p3 = np.reshape(rows[left], (3, 4)), np.reshape(rows[right], (3, 4))
            focal = float(p2[0, 0])
            baseline = float(p2[0, 3] - p3[0, 3]) / focal
            doffs = float(p3[0, 2] - p2[0, 2])
            return Calibration(focal, float(p2[0, 2]), float(p2[1, 2]), baseline, doffs, "m",
                               None, source)  # fmt: skip
    raise CalibrationError(f"{source}: no P2/P3 or P_rect_02/P_rect_03 rows of 12 numbers (KITTI)")


def read_calibration(path: str | Path) -> Calibration:
    """Middlebury's ``key=value`` format or KITTI's ``key: numbers`` one, by content."""
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"{path}: no such calibration file")
    return calibration_text(path.read_text(), str(path))


def calibration_text(text: str, source: str) -> Calibration:
    """A calibration file's content, Middlebury's or KITTI's format by what it holds."""
    if re.search(r"^cam0\s*=", text, re.M):
        return middlebury_text(text, source)
    return kitti_text(text, source)


def scene_calibration(folder: str | Path) -> Path | None:
    """The calibration file of a scene folder, if it has one."""
    return next((Path(folder) / n for n in CALIBRATION_FILES if (Path(folder) / n).is_file()), None)
