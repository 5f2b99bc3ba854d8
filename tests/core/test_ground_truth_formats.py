"""Ground truth read as the datasets store it: a PFM's header scale is its byte order only (as
Middlebury's SDK reads it), and the scale of the values follows from the format or the scene."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import qhsm
from shared.cli import main
from shared.ground_truth import ScaleWarning, resolve_gt_scale, scale_of_file, scale_of_format
from shared.images import ImageError, load_disparity_values, read_pfm, save_disparity


def pfm_bytes(values: np.ndarray, header_scale: float) -> bytes:
    """A gray PFM as Middlebury's files are: bottom row first, the scale's sign the byte order."""
    order = "<" if header_scale < 0 else ">"
    rows, columns = values.shape
    body = np.ascontiguousarray(values[::-1], dtype=f"{order}f4").tobytes()
    return f"Pf\n{columns} {rows}\n{header_scale}\n".encode() + body


finite = st.floats(-1e6, 1e6, allow_nan=False, width=32)


@settings(max_examples=40, deadline=None)
@given(
    values=arrays(np.float32, st.tuples(st.integers(1, 5), st.integers(1, 5)), elements=finite),
    header_scale=st.sampled_from([-0.003922, -1.0, 1.0, 0.5, -255.0]),
)
def test_pfm_values_are_read_as_stored_whatever_the_header_scale(values, header_scale):
    np.testing.assert_array_equal(read_pfm(pfm_bytes(values, header_scale)), values)


def test_colour_pfm_is_bgr_like_opencv(tmp_path):
    rgb = np.arange(2 * 3 * 3, dtype=np.float32).reshape(2, 3, 3)
    body = np.ascontiguousarray(rgb[::-1], dtype="<f4").tobytes()
    image = read_pfm(b"PF\n3 2\n-1.0\n" + body)
    np.testing.assert_array_equal(image, rgb[:, :, ::-1])


def test_truncated_pfm_is_an_image_error():
    with pytest.raises(ImageError, match="announces 4x4x1 floats but the file holds 2"):
        read_pfm(b"Pf\n4 4\n-1.0\n" + bytes(8), "gt.pfm")


def test_middlebury_2014_pfm_scores_as_its_stored_values(tmp_path, capsys):
    """The issue's target: a header scale of -0.003922 (as Middlebury 2014 ships) must not turn
    the values 255x larger (OpenCV's reading); RMSE equals the one from the raw values."""
    rng = np.random.default_rng(0)
    truth = rng.uniform(10, 120, (24, 32)).astype(np.float32)
    truth[0, :5] = np.inf  # unknown pixels, as in disp0GT.pfm
    (tmp_path / "disp0GT.pfm").write_bytes(pfm_bytes(truth, -0.003922))
    disparity = np.where(np.isfinite(truth), truth, 0) + rng.normal(0, 2, truth.shape)
    save_disparity(disparity.astype(np.float32), tmp_path / "d.pfm")
    known = np.isfinite(truth)
    expected = float(np.sqrt(np.mean((disparity[known] - truth[known]) ** 2)))

    command = ["eval", str(tmp_path / "d.pfm"), str(tmp_path / "disp0GT.pfm"), "--json"]
    assert main([*command, "--scale", "1"]) == 0
    out = capsys.readouterr()
    scores = json.loads(out.out)
    assert scores["rmse"] == pytest.approx(expected, rel=1e-4)
    assert "warning" not in out.err
    # without --scale: PFM holds pixels
    assert main(command) == 0
    scores = json.loads(capsys.readouterr().out)
    assert scores["rmse"] == pytest.approx(expected, rel=1e-4) and scores["scale"] == 1
    assert "PFM" in scores["scale_source"]


def test_a_scale_that_contradicts_the_format_is_warned_about(tmp_path):
    gt = tmp_path / "gt.png"
    cv2.imwrite(str(gt), np.full((8, 8), 2560, np.uint16))
    assert scale_of_file(gt).scale == 256
    with pytest.warns(ScaleWarning, match="given, but a 16-bit PNG"):
        assert resolve_gt_scale(gt, 16) == (16.0, "given")
    with pytest.warns(ScaleWarning):
        report = qhsm.evaluate(np.full((8, 8), 10.0, np.float32), gt, scale=16)
    assert report["scale"] == 16 and "says 256" in report["warnings"][0]
    assert resolve_gt_scale(gt)[0] == 256
    assert load_disparity_values(gt)[0, 0] / resolve_gt_scale(gt)[0] == 10


def test_eight_bit_ground_truth_takes_its_scene_convention_or_asks(tmp_path, capsys):
    scene = tmp_path / "tsukuba"
    scene.mkdir()
    for name in ("left.png", "right.png", "gt_left.png"):
        cv2.imwrite(str(scene / name), np.full((40, 40), 32, np.uint8))
    assert resolve_gt_scale(scene / "gt_left.png")[0] == 16  # Tsukuba's convention
    loose = tmp_path / "gt.png"
    cv2.imwrite(str(loose), np.full((8, 8), 32, np.uint8))
    assert scale_of_file(loose) is None
    save_disparity(np.full((40, 40), 2.0, np.float32), tmp_path / "d.pfm")
    assert main(["eval", str(tmp_path / "d.pfm"), str(loose)]) == 1
    assert "give it" in capsys.readouterr().err
    assert main(["eval", str(tmp_path / "d.pfm"), str(scene / "gt_left.png"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["rmse"] == 0


def test_format_scale_of_bytes():
    assert scale_of_format(pfm_bytes(np.ones((2, 2), np.float32), -0.003922)).scale == 1
    assert scale_of_format(cv2.imencode(".png", np.ones((2, 2), np.uint8))[1].tobytes()) is None


def test_eval_regions_threshold_error_map_and_table(tmp_path, capsys):
    truth = np.full((8, 8), 20.0, np.float32)
    (tmp_path / "gt.pfm").write_bytes(pfm_bytes(truth, -1.0))
    disparity = truth.copy()
    disparity[:2] = 30.0  # the object rows are 10 px off
    save_disparity(disparity, tmp_path / "d.pfm")
    objects = np.zeros((8, 8), np.uint8)
    objects[:4] = 1
    cv2.imwrite(str(tmp_path / "obj_map.png"), objects)
    errors = tmp_path / "errors.png"
    command = ["eval", str(tmp_path / "d.pfm"), str(tmp_path / "gt.pfm"), "--fg"]
    command += [str(tmp_path / "obj_map.png"), "--threshold", "2", "--error-map", str(errors)]
    assert main([*command, "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["d1"] == 25.0 and report["threshold"] == 2 and report["bad_4"] == 25.0
    assert report["regions"]["fg"]["d1"] == 50.0 and report["regions"]["bg"]["d1"] == 0.0
    assert cv2.imread(str(errors)).shape == (8, 8, 3) and report["error_map"] == str(errors)
    assert main(command) == 0
    table = capsys.readouterr().out.splitlines()
    assert table[1].split()[:3] == ["region", "pixels", "rmse"]
    assert [row.split()[0] for row in table[2:5]] == ["all", "bg", "fg"]


def test_eval_scores_a_recognised_scene_on_its_non_occluded_pixels(tmp_path, capsys):
    scene = tmp_path / "venus"
    scene.mkdir()
    for name in ("left.png", "right.png"):
        cv2.imwrite(str(scene / name), np.zeros((30, 30), np.uint8))
    cv2.imwrite(str(scene / "gt_left.png"), np.full((30, 30), 40, np.uint8))  # 5 px at scale 8
    nonocc = np.zeros((30, 30), np.uint8)
    nonocc[:, 15:] = 255
    cv2.imwrite(str(scene / "mask_nonocc.png"), nonocc)
    disparity = np.full((30, 30), 5.0, np.float32)
    disparity[:, :15] = 0
    save_disparity(disparity, tmp_path / "d.pfm")
    assert main(["eval", str(tmp_path / "d.pfm"), str(scene / "gt_left.png"), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["scale"] == 8 and report["border"] == 10
    assert report["regions"]["nonocc"]["bad_1"] == 0 and report["bad_1"] > 0
