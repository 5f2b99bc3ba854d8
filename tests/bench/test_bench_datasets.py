"""Layout detection, protocol resolution and `qhsm datasets fetch` against a file:// mirror."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from shared import datasets
from shared.cli import main
from shared.datasets import (
    ChecksumMismatchError,
    Manifest,
    RemoteFile,
    fetch,
    find_scenes,
    load_scene,
)

LAYOUTS = ["middlebury2001", "middlebury2001-tsukuba", "middlebury2003", "shared"]


@pytest.mark.parametrize("layout", LAYOUTS)
def test_every_layout_is_detected_with_its_default_protocol(
    tmp_path: Path, layout: str, scene_writer, layout_files
):
    assert sorted(layout_files) == LAYOUTS
    truth = scene_writer(tmp_path / "mystery", layout)
    scene = load_scene(tmp_path / "mystery")
    left_name, right_name, gt_name, scale = layout_files[layout]
    assert (scene.left.name, scene.right.name, scene.gt.name) == (left_name, right_name, gt_name)
    assert scene.layout == layout
    assert scene.scale == scale
    left, right = scene.load()
    assert left.shape[:2] == right.shape[:2] == truth.shape
    # stored values / scale give back the disparity (to the rounding of the 8-bit file)
    assert np.abs(scene.ground_truth() / scene.scale - truth).max() <= 0.5 / scale + 1e-6


def test_known_scene_names_and_overrides_take_precedence(tmp_path: Path, scene_writer):
    scene_writer(tmp_path / "venus", "shared")
    assert load_scene(tmp_path / "venus").protocol()["scale"] == 8.0  # name beats layout
    (tmp_path / "venus" / "protocol.json").write_text(json.dumps({"border": 3}))
    scene = load_scene(tmp_path / "venus")
    assert (scene.scale, scene.border, scene.max_disparity) == (8.0, 3, 20)
    scene = load_scene(tmp_path / "venus", scale=2.0, border=0, max_disparity=9)
    assert (scene.scale, scene.border, scene.max_disparity) == (2.0, 0, 9)
    (tmp_path / "venus" / "protocol.json").write_text(json.dumps({"bordr": 3}))
    with pytest.raises(ValueError, match="bordr"):
        load_scene(tmp_path / "venus")


def test_find_scenes_skips_non_scenes_and_accepts_a_scene_folder(tmp_path: Path, scene_writer):
    scene_writer(tmp_path / "a", "middlebury2003")
    scene_writer(tmp_path / "b", "middlebury2001", masks=("nonocc", "disc"))
    (tmp_path / "notes").mkdir()
    found = find_scenes(tmp_path)
    assert list(found) == ["a", "b"]
    assert sorted(found["b"].masks) == ["disc", "nonocc"]
    disc = found["b"].mask("disc")
    assert disc.sum() == disc.size - disc.shape[0] * (disc.shape[1] // 2)  # only the 255s
    assert list(find_scenes(tmp_path / "a")) == ["a"]
    with pytest.raises(FileNotFoundError):
        load_scene(tmp_path / "notes")


def test_shared_middlebury_scenes_get_the_provenance_protocol(middlebury_dir: Path):
    scenes = find_scenes(middlebury_dir)
    protocols = {name: (s.scale, s.border) for name, s in scenes.items()}
    assert protocols == {"tsukuba": (16.0, 18), "venus": (8.0, 10), "cones": (4.0, 0)}
    counts = {name: int(s.mask("disc").sum()) for name, s in scenes.items()}
    assert counts == {"tsukuba": 15790, "venus": 10540, "cones": 47189}  # PROVENANCE.md


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


@pytest.fixture
def mirror(tmp_path: Path, monkeypatch) -> tuple[str, Path]:
    """A file:// mirror holding a toy manifest's files, one of them without a known checksum."""
    root = tmp_path / "mirror"
    files = {"x/one/im2.ppm": b"left", "x/one/im6.ppm": b"right", "x/one/disp2.pgm": b"gt"}
    for relative, data in files.items():
        (root / relative).parent.mkdir(parents=True, exist_ok=True)
        (root / relative).write_bytes(data)
    manifest = Manifest(
        name="toy",
        base_url="https://example.invalid/",
        files=(
            RemoteFile("x/one/im2.ppm", "one/im2.ppm", _sha(b"left")),
            RemoteFile("x/one/im6.ppm", "one/im6.ppm", _sha(b"right")),
            RemoteFile("x/one/disp2.pgm", "one/disp2.pgm", None),
        ),
    )
    monkeypatch.setitem(datasets.MANIFESTS, "toy", manifest)
    return root.as_uri(), root


def test_fetch_verifies_known_checksums_and_reports_unknown_ones(mirror, tmp_path: Path):
    url, _ = mirror
    target = tmp_path / "out"
    statuses = {f.path.name: f.status for f in fetch("toy", target, mirror=url)}
    assert statuses == {"im2.ppm": "verified", "im6.ppm": "verified", "disp2.pgm": "unverified"}
    assert (target / "one" / "im6.ppm").read_bytes() == b"right"
    again = {f.path.name: f.status for f in fetch("toy", target, mirror=url)}
    assert again["im2.ppm"] == "present"


