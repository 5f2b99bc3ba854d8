"""`qhsm bench` end to end on a tiny synthetic dataset laid out like Middlebury."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from shared import bench
from shared.bench import BenchOptions, RunOutput, parse_solver_params, run_bench, scene_runners
from shared.bench.report import EXTRA_COLUMNS, fmt
from shared.cli import main
from shared.pipeline import run_pipeline


@pytest.fixture
def bench_result(tiny_dataset: Path, tmp_path: Path) -> tuple[dict, Path, str]:
    out = tmp_path / "out"
    argv = ["bench", str(tiny_dataset), "--out", str(out), "--solvers", "exact,nosuch"]
    assert main(argv) == 0
    results = json.loads((out / "results.json").read_text())
    return results, out, (out / "results.md").read_text()


def test_bench_runs_every_experiment_on_every_scene(bench_result):
    results, out, _ = bench_result
    runs = results["runs"]
    expected = {
        ("solvers", "exact"),
        ("solvers", "nosuch"),
        *(("accurate", name) for name in bench.ACCURATE_ABLATIONS),
        *(("ablations", name) for name in bench.ABLATIONS),
        ("baselines", "heidari"),
        ("baselines", "sgbm"),
    }
    for scene in ("tsukuba", "cones"):
        assert {(r["experiment"], r["variant"]) for r in runs if r["scene"] == scene} == expected
    skipped = [r for r in runs if r["status"] != "ok"]
    assert {r["variant"] for r in skipped} == {"nosuch"}
    assert all("unknown solver" in r["reason"] for r in skipped)
    for run in runs:
        if run["status"] != "ok":
            continue
        assert 0 <= run["bpp"] <= 100 and run["rmse"] >= 0 and run["seconds"] > 0
        assert run["rmse"] < 4  # a real disparity map, not noise (disparities go up to 8)
        for key in ("preview", "disparity", "error_map"):
            assert (out / run["files"][key]).is_file()
        preview = cv2.imread(str(out / run["files"]["preview"]))
        assert preview.shape[:2] == (32, 48)
    assert results["scenes"]["tsukuba"] == {
        "dataset": "data",
        "layout": "middlebury2001-tsukuba",
        "scale": 16.0,
        "border": 2,
        "max_disparity": 8,
        "max_disparity_source": "the scene's protocol.json",  # said, not assumed
        "non_occlusion": "mask",
        "masks": ["all", "disc", "nonocc"],
    }


def _cones(dataset: Path, out: Path, **changes) -> BenchOptions:
    """Bench options for the tiny dataset's ``cones`` scene alone."""
    return BenchOptions(dataset=dataset, out=out, scenes=["cones"], **changes)


def _configs(results: dict, experiment: str, scene: str = "cones") -> dict[str, dict]:
    """Each variant's pipeline configuration in ``experiment`` on ``scene``."""
    return {
        r["variant"]: r["config"]
        for r in results["runs"]
        if r["experiment"] == experiment and r["scene"] == scene
    }


def test_ablations_change_what_they_claim(bench_result):
    results, _, _ = bench_result
    configs = _configs(results, "ablations")
    assert configs["no-regularizer"]["regularizer"] == "none"
    assert configs["linear-regularizer"]["regularizer"] == "linear"
    assert not configs["no-bilateral"]["bilateral"] and configs["no-bilateral"]["median"]
    assert not configs["no-median-no-bilateral"]["median"]
    assert configs["full"] == next(
        r["config"]
        for r in results["runs"]
        if (r["experiment"], r["variant"], r["scene"]) == ("solvers", "exact", "cones")
    )


def test_accurate_ablations_switch_one_step_each(bench_result):
    results, _, _ = bench_result
    configs = _configs(results, "accurate")
    full = configs["accurate"]
    assert full["preset"] == "accurate" and full["lr_check"] and full["weighted_median"]
    changed = {
        name: {k for k in full if config[k] != full[k]}
        for name, config in configs.items()
        if name != "accurate"
    }
    assert changed == {
        "no-lr-check": {"lr_check"},
        "no-weighted-median": {"weighted_median"},
        "image-pyramid": {"pyramid", "levels"},
        "squared-difference": {"data_term"},
        "ad-census": {"data_term"},
        "one-slope": {"levels"},
        "rows": {"inference", "bundle_height"},  # rows take single-row bundles by default
    }


