"""Depth and point clouds from Middlebury's and KITTI's calibration files, or options."""

from __future__ import annotations

import json

import numpy as np
import pytest

from shared.cli import main
from shared.datasets.calibration import CalibrationError, read_calibration
from shared.depth import point_cloud
from shared.images import load_disparity, save_disparity
from tests.calibration import middlebury_calib

#: A full-size Middlebury 2014 calib.txt, with the isint, vmin and vmax lines its files have.
MIDDLEBURY = middlebury_calib(
    3979.911, (1244.772, 1369.115), 1019.507, doffs=124.343, baseline=193.001,
    size=(2964, 1988), ndisp=270, isint=0, vmin=23, vmax=245,
)  # fmt: skip
KITTI = (
    "P_rect_02: 7.215377e+02 0.000000e+00 6.095593e+02 4.485728e+01 0.000000e+00 "
    "7.215377e+02 1.728540e+02 2.163791e-01 0.000000e+00 0.000000e+00 1.000000e+00 "
    "2.745884e-03\n"
    "P_rect_03: 7.215377e+02 0.000000e+00 6.095593e+02 -3.395242e+02 0.000000e+00 "
    "7.215377e+02 1.728540e+02 2.199936e+00 0.000000e+00 0.000000e+00 1.000000e+00 "
    "2.729905e-03\n"
)


def test_calibration_files(tmp_path):
    (tmp_path / "calib.txt").write_text(MIDDLEBURY)
    middlebury = read_calibration(tmp_path / "calib.txt")
    assert (middlebury.focal, middlebury.doffs, middlebury.ndisp) == (3979.911, 124.343, 270)
    # Middlebury's formula: Z = baseline * f / (d + doffs)
    assert middlebury.depth(np.array([100.0]))[0] == pytest.approx(193.001 * 3979.911 / 224.343)
    (tmp_path / "kitti.txt").write_text(KITTI)
    kitti = read_calibration(tmp_path / "kitti.txt")
    assert kitti.baseline == pytest.approx(0.532725, abs=1e-5) and kitti.unit == "m"
    assert kitti.depth(np.array([0.0, -1.0])).tolist() == [pytest.approx(np.nan, nan_ok=True)] * 2
    (tmp_path / "bad.txt").write_text("P2: 1 2 3\n")
    with pytest.raises(CalibrationError, match="P2/P3"):
        read_calibration(tmp_path / "bad.txt")


def test_points_are_where_the_depth_says_with_their_colours(tmp_path):
    (tmp_path / "calib.txt").write_text(MIDDLEBURY)
    calibration = read_calibration(tmp_path / "calib.txt")
    disparity = np.full((4, 6), 100.0, np.float32)
    disparity[0, 0] = np.nan
    image = np.zeros((4, 6, 3), np.float32)
    image[..., 2] = 1.0  # red in BGR
    points, colours = point_cloud(disparity, calibration, image)
    assert len(points) == 23
    np.testing.assert_allclose(points[:, 2], calibration.depth(np.array([100.0]))[0], rtol=1e-5)
    # x = (u - cx) Z / f for the second pixel of the first row (u = 1)
    z = points[0, 2]
    assert points[0, 0] == pytest.approx((1 - 1244.772) * z / 3979.911, rel=1e-5)
    assert colours.tolist()[0] == [255, 0, 0]


def test_depth_command_writes_depth_and_ply(tmp_path, capsys):
    save_disparity(np.full((4, 6), 10.0, np.float32), tmp_path / "d.pfm")
    command = ["depth", str(tmp_path / "d.pfm"), "--focal", "500", "--baseline", "0.1"]
    command += ["--unit", "m", "-o", str(tmp_path / "z.pfm"), "--ply", str(tmp_path / "c.ply")]
    assert main([*command, "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["points"] == 24 and report["unit"] == "m"
    np.testing.assert_allclose(load_disparity(tmp_path / "z.pfm"), 5.0)
    data = (tmp_path / "c.ply").read_bytes()
    header, _, body = data.partition(b"end_header\n")
    assert b"element vertex 24" in header and len(body) == 24 * 15
    assert main(["depth", str(tmp_path / "d.pfm"), "--ply", str(tmp_path / "x.ply")]) == 1
    assert "--calib" in capsys.readouterr().err


def test_match_writes_a_point_cloud_of_the_confirmed_pixels(tmp_path, scene, capsys):
    import cv2

    for name, view in (("l.png", scene.left), ("r.png", scene.right)):
        cv2.imwrite(str(tmp_path / name), (view * 255).round().astype(np.uint8))
    (tmp_path / "calib.txt").write_text(MIDDLEBURY)
    out, cloud = str(tmp_path / "d.pfm"), str(tmp_path / "c.ply")
    command = ["match", str(tmp_path / "l.png"), str(tmp_path / "r.png"), "-o", out]
    command += ["--max-disparity", "16", "--ply", cloud, "--calib", str(tmp_path / "calib.txt")]
    assert main([*command, "--json"]) == 0
    maps = json.loads(capsys.readouterr().out)["maps"]
    valid = cv2.imread(maps["validity"], cv2.IMREAD_GRAYSCALE) > 0
    assert f"element vertex {int(valid.sum())}".encode() in (tmp_path / "c.ply").read_bytes()[:200]