def test_fetch_downloads_unverified_files_again_and_drops_a_corrupt_copy(mirror, tmp_path):
    url, root = mirror
    target = tmp_path / "out"
    fetch("toy", target, mirror=url)
    (root / "x/one/disp2.pgm").write_bytes(b"newer gt")
    (target / "one" / "im6.ppm").write_bytes(b"stale")
    (root / "x/one/im6.ppm").write_bytes(b"tampered")
    with pytest.raises(ChecksumMismatchError, match="differs"):
        fetch("toy", target, mirror=url)
    assert not (target / "one" / "im6.ppm").exists()  # neither the stale nor the bad copy
    (root / "x/one/im6.ppm").write_bytes(b"right")
    statuses = {f.path.name: (f.status, f.sha256) for f in fetch("toy", target, mirror=url)}
    assert statuses["disp2.pgm"] == ("unverified", _sha(b"newer gt"))
    assert (target / "one" / "disp2.pgm").read_bytes() == b"newer gt"
    assert statuses["im6.ppm"] == ("verified", _sha(b"right"))
    assert sorted(p.name for p in (target / "one").iterdir()) == ["disp2.pgm", "im2.ppm", "im6.ppm"]


def test_http_downloads_go_through_pooch_and_are_retried(mirror, tmp_path, monkeypatch):
    """Served from the file mirror by a stand-in for pooch's HTTP downloader that fails once."""
    import pooch
    import requests

    _, root = mirror
    calls: list[str] = []

    class FlakyHTTP:
        failures = 1  # the first this many calls fail

        def __init__(self, **kwargs):
            assert kwargs == {"timeout": 60.0}

        def __call__(self, url, output_file, pooch_, check_only=False):
            calls.append(url)
            if len(calls) <= self.failures:
                raise requests.ConnectionError("connection reset")
            relative = url.removeprefix("https://example.invalid/")
            Path(output_file).write_bytes((root / relative).read_bytes())

    monkeypatch.setattr(pooch, "HTTPDownloader", FlakyHTTP)
    monkeypatch.setattr(pooch.core.time, "sleep", lambda seconds: None)
    fetched = fetch("toy", tmp_path / "out")
    assert [f.status for f in fetched] == ["verified", "verified", "unverified"]
    assert calls[:2] == ["https://example.invalid/x/one/im2.ppm"] * 2  # retried once
    calls.clear()
    FlakyHTTP.failures = 99
    with pytest.raises(ConnectionError, match=r"could not download https://example\.invalid/"):
        fetch("toy", tmp_path / "other")
    assert len(calls) == 3  # RETRIES more attempts, then the error


def test_fetch_rejects_a_corrupt_file_and_keeps_nothing(mirror, tmp_path: Path):
    url, root = mirror
    (root / "x/one/im6.ppm").write_bytes(b"tampered")
    with pytest.raises(ChecksumMismatchError, match="differs"):
        fetch("toy", tmp_path / "out", mirror=url)
    assert not (tmp_path / "out" / "one" / "im6.ppm").exists()


def test_fetch_errors_name_the_problem(mirror, tmp_path: Path):
    url, _ = mirror
    with pytest.raises(ValueError, match="known datasets"):
        fetch("nosuch", tmp_path)
    with pytest.raises(ValueError, match="no scene two"):
        fetch("toy", tmp_path, mirror=url, scenes=["two"])
    with pytest.raises(ConnectionError, match="could not download"):
        fetch("toy", tmp_path, mirror=(tmp_path / "empty").as_uri())


def test_cli_fetch_reads_the_mirror_from_the_environment(mirror, tmp_path, monkeypatch, capsys):
    url, _ = mirror
    monkeypatch.setenv("QHSM_DATASET_MIRROR", url)
    assert main(["datasets", "fetch", "toy", str(tmp_path / "out")]) == 0
    captured = capsys.readouterr()
    assert "unverified" in captured.out and "no known checksum" in captured.err
    assert "Downloading" not in captured.err  # pooch's own log lines stay quiet
    assert main(["datasets", "fetch", "toy", str(tmp_path / "o2"), "--mirror", "file:///no"]) == 1


def test_real_manifest_checksums_match_the_shared_copies(middlebury_dir: Path, tmp_path: Path):
    """Serve the ../shared copies under the official paths: the manifest's sha256 must match."""
    copies = {
        "tsukuba": {
            "scene1.row3.col3.ppm": "left.ppm",
            "scene1.row3.col4.ppm": "right.ppm",
            "truedisp.row3.col3.pgm": "gt_left.pgm",
        },
        "venus": {"im2.ppm": "left.ppm", "im6.ppm": "right.ppm", "disp2.pgm": "gt_left.pgm"},
    }
    root = tmp_path / "mirror"
    for remote in datasets.MANIFESTS["middlebury2001"].files:
        scene, name = remote.target.split("/")
        if scene not in copies:
            continue
        local = copies[scene].get(name) or f"mask_{name}"
        (root / remote.source).parent.mkdir(parents=True, exist_ok=True)
        (root / remote.source).symlink_to(middlebury_dir / scene / local)
    fetched = fetch(
        "middlebury2001", tmp_path / "out", mirror=root.as_uri(), scenes=["tsukuba", "venus"]
    )
    assert {f.status for f in fetched} == {"verified"}
    scenes = find_scenes(tmp_path / "out")
    assert {name: (s.layout, s.scale, s.border) for name, s in scenes.items()} == {
        "tsukuba": ("middlebury2001-tsukuba", 16.0, 18),
        "venus": ("middlebury2001", 8.0, 10),
    }
    assert sorted(scenes["venus"].masks) == ["all", "disc", "nonocc"]
