"""The generalisation benchmark's instrument (issue 17): non-occlusion from the ground truth's
left-right check, the SGBM baseline's settings, discovery of datasets laid out like Middlebury
2005/2006 (and KITTI, MiddEval3), variants, the comparison and one run end to end."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.baselines import SGBM_PARAMETERS, sgbm, sgbm_matcher
from shared.bench.experiments import BenchError
from shared.bench.generalisation import (
    VARIANTS,
    Options,
    named_variants,
    parse_variant,
    run_benchmark,
    select_scenes,
)
from shared.bench.generalisation_report import compare, markdown
from shared.bench.scoring import Run, score
from shared.cli import main
from shared.config import Preset
from shared.datasets import confirmed_by_right_view, find_datasets, load_scene
from shared.filters import fill_from_background
from shared.synthetic import make_scene

# --- non-occlusion from the ground truth's left-right consistency ---------------------------

WIDTH, HEIGHT = 40, 6
BACKGROUND, FOREGROUND = 2, 6
FRONT = slice(20, 30)  # the foreground's columns in the left view


def _layered_ground_truth() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Left and right ground truth of a fronto-parallel square before a background, and the
    left pixels that are occluded in the right view (worked out by hand)."""
    left = np.full((HEIGHT, WIDTH), BACKGROUND, np.uint8)
    left[:, FRONT] = FOREGROUND
    right = np.full((HEIGHT, WIDTH), BACKGROUND, np.uint8)
    right[:, FRONT.start - FOREGROUND : FRONT.stop - FOREGROUND] = FOREGROUND
    occluded = np.zeros((HEIGHT, WIDTH), bool)
    # background just left of the square: its match lands on the square in the right view
    occluded[:, FRONT.start - (FOREGROUND - BACKGROUND) : FRONT.start] = True
    occluded[:, :BACKGROUND] = True  # the match falls off the right image
    return left, right, occluded


def _write_views(folder: Path, height: int, width: int) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    for name in ("left.png", "right.png"):
        cv2.imwrite(str(folder / name), rng.integers(0, 255, (height, width, 3), np.uint8))


def test_non_occluded_pixels_are_those_the_right_ground_truth_confirms(tmp_path: Path):
    left, right, occluded = _layered_ground_truth()
    left[0, 5] = 0  # unknown on the left: never scored
    right[1, 8] = 0  # unknown on the right: the left pixel matching it cannot be confirmed
    folder = tmp_path / "lab" / "square"
    _write_views(folder, HEIGHT, WIDTH)
    cv2.imwrite(str(folder / "gt_left.png"), left)
    cv2.imwrite(str(folder / "gt_right.png"), right)
    scene = load_scene(folder)
    assert scene.gt_right is not None and scene.gt_right.name == "gt_right.png"
    assert (scene.non_occlusion, scene.scale) == ("left-right", 1.0)
    expected = ~occluded & (left > 0)
    expected[1, 8 + BACKGROUND] = False
    np.testing.assert_array_equal(scene.non_occluded(), expected)

    # scored: a map wrong only where the right view cannot see is perfect on the non-occluded
    disparity = left.astype(np.float32)
    disparity[occluded] = 0.0
    run = Run("square", "generalisation", "x", "pipeline", "exact", "ok")
    score(run, disparity, scene, scene.ground_truth())
    nonocc = {key: run.masks["nonocc"][key] for key in ("rmse", "bpp", "pixels", "d1")}
    assert nonocc == {"rmse": 0.0, "bpp": 0.0, "pixels": int(expected.sum()), "d1": 0.0}
    assert run.bpp == pytest.approx(100 * occluded[left > 0].mean())

    # a nonocc mask on disk is the dataset's word and wins over the ground truth's check
    cv2.imwrite(str(folder / "mask_nonocc.png"), np.full((HEIGHT, WIDTH), 255, np.uint8))
    scene = load_scene(folder)
    assert scene.non_occlusion == "mask" and scene.non_occluded().all()


