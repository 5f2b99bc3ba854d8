"""Service benchmark: HTTP + Celery + Redis against in-process matching, and worker scaling.

    python benchmarks/service.py                  # both parts (~3 minutes on 2 cores)
    python benchmarks/service.py --part exact     # Tsukuba, exact: service vs in process
    python benchmarks/service.py --part sa        # Tsukuba, sa (domain-wall): 2 vs 1 process

Part "exact" (target: service <= 1.5x in-process). The same Tsukuba job (paper pyramid, exact,
max disparity 16) is timed (a) as the ``qhsm match`` command (a fresh process: start-up, I/O,
pipeline), (b) as ``run_pipeline`` in a warm process (pipeline only) and (c) through the service
with 2 warm worker processes: from the POST until the PFM download has arrived, polling every
20 ms. Medians over ``--repeats`` runs, all in the same run of this script.

Part "sa" (target: >= 1.7x). The same Tsukuba job with ``sa`` (domain-wall, preset ``fast``,
no roof-duality preprocessing) through the service with a worker of 1 process and of 2
processes (interleaved, ``--sa-repeats`` each); wall time from POST to download, medians.
Both parts need the machine's two cores: the 1-minute load average is reported at start and end,
and for sa the CPU the worker got (CPU seconds of the worker and its pool / wall seconds).
Redis: QHSM_REDIS_URL when set, else an embedded redis-server in a temporary folder.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from contextlib import contextmanager
from pathlib import Path

from api.client import Client
from api.server import ApiThread
from api.users import UserStore, ensure_local_admin
from shared.config import MatchConfig, Settings, get_settings
from shared.datasets import default_middlebury_dir, load_scene
from shared.pipeline import run_pipeline
from workers.app import make_celery
from workers.embedded_redis import EmbeddedRedis, free_port
from workers.supervisor import WorkerProcess, wait_for_workers, worker_env

EXACT = {"solver": "exact", "max_disparity": 16}
SA = {
    "solver": "sa",
    "max_disparity": 16,
    "encoding": "domain-wall",
    # anneal every variable (no roof-duality fixing, which solves most Tsukuba rows outright):
    # the annealer's work is what the workers share
    "solver_params": {"preset": "fast", "preprocess": "none", "num_reads": 4},
}


@contextmanager
def service(folder: Path, redis_url: str, processes: int, queues: list[str]):
    """A worker with ``processes`` pool processes and the API on a free port."""
    settings = get_settings().model_copy(
        update={
            "redis_url": redis_url,
            "key_prefix": f"qhsm-bench-{uuid.uuid4().hex[:8]}",
            "data_dir": folder / "data",
            "api_port": free_port(),
        }
    )
    worker = WorkerProcess(
        f"bench-{processes}-{uuid.uuid4().hex[:6]}",
        ["control", *queues],
        processes,
        worker_env(settings, redis_url, dwave=False),
        folder / f"worker-{processes}.log",
    ).start()
    api = None
    try:
        wait_for_workers(make_celery(settings, with_tasks=False), [worker.hostname])
        api = ApiThread(settings).start()
        key, _ = ensure_local_admin(UserStore.from_settings(settings), settings.data_dir)
        client = Client(api.url, key=key)
        yield client, settings, worker
        client.close()
    finally:
        if api:
            api.stop()
        worker.stop()


def run_job(client: Client, left: bytes, right: bytes, params: dict) -> tuple[float, dict]:
    """Seconds from POST to the downloaded PFM, and the final status."""
    started = time.perf_counter()
    job = client.submit(left, right, params, names=("left.ppm", "right.ppm"))
    status = client.wait(job["id"], interval=0.02, max_interval=0.02)
    if status["state"] != "succeeded":
        raise RuntimeError(f"benchmark job {status['state']}: {status['error']}")
    client.disparity(job["id"], "pfm")
    return time.perf_counter() - started, status


def part_exact(folder: Path, redis_url: str, scene, repeats: int) -> dict:
    output = folder / "match.pfm"
    qhsm = shutil.which("qhsm")
    program = [qhsm] if qhsm else [sys.executable, "-m", "shared.cli"]
    command = [
        *program, "match", str(scene.left), str(scene.right),
        "-o", str(output), "--max-disparity", str(EXACT["max_disparity"]),
    ]  # fmt: skip
    cli = []
    for _ in range(repeats):
        started = time.perf_counter()
        subprocess.run(command, check=True, capture_output=True)
        cli.append(time.perf_counter() - started)
    left, right = scene.load()
    config = MatchConfig.model_validate(EXACT)
    run_pipeline(left, right, config)  # warm up
    pipeline = [run_pipeline(left, right, config).seconds for _ in range(repeats)]
    with service(folder / "exact", redis_url, 2, ["exact"]) as (client, settings, _):
        raw = scene.left.read_bytes(), scene.right.read_bytes()
        run_job(client, *raw, EXACT)  # warm the workers' imports
        served = [run_job(client, *raw, EXACT)[0] for _ in range(repeats)]
        rows_per_task = settings.solver_rows_per_task.get("exact", settings.rows_per_task)
    result = {
        "qhsm_match_command_s": statistics.median(cli),
        "run_pipeline_s": statistics.median(pipeline),
        "service_s": statistics.median(served),
        "rows_per_task": rows_per_task,
        "repeats": repeats,
    }
    result["service_over_command"] = result["service_s"] / result["qhsm_match_command_s"]
    result["service_over_pipeline"] = result["service_s"] / result["run_pipeline_s"]
    return result


def worker_cpu(worker: WorkerProcess) -> float:
    """CPU seconds (user + system) the worker and its pool processes have used so far."""
    ticks = 0
    for pid in [worker.pid, *worker.children()]:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        ticks += int(fields[11]) + int(fields[12])  # utime, stime (fields 14 and 15)
    return ticks / os.sysconf("SC_CLK_TCK")


def part_sa(folder: Path, redis_url: str, scene, repeats: int) -> dict:
    raw = scene.left.read_bytes(), scene.right.read_bytes()
    times: dict[int, list[float]] = {1: [], 2: []}
    cores: dict[int, list[float]] = {1: [], 2: []}
    bundles = 0
    for repeat in range(repeats):  # interleaved, so load from other users hits both alike
        for processes in (1, 2):
            where = folder / f"sa{processes}-{repeat}"
            with service(where, redis_url, processes, ["sa"]) as (client, _, worker):
                cpu_before = worker_cpu(worker)
                seconds, status = run_job(client, *raw, SA)
                busy = (worker_cpu(worker) - cpu_before) / seconds
            times[processes].append(seconds)
            cores[processes].append(busy)
            bundles = sum(level["bundles"] for level in status["levels"])
            print(
                f"sa, {processes} process(es): {seconds:.1f} s, {busy:.2f} cores busy",
                file=sys.stderr,
                flush=True,
            )
    one, two = statistics.median(times[1]), statistics.median(times[2])
    return {
        "one_process_s": one,
        "two_processes_s": two,
        "speedup": one / two,
        "cores_busy_one": statistics.median(cores[1]),
        "cores_busy_two": statistics.median(cores[2]),
        "bundles": bundles,
        "rows_per_task": Settings().rows_per_task,
        "repeats": repeats,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=["exact", "sa", "all"], default="all")
    parser.add_argument("--repeats", type=int, default=5, help="runs per exact measurement")
    parser.add_argument("--sa-repeats", type=int, default=2, help="runs per sa measurement")
    args = parser.parse_args(argv)
    scene = load_scene(default_middlebury_dir() / "tsukuba")
    results: dict = {"load_average_1min_at_start": os.getloadavg()[0]}
    with tempfile.TemporaryDirectory(prefix="qhsm-bench-") as tmp:
        folder = Path(tmp)
        redis_url, embedded = get_settings().redis_url, None
        if redis_url is None:
            embedded = EmbeddedRedis(folder / "redis").start()
            redis_url = embedded.url
        try:
            if args.part in ("exact", "all"):
                results["exact"] = part_exact(folder, redis_url, scene, args.repeats)
                print(json.dumps({"exact": results["exact"]}), flush=True)
            if args.part in ("sa", "all"):
                results["sa"] = part_sa(folder, redis_url, scene, args.sa_repeats)
                print(json.dumps({"sa": results["sa"]}), flush=True)
        finally:
            if embedded:
                embedded.stop()
    results["load_average_1min_at_end"] = os.getloadavg()[0]
    print(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
