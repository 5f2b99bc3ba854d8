"""Peak memory of ``qhsm match`` on a large synthetic pair (default 2000 x 2000, 256-px range).

    python benchmarks/memory.py [--size 2000] [--max-disparity 256] [--solver exact]

Writes the pair as PNGs to a temporary folder, runs ``/usr/bin/time -v qhsm match`` on it with the
defaults (accurate preset) and prints the wall time and the maximum resident set size. Costs are
built per block of rows, so the peak should grow with the image's rows, not with the cost
volume (which alone would be 2000 x 2000 x 257 x 4 B = 4.1 GB per view).
"""

from __future__ import annotations

import argparse
import re
import subprocess
import tempfile
from pathlib import Path

import cv2
import numpy as np

from shared.synthetic import make_scene


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=2000)
    parser.add_argument("--max-disparity", type=int, default=256)
    parser.add_argument("--solver", default="exact")
    args = parser.parse_args()
    scene = make_scene(args.size, args.size, max_disparity=args.max_disparity, seed=0)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for name, image in (("left", scene.left), ("right", scene.right)):
            cv2.imwrite(str(folder / f"{name}.png"), np.rint(image * 255).astype(np.uint8))
        command = ["/usr/bin/time", "-v", "qhsm", "match", str(folder / "left.png")]
        command += [str(folder / "right.png"), "-o", str(folder / "d.pfm"), "--json"]
        command += ["--max-disparity", str(args.max_disparity), "--solver", args.solver]
        done = subprocess.run(command, capture_output=True, text=True, check=True)
    peak_kb = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", done.stderr)[1])
    wall = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): (\S+)", done.stderr)[1]
    print(f"{args.size}x{args.size}, max disparity {args.max_disparity}, solver {args.solver}:")
    print(f"peak RSS {peak_kb / 2**20:.2f} GiB, wall {wall}")


if __name__ == "__main__":
    main()
