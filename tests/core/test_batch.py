"""`qhsm batch`: every pair below a folder, the range stated or estimated (never the ground
truth's), one table."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from shared.batch import find_pairs
from shared.cli import main
from shared.datasets import load_scene
from shared.synthetic import make_scene
from tests.calibration import middlebury_calib

CALIB = middlebury_calib(500, (30, 32), 20, doffs=2, baseline=100, size=(64, 48), ndisp=14)


def write_views(folder: Path, names: tuple[str, str], seed: int, swapped: bool = False):
    scene = make_scene(48, 64, max_disparity=10, seed=seed)
    folder.mkdir(parents=True)
    views = (scene.right, scene.left) if swapped else (scene.left, scene.right)
    for name, view in zip(names, views, strict=True):
        cv2.imwrite(str(folder / name), (view * 255).round().astype(np.uint8))
    return scene


def pfm(values: np.ndarray) -> bytes:
    height, width = values.shape
    body = np.ascontiguousarray(values[::-1], "<f4").tobytes()
    return f"Pf\n{width} {height}\n-0.003922\n".encode() + body


@pytest.fixture
def folder(tmp_path):
    root = tmp_path / "data"
    stated = write_views(root / "lab" / "a", ("left.png", "right.png"), 1)
    cv2.imwrite(str(root / "lab" / "a" / "gt_left.png"), (stated.disparity * 8).astype(np.uint8))
    (root / "lab" / "a" / "protocol.json").write_text(json.dumps({"scale": 8, "max_disparity": 12}))
    calibrated = write_views(root / "m2014" / "b", ("im0.png", "im1.png"), 2)
    (root / "m2014" / "b" / "disp0GT.pfm").write_bytes(pfm(calibrated.disparity))
    (root / "m2014" / "b" / "calib.txt").write_text(CALIB)
    unknown = write_views(root / "m2014" / "c", ("im0.png", "im1.png"), 3)
    (root / "m2014" / "c" / "disp0GT.pfm").write_bytes(pfm(unknown.disparity))
    write_views(root / "m2014" / "swapped", ("im0.png", "im1.png"), 4, swapped=True)
    return root


def test_ranges_are_stated_or_estimated_and_said(folder):
    pairs = {pair.name: pair for pair in find_pairs(folder / "m2014")}
    assert (pairs["m2014/b"].max_disparity, pairs["m2014/b"].range_source) == (
        14,
        f"{folder / 'm2014' / 'b' / 'calib.txt'} (ndisp)",
    )
    # the ground truth's maximum is what `qhsm bench` scores with, but never a batch's range
    assert load_scene(folder / "m2014" / "c").max_disparity_source == "the ground truth's maximum"
    assert pairs["m2014/c"].max_disparity is None
    assert pairs["m2014/c"].range_source == "estimated (auto)"


def test_batch_writes_one_table_with_every_pair(folder, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["batch", str(folder), "--out", str(out), "--json"]) == 1  # one pair failed
    rows = {row["name"]: row for row in json.loads(capsys.readouterr().out)}
    assert set(rows) == {"lab/a", "m2014/b", "m2014/c", "m2014/swapped"}
    assert rows["lab/a"]["max_disparity"] == 12 and "protocol.json" in rows["lab/a"]["range_source"]
    assert rows["m2014/b"]["max_disparity"] == 14
    assert rows["m2014/c"]["range_source"] == "estimated (auto)"
    for name in ("lab/a", "m2014/b", "m2014/c"):
        assert rows[name]["status"] == "ok" and rows[name]["bad_2"] < 25, rows[name]
        assert Path(rows[name]["output"]).is_file()
        assert Path(rows[name]["validity_map"]).is_file()  # the accurate preset's LR check
        assert Path(rows[name]["confidence_map"]).is_file()
    assert rows["m2014/swapped"]["status"] == "failed"
    assert "swapped" in rows["m2014/swapped"]["reason"]
    with (out / "results.csv").open() as stream:
        table = list(csv.DictReader(stream))
    assert [row["name"] for row in table] == sorted(rows)
    assert {"rmse", "d1", "bad_0_5", "range_source"} <= set(table[0])
    assert json.loads((out / "results.json").read_text())["provenance"]["solver"] == "exact"


def test_kitti_layout(tmp_path, capsys):
    root = tmp_path / "training"
    scene = write_views(root / "image_2", ("000000_10.png", "unused.png"), 5)
    (root / "image_3").mkdir()
    cv2.imwrite(str(root / "image_3" / "000000_10.png"), (scene.right * 255).astype(np.uint8))
    (root / "disp_occ_0").mkdir()
    cv2.imwrite(
        str(root / "disp_occ_0" / "000000_10.png"), (scene.disparity * 256).astype(np.uint16)
    )
    (root / "obj_map").mkdir()
    objects = (scene.disparity > 6).astype(np.uint8)
    cv2.imwrite(str(root / "obj_map" / "000000_10.png"), objects)
    [pair] = find_pairs(root)
    assert (pair.name, pair.scale, pair.range_source) == (
        "training/000000_10",
        256.0,
        "estimated (auto)",
    )
    command = ["batch", str(root), "--out", str(tmp_path / "out"), "--max-disparity", "12"]
    assert main([*command, "--json"]) == 0
    [row] = json.loads(capsys.readouterr().out)
    assert row["range_source"] == "given" and {"fg_d1", "bg_d1", "d1"} <= set(row)