@settings(max_examples=60, deadline=None)
@given(
    layers=st.lists(st.sampled_from([2, 5, 8, 11]), min_size=1, max_size=6),
    widths=st.lists(st.integers(1, 12), min_size=6, max_size=6),
)
def test_the_check_finds_exactly_the_pixels_the_right_view_sees(layers, widths):
    """Fronto-parallel layers 3 px of disparity apart, the right ground truth rendered with a
    z-buffer: the check keeps exactly the left pixels that win the z-test at their match."""
    row = np.concatenate([np.full(w, d) for d, w in zip(layers, widths, strict=False)])
    width = row.size
    right = np.zeros(width)
    for x in np.argsort(row, kind="stable"):  # nearer (larger d) written last: the z-test
        if x - row[x] >= 0:
            right[x - row[x]] = row[x]
    visible = np.array([x - d >= 0 and right[x - d] == d for x, d in enumerate(row)])
    found = confirmed_by_right_view(row[None].astype(float), right[None])
    np.testing.assert_array_equal(found[0], visible)


# --- the SGBM baseline ----------------------------------------------------------------------


def test_sgbm_is_the_issue_17_baseline():
    matcher = sgbm_matcher(55)
    settings_read_back = {
        "blockSize": matcher.getBlockSize(),
        "P1": matcher.getP1(),
        "P2": matcher.getP2(),
        "disp12MaxDiff": matcher.getDisp12MaxDiff(),
        "uniquenessRatio": matcher.getUniquenessRatio(),
        "speckleWindowSize": matcher.getSpeckleWindowSize(),
        "speckleRange": matcher.getSpeckleRange(),
        "mode": matcher.getMode(),
    }
    assert settings_read_back == SGBM_PARAMETERS
    assert settings_read_back == {  # issue 17, in its own terms
        "blockSize": 5,
        "P1": 8 * 3 * 25,
        "P2": 32 * 3 * 25,
        "disp12MaxDiff": 1,
        "uniquenessRatio": 10,
        "speckleWindowSize": 100,
        "speckleRange": 2,
        "mode": cv2.STEREO_SGBM_MODE_HH,
    }
    assert (matcher.getMinDisparity(), matcher.getNumDisparities()) == (0, 64)
    assert sgbm_matcher(47).getNumDisparities() == 48  # 0..47 fits in 48


def test_sgbm_matches_the_colour_views_and_fills_from_the_background(scene):
    # channels that carry different information (pointwise functions keep the correspondence)
    colour = lambda view: np.dstack([view, view**2, 1 - view]).astype(np.float32)  # noqa: E731
    left, right = colour(scene.left), colour(scene.right)
    result = sgbm(left, right, 16)
    as_bytes = lambda view: np.rint(view * 255).astype(np.uint8)  # noqa: E731
    raw = sgbm_matcher(16).compute(as_bytes(left), as_bytes(right)).astype(np.float32) / 16
    np.testing.assert_array_equal(result.disparity, fill_from_background(raw, raw >= 0, 0.0))
    gray = sgbm(cv2.cvtColor(left, cv2.COLOR_BGR2GRAY), cv2.cvtColor(right, cv2.COLOR_BGR2GRAY), 16)
    assert not np.array_equal(result.disparity, gray.disparity)  # the colour reached OpenCV
    assert result.info["num_disparities"] == 32 and 0 < result.info["invalid_fraction"] < 0.5


# --- discovery ------------------------------------------------------------------------------


def _write_middlebury_scene(
    folder: Path, height: int, factor: int, top: float, names: tuple[str, ...] = ()
) -> None:
    """A scene of a Middlebury 2005/2006 size: 8-bit GT of full-size disparities (our file
    names, or ``names``: left, right, left GT, right GT)."""
    left, right, gt_left, gt_right = names or (
        "left.png",
        "right.png",
        "gt_left.png",
        "gt_right.png",
    )
    _write_views(folder, height, 24)
    if names:
        for ours, theirs in (("left.png", left), ("right.png", right)):
            (folder / ours).rename(folder / theirs)
    disparity = np.linspace(1.0, top, 24)[None].repeat(height, axis=0)
    stored = np.rint(disparity * factor).astype(np.uint8)
    stored[0, 0] = 0  # unknown
    cv2.imwrite(str(folder / gt_left), stored)
    cv2.imwrite(str(folder / gt_right), stored)


