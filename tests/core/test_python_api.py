"""The documented Python API: README's examples run as written, results carry provenance."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

import qhsm
from api.client import Client
from shared.cli import main
from shared.config import MatchConfig
from shared.images import load_pair, load_view

README = Path(__file__).resolve().parents[2] / "README.md"


def examples() -> tuple[list[str], list[str]]:
    """The Python API section's ```python blocks: (run by this test, marked notest)."""
    text = README.read_text()
    section = text[text.index("## Python API") :]
    section = section[: section.index("\n## ", 1)]
    blocks = re.findall(r"```python( notest)?\n(.*?)```", section, re.S)
    return [code for flag, code in blocks if not flag], [code for flag, code in blocks if flag]


@pytest.fixture
def scene_folder(tmp_path, scene, monkeypatch):
    colour = np.dstack([scene.left, scene.left * 0.8, scene.left * 0.6])
    cv2.imwrite(str(tmp_path / "left.png"), (colour * 255).round().astype(np.uint8))
    right = np.dstack([scene.right, scene.right * 0.8, scene.right * 0.6])
    cv2.imwrite(str(tmp_path / "right.png"), (right * 255).round().astype(np.uint8))
    body = np.ascontiguousarray(scene.disparity[::-1], "<f4").tobytes()
    height, width = scene.disparity.shape
    (tmp_path / "gt.pfm").write_bytes(f"Pf\n{width} {height}\n-0.003922\n".encode() + body)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_readme_examples_run(scene_folder, capsys):
    runnable, _ = examples()
    assert len(runnable) >= 2
    for code in runnable:
        exec(compile(code, str(README), "exec"), {})
    lines = capsys.readouterr().out.splitlines()
    version, preset, solver = lines[0].split()
    assert (version, preset, solver) == (qhsm.__version__, "accurate", "exact")
    rmse = float(re.search(r"RMSE ([0-9.]+) px", lines[1]).group(1))
    assert rmse < 2  # gt.pfm read in pixels despite its header scale
    assert lines[2].startswith("True")
    assert (scene_folder / "disparity.pfm").exists()


def test_the_client_example_uses_the_client_as_it_is():
    _, documented = examples()
    assert documented and qhsm.Client is Client
    for method in re.findall(r"client\.(\w+)\(", "".join(documented)):
        assert callable(getattr(Client, method)), method


def test_load_pair_is_the_cli_reading_in_colour(scene_folder):
    left, _ = qhsm.load_pair("left.png", "right.png")
    assert left.ndim == 3 and np.array_equal(left, load_view("left.png"))
    assert qhsm.load_pair is load_pair and qhsm.MatchConfig is MatchConfig


def test_api_and_cli_give_the_same_map_and_the_same_provenance(scene_folder, capsys):
    result = qhsm.match("left.png", "right.png", max_disparity=16, preset="paper")
    command = ["match", "left.png", "right.png", "-o", "d.pfm", "--max-disparity", "16"]
    assert main([*command, "--preset", "paper", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    cli_map = qhsm.evaluate("d.pfm", result.disparity)
    assert cli_map["rmse"] == 0
    assert summary["provenance"] == result.provenance
    assert result.provenance["config"]["preset"] == "paper"
    assert (
        result.provenance["config"]["levels"]
        == MatchConfig(preset="paper").model_dump(mode="json")["levels"]
    )
    sidecar = json.loads(Path(summary["sidecar"]).read_text())
    assert sidecar["provenance"]["version"] == qhsm.__version__ and sidecar["output"] == "d.pfm"


def test_version_option():
    completed = subprocess.run(
        [sys.executable, "-c", "from shared.cli import main; main(['--version'])"],
        capture_output=True,
        text=True,
    )
    assert completed.stdout.strip() == f"qhsm {qhsm.__version__}"


def test_the_installed_version_is_the_one_written_in_shared():
    # pyproject.toml reads shared.__version__ at install: the distribution says the same
    from importlib.metadata import version

    import shared

    assert version("qhsm") == shared.__version__ == qhsm.__version__


def test_the_console_script_returns_mains_status_with_its_objects_frozen(monkeypatch):
    import gc

    from shared import cli

    monkeypatch.setattr(cli, "main", lambda: 7)
    try:
        assert cli.console() == 7
        assert gc.get_freeze_count() > 0  # the exit's collection skips them
    finally:
        gc.unfreeze()


def test_validity_and_confidence_maps_are_written_beside_the_disparity(scene_folder, capsys):
    from shared.images import load_disparity, load_mask

    command = ["match", "left.png", "right.png", "-o", "d.png", "--max-disparity", "16", "--json"]
    assert main(command) == 0
    maps = json.loads(capsys.readouterr().out)["maps"]
    assert maps == {
        "validity": "d.valid.png",
        "confidence": "d.confidence.pfm",
        "provenance": "d.provenance.png",
    }
    valid, confidence = load_mask(maps["validity"]), load_disparity(maps["confidence"])
    assert 0.5 < valid.mean() < 1  # occlusions fail the left-right check
    assert confidence.min() >= 0 and confidence.max() <= 1 and (confidence[~valid] == 0).all()
    # confident pixels are right more often than the others
    truth = load_disparity("gt.pfm")
    errors = np.abs(load_disparity("d.png") - truth)
    sure = confidence > np.median(confidence[valid])
    assert (errors[sure] > 1).mean() < (errors[~sure] > 1).mean()
