"""What a job's uploads cost in Redis (issue 22, item 3: workers read them from there): for
views decoded as the API decodes them, the float32 size, what ``workers.arrays.array_fields``
stores (the integers the views were decoded from, in pieces of at most 4 MiB), and the time to
encode (the API, once per job) and to decode (the control worker, once per level). Prints the
markdown table of docs/benchmarks.md ("Uploads in Redis").

    python benchmarks/uploads.py [DATA]     # DATA: default ../shared/data
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

import cv2

from api.uploads import decode_view
from shared.config import Settings
from shared.datasets import default_middlebury_dir
from workers.arrays import array_fields, array_from

REPEATS = 3
#: Left views measured (dataset folder, scene): the three sizes of the data at hand.
SCENES = [("middlebury", "tsukuba"), ("middlebury", "cones"), ("middlebury2006", "Aloe")]
#: Pixels of the largest view the default QHSM_MAX_IMAGE_PIXELS accepts (Aloe upscaled).
LARGEST = Settings().max_image_pixels


def left_file(folder: Path) -> Path:
    return next(path for path in sorted(folder.iterdir()) if path.stem in ("left", "view1"))


def measure(name: str, data: bytes) -> str:
    view = decode_view(data, "left", Settings())
    encode, decode = [], []
    for _ in range(REPEATS):
        started = time.perf_counter()
        fields = array_fields("left", view, images=True)
        encode.append(time.perf_counter() - started)
        raw = {key.encode(): value for key, value in fields.items()}
        started = time.perf_counter()
        back = array_from(raw, "left")
        decode.append(time.perf_counter() - started)
    assert back.tobytes() == view.tobytes()
    stored = sum(len(value) for value in fields.values())
    height, width = view.shape[:2]
    return (
        f"| {name} | {width}x{height} | {view.nbytes / 1e6:.2f} | {stored / 1e6:.2f} | "
        f"{view.nbytes / stored:.1f} | {len(fields) - 1} | {statistics.median(encode):.3f} | "
        f"{statistics.median(decode):.3f} |"
    )


def main(argv: list[str]) -> int:
    root = Path(argv[0]) if argv else default_middlebury_dir().parent
    print("| view | size | float32 (MB) | stored (MB) | ratio | pieces | encode (s) | decode (s) |")
    print("|---|---|---|---|---|---|---|---|")
    last = None
    for dataset, scene in SCENES:
        folder = root / dataset / scene
        if not folder.is_dir():
            print(f"| {dataset}/{scene} | missing | | | | | | |")
            continue
        path = left_file(folder)
        last = path
        print(measure(f"{dataset}/{scene}", path.read_bytes()))
    if last is not None:
        image = cv2.imread(str(last), cv2.IMREAD_COLOR)
        factor = (LARGEST / (image.shape[0] * image.shape[1])) ** 0.5 * 0.999
        size = (int(image.shape[1] * factor), int(image.shape[0] * factor))
        large = cv2.resize(image, size, interpolation=cv2.INTER_CUBIC)
        png = cv2.imencode(".png", large)[1].tobytes()
        print(measure(f"{last.parent.name} upscaled (largest accepted)", png))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