@pytest.fixture
def datasets(tmp_path: Path, scene_writer) -> Path:
    """A folder of datasets the way the lab keeps them: 2001, 2005 third, 2006 half and full
    size, KITTI, MiddEval3 and one of its own with a dataset-wide protocol.json."""
    root = tmp_path / "data"
    scene_writer(root / "middlebury" / "tsukuba", "shared", masks=("nonocc",))
    _write_middlebury_scene(root / "middlebury2005" / "Art", 370, 3, 70.3)
    _write_middlebury_scene(root / "middlebury2006" / "Aloe", 555, 2, 50.5)
    _write_middlebury_scene(root / "middlebury2006" / "Baby1", 1110, 1, 120.0)
    kitti = root / "kitti2015" / "000000"
    _write_views(kitti, 8, 24)
    cv2.imwrite(str(kitti / "gt_left.png"), np.full((8, 24), 40 * 256 + 64, np.uint16))
    teddy = root / "middlebury2014" / "Teddy"  # a known 2003 name, but PFM: real disparities
    _write_views(teddy, 8, 24)
    cv2.imwrite(str(teddy / "gt_left.pfm"), np.full((8, 24), 33.25, np.float32))
    mask = np.full((8, 24), 255, np.uint8)
    mask[:, :4] = 128  # MiddEval3: 128 = occluded
    cv2.imwrite(str(teddy / "mask_left_nocc.png"), mask)
    # as Middlebury distributes them, in a folder of any name: the file names tell
    original = ("view1.png", "view5.png", "disp1.png", "disp5.png")
    _write_middlebury_scene(root / "downloads" / "Cloth2", 555, 2, 40.0, original)
    piano = root / "downloads" / "Piano"
    _write_views(piano, 8, 24)
    for ours, theirs in (("left.png", "im0.png"), ("right.png", "im1.png")):
        (piano / ours).rename(piano / theirs)
    cv2.imwrite(str(piano / "disp0GT.pfm"), np.full((8, 24), 12.5, np.float32))
    cv2.imwrite(str(piano / "mask0nocc.png"), mask)
    lab = root / "lab-scans"
    scene_writer(lab / "one", "shared", max_disparity=8)
    (lab / "protocol.json").write_text(json.dumps({"scale": 4, "border": 1}))
    (root / "notes").mkdir()
    return root


def test_datasets_are_found_by_layout_with_their_conventions(datasets: Path, capsys):
    found = find_datasets(datasets)
    assert list(found) == [
        "downloads",
        "kitti2015",
        "lab-scans",
        "middlebury",
        "middlebury2005",
        "middlebury2006",
        "middlebury2014",
    ]
    scenes = {s.qualified_name: s for group in found.values() for s in group.values()}
    protocols = {name: (s.scale, s.border, s.non_occlusion) for name, s in scenes.items()}
    assert protocols == {
        "downloads/cloth2": (2.0, 0, "left-right"),  # 2005/2006 names: half size by its height
        "downloads/piano": (1.0, 0, "mask"),  # MiddEval3 names
        "kitti2015/000000": (256.0, 0, "none"),
        "lab-scans/one": (4.0, 1, "none"),  # the dataset's protocol.json
        "middlebury/tsukuba": (16.0, 18, "mask"),  # the known scene
        "middlebury2005/art": (3.0, 0, "left-right"),  # third size: 1110 / 370
        "middlebury2006/aloe": (2.0, 0, "left-right"),  # half size
        "middlebury2006/baby1": (1.0, 0, "left-right"),  # full size
        "middlebury2014/teddy": (1.0, 0, "mask"),  # PFM, not 2003's scale 4
    }
    ranges = {name: s.ground_truth_range() for name, s in scenes.items()}
    assert ranges["middlebury2005/art"] == 71  # 211 / 3 = 70.33 px
    assert ranges["middlebury2006/aloe"] == 51  # 101 / 2 = 50.5 px
    assert ranges["middlebury2006/baby1"] == 120
    assert ranges["kitti2015/000000"] == 41  # 10304 / 256 = 40.25 px
    assert ranges["middlebury2014/teddy"] == 34
    assert scenes["middlebury2014/teddy"].non_occluded().sum() == 8 * 20  # the 255s only
    assert scenes["downloads/piano"].non_occluded().sum() == 8 * 20
    assert (scenes["downloads/cloth2"].gt.name, scenes["downloads/cloth2"].gt_right.name) == (
        "disp1.png",
        "disp5.png",
    )
    # `qhsm datasets list` shows the same
    assert main(["datasets", "list", str(datasets), "--json"]) == 0
    listed = {row["name"]: row for row in json.loads(capsys.readouterr().out)}
    assert listed.keys() == scenes.keys()
    assert listed["middlebury2005/art"]["non_occlusion"] == "left-right"
    # one dataset folder, or one scene folder, is found the same way
    assert list(find_datasets(datasets / "middlebury2006")) == ["middlebury2006"]
    assert list(find_datasets(datasets / "middlebury2006" / "Aloe")["middlebury2006"]) == ["aloe"]


