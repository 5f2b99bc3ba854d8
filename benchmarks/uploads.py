"""What a job's uploads cost in Redis (issue 22, item 3: workers read them from there): for
views decoded as the API decodes them, the float32 size, what ``workers.arrays.array_fields``
stores (the integers the views were decoded from, in pieces of at most 4 MiB), and the time to
encode (the API, once per job) and to decode (the control worker, once per level). Prints the
markdown table of docs/benchmarks.md ("Uploads in Redis").

    python benchmarks/uploads.py [DATA]     # DATA: default ../shared/data

Then one Tsukuba job's round trip, median of 15, three times: the uploads kept as before this
change (``np.save`` of both views into a job folder, ``np.load`` of both at each of 3 levels)
against ``JobStore.create`` plus 3 x ``JobStore.load_views`` through the Redis of
``QHSM_REDIS_URL`` (default 127.0.0.1:6379, database 13; a key prefix of its own, deleted).
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
import uuid
from pathlib import Path

import cv2
import numpy as np

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


def median_ms(run, repeats: int = 15) -> float:
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        run()
        times.append(time.perf_counter() - started)
    return 1e3 * statistics.median(times)


def round_trips(folder: Path) -> str:
    """One job's uploads written once and read at 3 levels: on disk (before) and in Redis."""
    from shared.config import MatchConfig
    from workers.records import JobRecord, JobState, new_job_id, now
    from workers.store import JobStore

    settings = Settings()
    url = settings.redis_url or "redis://127.0.0.1:6379/13"
    prefix = f"qhsm-bench-uploads-{uuid.uuid4().hex[:8]}"
    settings = settings.model_copy(update={"redis_url": url, "key_prefix": prefix})
    views = [decode_view(path.read_bytes(), "view", settings) for path in
             (left_file(folder), next(folder.glob("right.*")))]  # fmt: skip
    store = JobStore.from_settings(settings)

    def disk() -> None:
        with tempfile.TemporaryDirectory() as job:
            for name, view in zip(("left", "right"), views, strict=True):
                np.save(Path(job) / f"{name}.npy", view, allow_pickle=False)
            for _ in range(3):
                [np.load(Path(job) / f"{name}.npy") for name in ("left", "right")]

    def in_redis() -> None:
        record = JobRecord(
            id=new_job_id(), config=MatchConfig(), width=1, height=1, created_at=now()
        )
        store.create(record, {"left": views[0], "right": views[1]})
        for _ in range(3):
            store.load_views(record.id)
        store.transition(record.id, JobState.CANCELLED, {JobState.QUEUED})

    try:
        rows = [(median_ms(disk), median_ms(in_redis)) for _ in range(3)]
    finally:
        for key in store.redis.scan_iter(match=f"{prefix}:*"):
            store.redis.delete(key)
    disk_ms = ", ".join(f"{d:.1f}" for d, _ in rows)
    redis_ms = ", ".join(f"{r:.1f}" for _, r in rows)
    return f"{folder.name}: disk (before) {disk_ms} ms; Redis {redis_ms} ms"


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
    tsukuba = root / "middlebury" / "tsukuba"
    if tsukuba.is_dir():
        print()
        print(round_trips(tsukuba))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
