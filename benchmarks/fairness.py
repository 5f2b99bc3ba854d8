"""Fair share between users (issue 20, item 7): how long user B's small job takes while user A
has two large jobs running, against the same job on an idle service.

    python benchmarks/fairness.py                 # 3 loaded runs (about 10 minutes on 2 cores)
    python benchmarks/fairness.py --repeats 1 --b-solver sa

The service is what ``qhsm serve`` starts (``workers.supervisor.Stack``: an embedded Redis, a
control worker, one CPU worker with a process per core) and the API. B's job: Tsukuba, ``exact``
(``--b-solver``), the defaults otherwise, max disparity 16; timed from the POST until it has
succeeded (polls every 20 ms). A's jobs: two Cones jobs with ``sa`` (defaults, max disparity 60),
submitted first; B's job is sent once both are running and A still has work queued. Each loaded
run is paired with an idle run just before it (nothing else on the service), so the ratio
loaded / idle compares like with like on a shared machine. Target: the median ratio <= 3.

Run it against another checkout to compare (``PYTHONPATH=/path/to/checkout python
benchmarks/fairness.py``); the script only uses what both have.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

from api.client import Client
from api.server import ApiThread
from api.users import UserStore
from shared.config import get_settings
from shared.datasets import default_middlebury_dir, load_scene
from workers.embedded_redis import free_port
from workers.supervisor import Stack


def scene_files(name: str) -> tuple[bytes, bytes]:
    scene = load_scene(default_middlebury_dir() / name)
    return scene.left.read_bytes(), scene.right.read_bytes()


def wait(client: Client, job_id: str, states: set[str], timeout: float = 3600) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        status = client.status(job_id)
        if status["state"] in states:
            return status
        time.sleep(0.02)
    raise RuntimeError(f"job {job_id} not {states} after {timeout} s")


def timed_job(client: Client, pair: tuple[bytes, bytes], params: dict) -> float:
    started = time.perf_counter()
    job = client.submit(*pair, params)
    status = wait(client, job["id"], {"succeeded", "failed", "cancelled"})
    if status["state"] != "succeeded":
        raise RuntimeError(f"B's job {status['state']}: {status['error']}")
    return time.perf_counter() - started


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--b-solver", default="exact")
    parser.add_argument("--json", help="also write the figures here")
    args = parser.parse_args()
    b_params = {"solver": args.b_solver, "max_disparity": 16}
    a_params = {"solver": "sa", "max_disparity": 60}
    tsukuba, cones = scene_files("tsukuba"), scene_files("cones")
    folder = Path(tempfile.mkdtemp(prefix="qhsm-fairness-"))
    settings = get_settings().model_copy(
        update={"data_dir": folder / "data", "api_port": free_port(), "redis_url": None}
    )
    load = os.getloadavg()[0]
    rows = []
    with Stack(settings) as stack:
        api = ApiThread(stack.settings).start()
        try:
            users = UserStore.from_settings(stack.settings)
            _, key_a = users.create_user("user-a", qpu_seconds=None)
            _, key_b = users.create_user("user-b", qpu_seconds=None)
            a, b = Client(api.url, key=key_a), Client(api.url, key=key_b)
            timed_job(b, tsukuba, b_params)  # warm-up: imports, numba, caches
            for run in range(args.repeats):
                idle = timed_job(b, tsukuba, b_params)
                jobs = [a.submit(*cones, a_params)["id"] for _ in range(2)]
                for job_id in jobs:
                    wait(a, job_id, {"running"})
                while sum(a.status(j)["progress"]["bundles_done"] for j in jobs) < 4:
                    time.sleep(0.05)  # both of A's jobs have bundles solving
                loaded = timed_job(b, tsukuba, b_params)
                states = [a.status(j)["state"] for j in jobs]
                for job_id in jobs:
                    a.cancel(job_id)
                rows.append({"idle": idle, "loaded": loaded, "ratio": loaded / idle})
                print(
                    f"run {run + 1}: B idle {idle:.2f} s, with A's two jobs {loaded:.2f} s "
                    f"({loaded / idle:.1f}x); A's jobs were {', '.join(states)}",
                    flush=True,
                )
                time.sleep(2)  # A's cancelled tasks drain
        finally:
            api.stop()
    ratios = [row["ratio"] for row in rows]
    summary = {
        "b_solver": args.b_solver,
        "idle_median_s": statistics.median(row["idle"] for row in rows),
        "loaded_median_s": statistics.median(row["loaded"] for row in rows),
        "ratio_median": statistics.median(ratios),
        "ratio_max": max(ratios),
        "load_average_start": load,
        "load_average_end": os.getloadavg()[0],
        "runs": rows,
        "code": str(Path(__import__("shared").__file__).parents[1]),
    }
    print(json.dumps(summary, indent=2))
    if args.json:
        Path(args.json).write_text(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