def test_select_scenes_names_them_by_dataset_and_gives_the_range(datasets: Path):
    chosen = select_scenes([datasets], ["aloe", "middlebury2005/Art"])
    assert [(s.name, s.max_disparity) for s in chosen] == [
        ("middlebury2006/aloe", 51),
        ("middlebury2005/art", 71),
    ]
    assert len(select_scenes([datasets])) == 9
    with pytest.raises(BenchError, match="not found"):
        select_scenes([datasets], ["cones"])
    with pytest.raises(BenchError, match="no such directory"):
        select_scenes([datasets / "nowhere"])


def test_the_development_scenes_get_the_provenance_conventions(middlebury_dir: Path):
    data = middlebury_dir.parent
    if not (data / "middlebury2005").is_dir() or not (data / "middlebury2006").is_dir():
        pytest.skip(f"the 2005/2006 development scenes are not in {data}")
    scenes = {s.name: s for s in select_scenes([data])}
    assert len(scenes) == 20
    assert {s.scale for n, s in scenes.items() if n.startswith("middlebury2005/")} == {3.0}
    assert {s.scale for n, s in scenes.items() if n.startswith("middlebury2006/")} == {2.0}
    # ranges: ceil of the GT maxima in PROVENANCE-2005-2006.md (Art 74.67, Bowling1 115.00 px)
    assert scenes["middlebury2005/art"].max_disparity == 75
    assert scenes["middlebury2006/bowling1"].max_disparity == 115
    assert scenes["middlebury/tsukuba"].max_disparity == 14
    # where both exist, the ground truth's left-right check agrees with the official mask
    for name in ("middlebury/venus", "middlebury/cones"):
        scene = scenes[name]
        official = scene.non_occluded()
        lr = confirmed_by_right_view(
            *(
                cv2.imread(str(path), cv2.IMREAD_UNCHANGED) / scene.scale
                for path in (scene.gt, scene.gt_right)
            )
        )
        evaluated = scene.mask("all")
        assert np.mean((lr == official)[evaluated]) > 0.985, name


# --- variants and the comparison ------------------------------------------------------------


