"""``qhsm match`` with ``exact`` (the default) imports no QUBO machinery (issue 28): dimod, and
networkx with it, cost a third of a second of CPU at every start."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

from shared.synthetic import make_scene

ROOT = Path(__file__).resolve().parents[2]

PROBE = """
import sys
from shared.cli import main
code = main(sys.argv[1:])
heavy = sorted(m for m in ("dimod", "networkx", "celery", "fastapi", "dwave") if m in sys.modules)
print("HEAVY", ",".join(heavy))
sys.exit(code)
"""


def test_match_with_exact_imports_neither_dimod_nor_networkx(tmp_path):
    scene = make_scene(20, 28, max_disparity=4, seed=0)
    views = []
    for name, view in (("left", scene.left), ("right", scene.right)):
        path = tmp_path / f"{name}.png"
        cv2.imwrite(str(path), np.round(np.clip(view, 0, 1) * 255).astype(np.uint8))
        views.append(str(path))
    output = tmp_path / "d.pfm"
    done = subprocess.run(
        [sys.executable, "-c", PROBE, "match", *views, "-o", str(output), "--max-disparity", "4"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert output.exists()
    assert "HEAVY \n" in done.stdout
