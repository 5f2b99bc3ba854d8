"""The `qhsm` command as a user runs it (installed console script)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from shared.cli import build_parser, main
from shared.cli_options import config_from_args
from shared.images import load_disparity
from shared.inference import level_bundles
from shared.metrics import evaluate
from shared.pipeline import match_views, plan_run, prepare_level


@pytest.fixture(scope="module")
def pair(tmp_path_factory, scene):
    folder = tmp_path_factory.mktemp("pair")
    cv2.imwrite(str(folder / "left.png"), (scene.left * 255).round().astype(np.uint8))
    cv2.imwrite(str(folder / "right.png"), (scene.right * 255).round().astype(np.uint8))
    cv2.imwrite(str(folder / "gt.png"), (scene.disparity * 4).round().astype(np.uint16))
    return folder


def test_console_script_matches_and_reports_json(pair, tmp_path, scene):
    exe = shutil.which("qhsm")
    assert exe, "the qhsm console script is not installed (pip install -e .)"
    out = tmp_path / "d.pfm"
    completed = subprocess.run(
        [
            exe,
            "match",
            str(pair / "left.png"),
            str(pair / "right.png"),
            "-o",
            str(out),
            "--max-disparity",
            "16",
            "--json",
            "--preview",
            str(tmp_path / "p.png"),
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    summary = json.loads(completed.stdout)
    assert [level["bin_width"] for level in summary["levels"]] == [4, 2, 1]
    range_used = summary["disparity_range"]
    assert {key: range_used[key] for key in ("max_disparity", "source", "note", "warning")} == {
        "max_disparity": 16,
        "source": "given",
        "note": "",
        "warning": "",  # the views were checked, and are in order
    }
    assert range_used["confirmed"] > 0.5
    assert all(level["energy"] > 0 and level["seconds"] > 0 for level in summary["levels"])
    assert evaluate(load_disparity(out), scene.disparity).bpp < 5
    assert (tmp_path / "p.png").stat().st_size > 0


def match(pair, out, *options: str) -> int:
    """``qhsm match`` of the test pair with a 16 px range."""
    left, right = str(pair / "left.png"), str(pair / "right.png")
    return main(["match", left, right, "-o", str(out), "--max-disparity", "16", *options])


@pytest.mark.parametrize("suffix", [".png", ".npy"])
def test_output_format_follows_the_extension(pair, tmp_path, suffix):
    out = tmp_path / f"d{suffix}"
    assert match(pair, out, "--no-bilateral") == 0
    disparity = load_disparity(out)
    assert disparity.shape == (96, 128) and disparity.max() > 8


def test_eval_prints_rmse_and_bpp(pair, tmp_path, capsys):
    out = tmp_path / "d.pfm"
    match(pair, out)
    capsys.readouterr()
    command = ["eval", str(out), str(pair / "gt.png"), "--scale", "4", "--border", "2"]
    assert main([*command, "--json"]) == 0
    scores = json.loads(capsys.readouterr().out)
    assert set(scores) >= {"rmse", "bpp"} and scores["bpp"] < 15


def test_user_errors_are_one_line_messages(pair, tmp_path, capsys):
    left, right, out = str(pair / "left.png"), str(pair / "right.png"), str(tmp_path / "d.pfm")
    cases = [
        ([left, str(tmp_path / "none.png"), "-o", out], "none.png: no such file"),
        ([left, right, "-o", out, "--solver", "nope"], "unknown solver 'nope'"),
        (
            [left, right, "-o", out, "--inference", "rows", "--bundle-height", "2"],
            "single-row bundles",
        ),
        ([left, right, "-o", str(tmp_path / "d.jpg")], ".pfm, .png or .npy"),
        ([left, right, "-o", out, "--bundle-width", "64"], "exact solves whole rows"),
        ([left, right, "-o", out, "--solver", "sa", "--bundle-width", "auto"], "in pixels"),
        ([left, right, "-o", out, "--bundle-width", "20", "--bundle-margin", "10"], "half"),
    ]
    for arguments, message in cases:
        assert main(["match", *arguments]) == 1
        error = capsys.readouterr().err
        assert message in error and error.count("\n") == 1, error


def test_preset_and_auto_range_from_the_command_line(pair, tmp_path, capsys):
    out = str(tmp_path / "d.npy")
    base = ["match", str(pair / "left.png"), str(pair / "right.png"), "-o", out, "--json"]
    assert main([*base, "--preset", "paper", "--max-disparity", "16"]) == 0
    paper = json.loads(capsys.readouterr().out)
    assert [level["downsample"] for level in paper["levels"]] == [4, 2, 1]
    assert main(base) == 0  # default: accurate, auto range
    accurate = json.loads(capsys.readouterr().out)
    assert accurate["disparity_range"]["source"] == "auto"
    assert 16 <= accurate["disparity_range"]["max_disparity"] <= 28
    with pytest.raises(SystemExit):
        main([*base, "--max-disparity", "wide"])
    assert "expected auto or an integer" in capsys.readouterr().err


def test_bundle_width_from_the_command_line(pair, scene):
    """--bundle-width and --bundle-margin reach the level's bundles (planned, not solved) when
    every tile is sent (``--no-certify-tiles``; the residual design sends 4x4 tiles instead)."""
    argv = ["match", str(pair / "left.png"), str(pair / "right.png"), "-o", "d.npy"]
    argv += ["--max-disparity", "16", "--solver", "sa", "--param", "num_reads=2"]
    argv += ["--no-certify-tiles", "--coarse-grid", "1"]  # the coarse level on the full grid
    config = config_from_args(build_parser().parse_args([*argv, "--bundle-width", "48",
                                                         "--bundle-margin", "8"]))  # fmt: skip
    left, right = match_views(scene.left, scene.right, config)
    _, plans = plan_run(left, right, config)
    assert [plan.downsample for plan in plans] == [1, 1, 1]  # every level at full resolution
    bundles = level_bundles(prepare_level(left, right, config, plans[0]), config)
    per_row = 3  # 128 px: segments at 0, 40 and 80 (the last one shifted left)
    assert len(bundles) == 2 * (96 // 3) * per_row  # both views, tiles of 3 rows
    assert sorted({bundle.shape[1] for bundle in bundles}) == [48]


def test_ctrl_c_in_match_is_one_line_and_leaves_no_process(pair, tmp_path, ctrl_c):
    exe = shutil.which("qhsm")
    assert exe, "the qhsm console script is not installed (pip install -e .)"
    left, right = str(pair / "left.png"), str(pair / "right.png")
    command = [exe, "match", left, right, "-o", str(tmp_path / "d.pfm"), "--solver", "sa"]
    # rows inference: many small bundles, so the run is surely under way when Ctrl-C comes
    options = ["--processes", "2", "--max-disparity", "16", "--inference", "rows"]
    got = ctrl_c([*command, *options], when="bundles")
    assert got.returncode == 130
    assert "Traceback" not in got.stderr and "KeyboardInterrupt" not in got.stderr
    assert got.last_line == "qhsm: interrupted"
    assert not got.left_processes  # the pool's children are gone too
    assert not (tmp_path / "d.pfm").exists()


def test_ctrl_c_inside_generated_code_still_exits_130(tmp_path):
    """A Ctrl-C that lands in code run by ``exec`` from a string (in CI: a dataclass's generated
    ``__init__`` while ``qhsm submit --wait`` imported a module lazily; here a plain ``exec``) and
    is answered must not turn ``python -m``'s status into a death by SIGINT (CPython 3.11-3.13
    remember it)."""
    (tmp_path / "answered.py").write_text(
        "import sys\n"
        "from shared.exit_codes import interrupted\n"
        "def main():\n"
        "    try:\n"
        "        exec('raise KeyboardInterrupt')\n"
        "    except KeyboardInterrupt:\n"
        "        print('qhsm: interrupted', file=sys.stderr)\n"
        "        return interrupted()\n"
        "sys.exit(main())\n"
    )
    root = Path(__file__).resolve().parents[2]
    got = subprocess.run(
        [sys.executable, "-m", "answered"],
        cwd=tmp_path,
        env={"PYTHONPATH": f"{tmp_path}:{root}"},
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert (got.returncode, got.stderr) == (130, "qhsm: interrupted\n")


def test_a_closed_stdout_ends_quietly(tmp_path):
    """`qhsm solvers | head -0`: the reader is gone before anything is written."""
    exe = shutil.which("qhsm")
    assert exe, "the qhsm console script is not installed (pip install -e .)"
    process = subprocess.Popen([exe, "solvers"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert process.stdout is not None and process.stderr is not None
    process.stdout.close()
    error = process.stderr.read().decode()
    assert process.wait(60) == 141, error
    assert error == ""


def test_swapped_views_stop_the_run_unless_forced(pair, tmp_path, capsys):
    left, right, out = str(pair / "left.png"), str(pair / "right.png"), str(tmp_path / "d.pfm")
    assert main(["match", right, left, "-o", out, "--max-disparity", "16"]) == 1
    error = capsys.readouterr().err
    assert "qhsm: the views look swapped" in error and "stopped before the run" in error
    assert "level 1/3" not in error and not Path(out).exists()


def test_swapped_views_forced_are_one_warning_line_before_the_run(pair, tmp_path, capsys):
    left, right, out = str(pair / "left.png"), str(pair / "right.png"), str(tmp_path / "d.pfm")
    assert main(["match", right, left, "-o", out, "--max-disparity", "16", "--force"]) == 0
    error = capsys.readouterr().err
    [warning] = [line for line in error.splitlines() if "warning" in line]
    assert warning.startswith("qhsm: warning: the views look swapped: ")
    assert error.index(warning) < error.index("level 1/3")  # before any work


@pytest.mark.skipif(sys.platform != "linux", reason="XDG_DATA_HOME is the Linux convention")
def test_the_data_directory_does_not_depend_on_the_current_directory(tmp_path, monkeypatch):
    from shared.config import get_settings

    monkeypatch.delenv("QHSM_DATA_DIR")
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))  # where platformdirs looks first
    seen = set()
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        monkeypatch.chdir(tmp_path / folder)
        seen.add(get_settings().data_dir)
    assert seen == {tmp_path / "xdg" / "qhsm"}