def test_variants_are_named_config_changes():
    variant = parse_variant("rows=median:false,lr_tolerance:2,solver:sa,preset:paper")
    assert (variant.name, variant.solver, variant.preset) == ("rows", "sa", Preset.PAPER)
    assert variant.overrides == {"median": False, "lr_tolerance": 2}
    levels = '[{"downsample": 1, "candidates": 4}]'
    assert parse_variant(f"one=levels:{levels},median_size:3").overrides == {
        "levels": [{"downsample": 1, "candidates": 4}],
        "median_size": 3,
    }
    plain = parse_variant("default=")
    assert (plain.overrides, plain.solver, plain.preset) == ({}, "exact", Preset.ACCURATE)
    assert [v.name for v in named_variants(VARIANTS)] == list(VARIANTS)
    with pytest.raises(BenchError, match="medain"):
        parse_variant("typo=medain:false")
    with pytest.raises(BenchError, match="median_size"):
        parse_variant("bad=median_size:0")
    with pytest.raises(BenchError, match="NAME=KEY:VALUE"):
        parse_variant("median:false")
    with pytest.raises(BenchError, match="baseline"):
        parse_variant("sgbm=median:false")
    with pytest.raises(BenchError, match="unknown variant nosuch"):
        named_variants(["nosuch"])


def _run(scene: str, variant: str, nonocc: float | None, bpp: float = 50.0, **extra) -> Run:
    run = Run(scene, "generalisation", variant, "pipeline", "exact", "ok", bpp=bpp, rmse=1.0)
    if nonocc is not None:
        run.masks["nonocc"] = {"rmse": 1.0, "bpp": nonocc, "pixels": 10}
    for key, value in extra.items():
        setattr(run, key, value)
    return run


def test_compare_counts_wins_and_averages_over_the_scenes_both_ran():
    runs = [
        _run("a", "ours", 10.0),
        _run("a", "sgbm", 20.0),
        _run("b", "ours", 30.0),
        _run("b", "sgbm", 15.0),
        _run("c", "ours", 5.0),
        _run("c", "sgbm", 5.0),
        _run("kitti", "ours", None, bpp=8.0),  # no non-occlusion: every known pixel
        _run("kitti", "sgbm", None, bpp=4.0),
        _run("d", "ours", None, status="failed", reason="RuntimeError: boom"),
        _run("d", "sgbm", 1.0),
    ]
    (entry,) = compare(runs)
    assert [(r["scene"], r["result"]) for r in entry["rows"]] == [
        ("a", "win"),
        ("b", "loss"),
        ("c", "tie"),
        ("kitti", "loss"),
    ]
    assert (entry["wins"], entry["losses"], entry["ties"], entry["scenes"]) == (1, 2, 1, 4)
    assert entry["rows"][0]["ratio"] == pytest.approx(0.5)
    assert entry["mean"] == pytest.approx((10 + 30 + 5 + 8) / 4)
    assert entry["baseline_mean"] == pytest.approx((20 + 15 + 5 + 4) / 4)
    assert entry["ratio"] == pytest.approx(53 / 44)
    assert entry["missing"] == [{"scene": "d", "reason": "ours failed: RuntimeError: boom"}]


# --- end to end -----------------------------------------------------------------------------


@pytest.fixture
def small_datasets(tmp_path: Path, scene_writer) -> Path:
    """A scene with a nonocc mask, and one whose dataset gives the scale and which has both
    views' ground truth."""
    root = tmp_path / "data"
    scene_writer(root / "middlebury" / "plain", "shared", seed=1, masks=("nonocc",))
    scene = make_scene(32, 48, max_disparity=8, seed=2)
    folder = root / "lab" / "Toy"
    folder.mkdir(parents=True)
    (root / "lab" / "protocol.json").write_text(json.dumps({"scale": 8}))
    for name, view in (("left.png", scene.left), ("right.png", scene.right)):
        cv2.imwrite(str(folder / name), np.rint(view * 255).astype(np.uint8))
    for name, truth in (("gt_left.png", scene.disparity), ("gt_right.png", scene.right_disparity)):
        cv2.imwrite(str(folder / name), np.rint(truth * 8).astype(np.uint8))
    return root


