"""Where the time goes, from a py-spy profile: each function's share of the samples (inclusive:
the function and what it called), over every thread and process sampled.

    py-spy record --threads -r 200 --format raw -o match.raw -- \\
        qhsm match left.ppm right.ppm -o out.pfm --max-disparity 16
    python benchmarks/profile_summary.py match.raw --top 30
    python benchmarks/profile_summary.py match.raw --only 'solve_chains|quick_match|<module> \\(cv2'

``--format raw`` is py-spy's collapsed-stack output (one line per distinct stack: frames joined by
``;`` and the sample count). Idle threads are not sampled unless py-spy is given ``--idle``.
"""

from __future__ import annotations

import argparse
import re
import sys
from collections import Counter
from pathlib import Path

FRAME = re.compile(r"(?P<function>.*) \((?P<file>.*?):\d+\)$")
#: Path prefixes dropped from file names (site-packages, the repository, the standard library).
PREFIXES = ("site-packages/", "lib/python3.11/")


def frame_name(frame: str, root: str) -> str:
    """``function (file)`` with the file relative to the repository or its package."""
    match = FRAME.match(frame.strip())
    if not match:
        return frame.strip()
    where = match["file"]
    for prefix in (*PREFIXES, root):
        if prefix and prefix in where:
            where = where.split(prefix, 1)[1]
    return f"{match['function']} ({where})"


def shares(lines: list[str], root: str) -> tuple[Counter, int]:
    """Samples per function (each counted once per stack it is on) and the samples in all."""
    inclusive: Counter = Counter()
    total = 0
    for line in lines:
        stack, _, count = line.rstrip().rpartition(" ")
        if not count.isdigit():
            continue
        samples = int(count)
        total += samples
        frames = {frame_name(frame, root) for frame in stack.split(";")[1:]}  # [0]: the thread
        for name in frames:
            inclusive[name] += samples
    return inclusive, total


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("profile", type=Path, help="py-spy record --format raw output")
    parser.add_argument("--top", type=int, default=30, help="functions to list")
    parser.add_argument("--only", help="regular expression: list only the functions it matches")
    args = parser.parse_args(argv)
    root = str(Path(__file__).resolve().parents[1]) + "/"
    inclusive, total = shares(args.profile.read_text().splitlines(), root)
    pattern = re.compile(args.only) if args.only else None
    listed = [(f, n) for f, n in inclusive.most_common() if not pattern or pattern.search(f)]
    print(f"{total} samples")
    for name, samples in listed[: args.top]:
        print(f"{100 * samples / max(total, 1):5.1f} %  {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
