"""The start of ``qhsm match`` (issue 28): CPU of its imports and of the first kernel calls.

    python benchmarks/start.py [--repeats 5]
    PYTHONPATH=/other/checkout python benchmarks/start.py   # the same of another version

Each statement runs in a fresh ``python -c`` process, the statements alternated, and the median
user + system CPU of each is printed (CPU, not wall time: other users of a shared machine
disturb it far less). Then, in one fresh process after the imports, ``run_pipeline`` twice on a
24 x 32 synthetic scene: the first run loads the numba cache of the kernels (nothing is compiled
once the cache is warm), unless they were compiled ahead of time (``qhsm build-kernels``, then
numba is not even imported); the second shows what the scene itself costs.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys

STATEMENTS = [
    "pass",
    "import numpy, cv2",
    "import numba",
    "import dimod",
    "import pydantic_settings",
    # what ``qhsm match`` with ``exact`` imports and parses before it reads the views (its
    # ``--help``: the same parser, any version)
    "import contextlib, io, shared.images, shared.pipeline, shared.process_pool, "
    "shared.progress_bar\nfrom shared.cli import main\n"
    "with contextlib.redirect_stdout(io.StringIO()):\n"
    "    try:\n        main(['match', '--help'])\n    except SystemExit:\n        pass",
]

MATCH_LABEL = "the match path's imports; qhsm match --help"

FIRST_RUN = """
import time
from shared.cli import build_parser
build_parser()
from shared.config import MatchConfig
from shared.pipeline import run_pipeline
from shared.synthetic import make_scene
scene = make_scene(24, 32, max_disparity=6, seed=0)
for run in ("first", "second"):
    started = time.process_time()
    run_pipeline(scene.left, scene.right, MatchConfig(max_disparity=6))
    print(f"{run} run on 24 x 32: {time.process_time() - started:.2f} s CPU")
import sys
print("numba imported:", "numba" in sys.modules)
"""


def cpu_of(code: str) -> tuple[float, str]:
    """User + system CPU of a fresh interpreter running ``code``, and what it printed."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    done = subprocess.run(
        [sys.executable, "-c", code], check=True, capture_output=True, text=True, env=os.environ
    )
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
    return cpu, done.stdout


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    seconds: dict[str, list[float]] = {s: [] for s in STATEMENTS}
    for _ in range(args.repeats):
        for statement in STATEMENTS:
            seconds[statement].append(cpu_of(statement)[0])
    print("| statement | CPU s (median) |\n|---|---:|")
    for statement, values in seconds.items():
        label = statement if "\n" not in statement else MATCH_LABEL
        print(f"| `{label}` | {statistics.median(values):.2f} |")
    print(cpu_of(FIRST_RUN)[1], end="")


if __name__ == "__main__":
    main()
