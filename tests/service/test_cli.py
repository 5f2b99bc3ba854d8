"""`qhsm submit` against a real HTTP server (uvicorn) and real workers; the embedded Redis."""

from __future__ import annotations

import json
import os
import re
import sys

import harness
import numpy as np
import pytest
import redis

from api.server import ApiThread
from shared.cli import main
from shared.config import MatchConfig
from shared.images import load_pair
from shared.pipeline import run_pipeline
from shared.solvers.registry import resolve
from shared.synthetic import make_scene
from workers.embedded_redis import EmbeddedRedis, free_port

pytestmark = pytest.mark.service


@pytest.fixture(scope="module")
def api_url(settings, workers, admin_key):
    """A real HTTP server; `qhsm submit` finds the key in QHSM_API_KEY."""
    api = ApiThread(settings.model_copy(update={"api_port": free_port()})).start()
    saved = os.environ.get("QHSM_API_KEY")
    os.environ["QHSM_API_KEY"] = admin_key
    yield api.url
    api.stop()
    if saved is None:
        os.environ.pop("QHSM_API_KEY", None)
    else:
        os.environ["QHSM_API_KEY"] = saved


def test_submit_waits_and_downloads_the_in_process_result(api_url, tmp_path, capsys):
    scene = make_scene(32, 48, max_disparity=8, seed=9)
    left, right = tmp_path / "left.png", tmp_path / "right.png"
    left.write_bytes(harness.png(scene.left))
    right.write_bytes(harness.png(scene.right))
    truth = tmp_path / "truth.npy"
    np.save(truth, scene.disparity)
    out = tmp_path / "out.npy"
    argv = [
        "submit", str(left), str(right), "--url", api_url, "--max-disparity", "8", "--seed", "4",
        "-o", str(out), "--preview", str(tmp_path / "preview.png"), "--ground-truth", str(truth),
    ]  # fmt: skip
    assert main(argv) == 0
    assert "RMSE" in capsys.readouterr().out
    expected = run_pipeline(*load_pair(left, right), MatchConfig(max_disparity=8, seed=4))
    assert np.array_equal(np.load(out), expected.disparity)
    assert (tmp_path / "preview.png").read_bytes().startswith(b"\x89PNG")


def test_bench_http_runner_and_the_key_it_sends(api_url, tmp_path, capsys):
    """`qhsm bench --url`'s runner (entry point qhsm.runners:http) sends QHSM_API_KEY; a wrong
    key is refused with a hint."""
    from importlib.metadata import entry_points

    [runner] = entry_points(group="qhsm.runners", name="http")
    scene = make_scene(16, 24, max_disparity=6, seed=2)
    left, right = tmp_path / "left.png", tmp_path / "right.png"
    left.write_bytes(harness.png(scene.left))
    right.write_bytes(harness.png(scene.right))
    config = MatchConfig(max_disparity=6, seed=1)
    disparity, levels = runner.load()(left, right, config, api_url)
    expected = run_pipeline(*load_pair(left, right), config)
    assert np.array_equal(disparity, expected.disparity)
    assert len(levels) == len(expected.levels) == 1  # max 6 px: one level of 1-px bins
    argv = ["submit", str(left), str(right), "--url", api_url, "--key", "qhsm_0_wrong"]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert "401" in err and "QHSM_API_KEY" in err


def test_submit_reports_refusals_and_unreachable_servers(api_url, tmp_path, capsys):
    image = tmp_path / "image.png"
    image.write_bytes(harness.png(make_scene(16, 16, max_disparity=4).left))
    assert main(["submit", str(image), str(image), "--url", api_url, "--solver", "nope"]) == 1
    assert "unknown solver 'nope'" in capsys.readouterr().err
    closed = f"http://127.0.0.1:{free_port()}"
    assert main(["submit", str(image), str(image), "--url", closed]) == 1
    assert "is `qhsm serve` running?" in capsys.readouterr().err


def test_embedded_redis_persists_to_its_folder(tmp_path):
    server = EmbeddedRedis(tmp_path / "redis").start()
    try:
        client = redis.Redis.from_url(server.url)
        client.set("key", "value")
        assert client.get("key") == b"value"
        assert (tmp_path / "redis").is_dir()
    finally:
        server.stop()
    with pytest.raises(redis.ConnectionError):
        redis.Redis.from_url(server.url, socket_connect_timeout=0.5).ping()