def test_one_run_scores_every_variant_against_sgbm(small_datasets: Path, tmp_path: Path):
    variants = [*named_variants(["accurate"]), parse_variant("no-median=median:false")]
    options = Options([small_datasets], tmp_path / "one", variants, processes=1)
    data = run_benchmark(options, command=["test"], log=lambda line: None)
    assert sorted(data["scenes"]) == ["lab/toy", "middlebury/plain"]
    toy = data["scenes"]["lab/toy"]
    stored_top = cv2.imread(str(small_datasets / "lab/Toy/gt_left.png"), 0).max()
    assert (toy["scale"], toy["non_occlusion"]) == (8.0, "left-right")
    assert toy["max_disparity"] == math.ceil(stored_top / 8)
    runs = {(r["scene"], r["variant"]): r for r in data["runs"]}
    assert len(runs) == 6 and {r["status"] for r in runs.values()} == {"ok"}
    plain = runs["middlebury/plain", "accurate"]
    assert plain["config"]["max_disparity"] == math.ceil(
        cv2.imread(str(small_datasets / "middlebury/plain/gt_left.png"), 0).max()
    )
    assert runs["lab/toy", "sgbm"]["info"]["num_disparities"] == 16
    for entry in data["comparison"]:
        assert entry["scenes"] == 2 and entry["wins"] + entry["losses"] + entry["ties"] == 2
        for row in entry["rows"]:
            ours, theirs = runs[row["scene"], entry["variant"]], runs[row["scene"], "sgbm"]
            assert row["ours"] == ours["masks"]["nonocc"]["bpp"]
            assert row["baseline"] == theirs["masks"]["nonocc"]["bpp"]
            assert (row["rmse_all"], row["bpp_all"]) == (ours["rmse"], ours["bpp"])
    assert (tmp_path / "one" / "lab" / "toy" / "generalisation-sgbm.pfm").is_file()
    assert json.loads((tmp_path / "one" / "results.json").read_text()) == data
    report = (tmp_path / "one" / "results.md").read_text()
    assert report == markdown(data)
    first = data["comparison"][0]
    assert f"fewer bad pixels than SGBM on {first['wins']} of 2 scenes" in report

    # side by side in two processes: the same maps, hence the same figures
    options.processes, options.out = 2, tmp_path / "two"
    pooled = run_benchmark(options, log=lambda line: None)
    figures = lambda results: [  # noqa: E731
        {**row, "seconds": None} for entry in results["comparison"] for row in entry["rows"]
    ]
    assert figures(pooled) == figures(data)


def test_the_command_reports_bad_arguments(small_datasets: Path, tmp_path: Path, capsys):
    import importlib.util

    path = Path(__file__).resolve().parents[2] / "benchmarks" / "generalisation.py"
    spec = importlib.util.spec_from_file_location("generalisation_command", path)
    assert spec is not None and spec.loader is not None
    command = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(command)
    base = ["--data", str(small_datasets), "--out", str(tmp_path), "--processes", "1"]
    assert command.main([*base, "--variant", "oops"]) == 2
    assert "NAME=KEY:VALUE" in capsys.readouterr().err
    assert command.main([*base, "--variants", "nosuch"]) == 2
    assert "unknown variant nosuch" in capsys.readouterr().err
    assert command.main([*base, "--scenes", "plain", "--variants", ""]) == 2
    assert "no variant" in capsys.readouterr().err
    assert command.main([*base, "--scenes", "plain"]) == 0
    assert "| middlebury/plain |" in capsys.readouterr().out


def test_an_unreadable_scene_fails_its_runs_not_the_benchmark(small_datasets: Path, tmp_path):
    (small_datasets / "lab" / "Toy" / "right.png").write_bytes(b"not a png")
    options = Options([small_datasets], tmp_path, named_variants(["accurate"]), processes=1)
    data = run_benchmark(options, log=lambda line: None)
    broken = [r for r in data["runs"] if r["scene"] == "lab/toy"]
    assert {r["status"] for r in broken} == {"failed"}
    assert all("loading the scene" in r["reason"] for r in broken)
    (entry,) = data["comparison"]
    assert [row["scene"] for row in entry["rows"]] == ["middlebury/plain"]
    assert [gone["scene"] for gone in entry["missing"]] == ["lab/toy"]
    assert "lab/toy: not compared (accurate failed: loading the scene" in markdown(data)