def test_table_and_json_carry_every_figure(bench_result):
    results, _, table = bench_result
    rows = {line for line in table.splitlines() if line.startswith("| ")}
    for run in results["runs"]:
        row = next(r for r in rows if r.startswith(f"| {run['scene']} | {run['variant']} |"))
        cells = [c.strip() for c in row.strip("|").split("|")]
        nonocc = run["masks"].get("nonocc", {})
        assert cells[2:8] == [
            fmt(run["rmse"]),
            fmt(run["bpp"]),
            fmt(nonocc.get("rmse")),
            fmt(nonocc.get("bpp")),
            fmt(run["masks"].get("disc", {}).get("bpp")),
            fmt(run["seconds"]),
        ]
        metrics = run["metrics"]
        assert cells[10:15] == [fmt(metrics.get(key)) for key in EXTRA_COLUMNS]
    for average in results["averages"]:
        ok = [
            r
            for r in results["runs"]
            if (r["experiment"], r["variant"]) == (average["experiment"], average["variant"])
            and r["status"] == "ok"
        ]
        assert average["rmse"] == pytest.approx(np.mean([r["rmse"] for r in ok]))
        assert average["seconds"] == pytest.approx(np.mean([r["seconds"] for r in ok]))
        assert (
            f"| **average** | {average['variant']} | {fmt(average['rmse'])} | "
            f"{fmt(average['bpp'])} |" in table
        )
    # the paper's Gurobi figures sit beside the exact row of the scene named tsukuba only
    exact = next(r for r in rows if r.startswith("| tsukuba | exact |"))
    assert "| 1.53 | 12.93 |" in exact
    assert "| n/a | n/a |" in next(r for r in rows if r.startswith("| cones | exact |"))


def test_solver_params_are_routed_per_solver():
    assert parse_solver_params(["sa:num_reads=5", "seed_like=3", "gurobi:mode=fast"]) == {
        "sa": {"num_reads": 5},
        "*": {"seed_like": 3},
        "gurobi": {"mode": "fast"},
    }
    with pytest.raises(ValueError, match="KEY=VALUE"):
        parse_solver_params(["oops"])


def test_url_runs_go_through_the_registered_runner(tiny_dataset, tmp_path, monkeypatch):
    calls = []

    def fake_runner(left, right, config, url):
        from shared.images import load_pair

        calls.append((Path(left).name, config.solver, url))
        result = run_pipeline(*load_pair(left, right), config)
        return result.disparity, result.summary()["levels"]

    class EntryPoint:
        def load(self):
            return fake_runner

    monkeypatch.setattr(scene_runners, "entry_points", lambda group, name: [EntryPoint()])
    options = _cones(
        tiny_dataset,
        tmp_path / "remote",
        solvers=["exact"],
        experiments=["solvers", "baselines"],
        url="http://localhost:8000",
    )
    results = run_bench(options, log=lambda line: None)
    assert calls == [("im2.png", "exact", "http://localhost:8000")]
    by_variant = {r["variant"]: r for r in results["runs"]}
    assert by_variant["exact"]["status"] == "ok" and len(by_variant["exact"]["levels"]) == 3
    assert "ran locally" in by_variant["heidari"]["reason"]


def test_url_without_a_runner_says_what_to_install(tiny_dataset, tmp_path, monkeypatch):
    monkeypatch.setattr(scene_runners, "entry_points", lambda group, name: [])
    options = BenchOptions(dataset=tiny_dataset, out=tmp_path, url="http://localhost:8000")
    with pytest.raises(bench.BenchError, match="needs the service package installed"):
        run_bench(options, log=lambda line: None)


def test_a_failing_run_is_recorded_and_the_bench_goes_on(tiny_dataset, tmp_path):
    def broken(scene, left, right, config):
        raise RuntimeError("solver exploded")

    options = _cones(tiny_dataset, tmp_path, solvers=["exact"])
    variant = bench.variants(options)[0]
    scene = bench.select_scenes(options)[0]
    run = bench.run_one(variant, scene, scene.load(), scene.ground_truth(), options, broken)
    assert run.status == "failed" and "solver exploded" in run.reason
    assert isinstance(RunOutput(np.zeros((1, 1)), 0.0).levels, list)


def test_bench_rejects_unknown_scenes_and_experiments(tiny_dataset, tmp_path, capsys):
    assert main(["bench", str(tiny_dataset), "--out", str(tmp_path), "--scenes", "venus"]) == 1
    assert "scene venus not in" in capsys.readouterr().err
    assert main(["bench", str(tiny_dataset), "--out", str(tmp_path), "--experiments", "x"]) == 1
    assert "unknown experiment x" in capsys.readouterr().err


def test_a_protocol_that_leaves_no_pixel_fails_the_run_not_the_bench(tiny_dataset, tmp_path):
    options = _cones(tiny_dataset, tmp_path, experiments=["baselines"], border=100)
    results = run_bench(options, log=lambda line: None)
    assert {r["status"] for r in results["runs"]} == {"failed"}
    assert all("no pixel left" in r["reason"] for r in results["runs"])
    assert "failed: evaluation" in (tmp_path / "results.md").read_text()


def test_an_estimated_range_is_reported_per_run(tiny_dataset, tmp_path):
    options = _cones(tiny_dataset, tmp_path, experiments=["accurate"], max_disparity="auto")
    lines: list[str] = []
    results = run_bench(options, log=lines.append)
    full = next(r for r in results["runs"] if r["variant"] == "accurate")
    assert full["config"]["max_disparity"] == "auto"
    assert full["info"]["disparity_range"]["source"].startswith("auto")
    assert any("range" in line and "auto" in line for line in lines)
