"""`qhsm bench` shows progress (issue 10, item 17): a bar over scenes x variants on stderr, each
finished run's line above it."""

from __future__ import annotations

import json

from shared.cli import main


def test_bench_shows_progress(tiny_dataset, tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["bench", str(tiny_dataset), "--out", str(out), "--solvers", "exact"]
    assert main([*argv, "--experiments", "solvers", "--processes", "1"]) == 0
    err = capsys.readouterr().err
    assert "2/2" in err and "run" in err  # tqdm's counter over scenes x variants
    assert "tsukuba solvers/exact: RMSE" in err  # each run's line above the bar
    runs = json.loads((out / "results.json").read_text())["runs"]
    assert {run["config"]["encoding"] for run in runs} == {"one-hot"}  # exact: the paper's
