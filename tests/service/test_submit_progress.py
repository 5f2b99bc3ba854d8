"""`qhsm submit` against a real server and workers (issue 10, item 17): progress on stderr in
every mode, JSON alone on stdout with --json, and --wait without -o says where it wrote."""

from __future__ import annotations

import json
import os

import harness
import pytest

from api.serve import ApiThread, free_port
from shared.cli import main
from shared.synthetic import make_scene

pytestmark = pytest.mark.service


@pytest.fixture(scope="module")
def api_url(settings, workers, admin_key):
    api = ApiThread(settings.model_copy(update={"api_port": free_port()})).start()
    saved = os.environ.get("QHSM_API_KEY")
    os.environ["QHSM_API_KEY"] = admin_key
    yield api.url
    api.stop()
    if saved is None:
        os.environ.pop("QHSM_API_KEY", None)
    else:
        os.environ["QHSM_API_KEY"] = saved


@pytest.fixture
def images(tmp_path, monkeypatch):
    scene = make_scene(16, 24, max_disparity=4, seed=5)
    (tmp_path / "l.png").write_bytes(harness.png(scene.left))
    (tmp_path / "r.png").write_bytes(harness.png(scene.right))
    monkeypatch.chdir(tmp_path)
    return ["l.png", "r.png", "--max-disparity", "4"]


def test_json_wait_prints_progress_to_stderr_and_only_json_to_stdout(api_url, images, capsys):
    assert main(["submit", *images, "--url", api_url, "--json", "--wait"]) == 0
    captured = capsys.readouterr()
    status = json.loads(captured.out)  # nothing else on stdout
    assert status["state"] == "succeeded"
    levels = status["progress"]["levels"]
    assert f"succeeded level {levels}/{levels}" in " ".join(captured.err.split())  # the bar
    written = os.path.join(os.getcwd(), f"{status['id']}.pfm")
    assert status["output"] == written and os.path.isfile(written)
    assert f"wrote {written} (no -o given: named after the job, in this directory)" in captured.err


def test_wait_without_output_says_where_it_wrote(api_url, images, capsys):
    assert main(["submit", *images, "--url", api_url, "--wait"]) == 0
    captured = capsys.readouterr()
    assert "bundles" in captured.err
    [line] = captured.out.splitlines()
    assert line.startswith(f"wrote {os.getcwd()}{os.sep}") and "no -o given" in line


def test_json_without_wait_is_json(api_url, images, capsys):
    assert main(["submit", *images, "--url", api_url, "--json"]) == 0
    job = json.loads(capsys.readouterr().out)
    assert job["state"] == "queued" and job["url"].endswith(f"/v1/jobs/{job['id']}")