# --- issue 10, item 17: progress on stderr in every mode, JSON alone on stdout with --json,
# and --wait without -o says where it wrote


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
    assert f"succeeded: level {levels}/{levels}" in captured.err  # the progress
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


def test_estimate_asks_the_service_and_agrees_with_the_local_model(api_url, tmp_path, capsys):
    import json

    from shared.solvers.meters import qpu_time

    # a scene whose bundles roof duality does not all solve on the host (seed 9's it does, with
    # the coarse levels' prior): some QPU time to estimate
    scene = make_scene(24, 32, max_disparity=8, seed=1)
    left, right = tmp_path / "left.png", tmp_path / "right.png"
    left.write_bytes(harness.png(scene.left))
    right.write_bytes(harness.png(scene.right))
    options = ["--solver", "qpu", "--encoding", "domain-wall", "--max-disparity", "8"]
    assert main(["estimate", str(left), str(right), *options, "--url", api_url, "--json"]) == 0
    remote = json.loads(capsys.readouterr().out)
    config = MatchConfig(solver="qpu", encoding="domain-wall", max_disparity=8)
    expected = qpu_time.job_seconds(resolve(config), (24, 32), 8)
    # what roof duality solves on the host is not estimated (the model alone: every bundle)
    assert 0 < remote["seconds"] <= expected.seconds * (1 + 1e-9) and remote["metered"]
    assert remote["bundles"] == expected.bundles and remote["fits"] is True
    assert main(["estimate", str(left), str(right), *options, "--url", api_url]) == 0
    text = capsys.readouterr().out
    assert f"qpu: {remote['seconds']:.2f} s of QPU access time" in text
    assert "qubits (assumed)" in text and "fits" in text
    assert main(["estimate", str(left), str(right), *options, "--local", "--json"]) == 0
    local = json.loads(capsys.readouterr().out)
    assert local["seconds"] == pytest.approx(remote["seconds"]) and "fits" not in local


# --- issue 22: wait, cancel, Ctrl-C, labels and warnings


def test_submit_says_how_to_follow_and_wait_and_cancel_follow(api_url, images, capsys):
    assert main(["submit", *images, "--url", api_url, "--label", "first pair"]) == 0
    captured = capsys.readouterr()
    job_id = captured.out.split()[0]
    assert f"`qhsm wait {job_id} --url {api_url}`" in captured.err
    assert f"`qhsm cancel {job_id} --url {api_url}`" in captured.err
    assert main(["wait", job_id, "--url", api_url, "-o", "out.npy", "--json"]) == 0
    status = json.loads(capsys.readouterr().out)
    assert status["state"] == "succeeded" and status["label"] == "first pair"
    assert status["files"] == ["l.png", "r.png"] and os.path.isfile("out.npy")
    assert main(["cancel", job_id, "--url", api_url]) == 1  # finished: nothing to cancel
    assert "already succeeded" in capsys.readouterr().err


def test_ctrl_c_leaves_the_job_running_and_says_how_to_cancel_or_wait(
    api_url, images, ctrl_c, capsys, tmp_path
):
    # a pair with many bundles: the job must outlast the CLI's start and its answer to Ctrl-C
    scene = make_scene(96, 48, max_disparity=4, seed=5)
    (tmp_path / "long-l.png").write_bytes(harness.png(scene.left))
    (tmp_path / "long-r.png").write_bytes(harness.png(scene.right))
    pair = ["long-l.png", "long-r.png", *images[2:]]
    command = [sys.executable, "-m", "shared.cli", "submit", *pair, "--url", api_url]
    got = ctrl_c([*command, "--solver", "fake-slow", "--wait"], when="job ")
    assert got.returncode == 130 and "Traceback" not in got.stderr
    job_id = got.stderr.split("job ", 1)[1].split()[0]
    assert re.match(
        f"qhsm: interrupted; job {job_id} is still (queued|running) on the service: ", got.last_line
    )
    assert f"`qhsm cancel {job_id} --url {api_url}`" in got.last_line
    assert f"`qhsm wait {job_id} --url {api_url}`" in got.last_line
    assert main(["cancel", job_id, "--url", api_url]) == 0
    assert capsys.readouterr().out.strip() == f"job {job_id} cancelled"


def test_swapped_views_are_a_warning_on_stderr(api_url, images, capsys):
    swapped = [images[1], images[0], *images[2:]]
    assert main(["submit", *swapped, "--url", api_url]) == 0
    error = capsys.readouterr().err
    assert "qhsm: warning: the views look swapped" in error and "left view first" in error
