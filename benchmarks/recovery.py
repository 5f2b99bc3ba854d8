"""Recovery at the default settings (issue 20, item 3): a job's extra time when one process of
the service is SIGKILLed while it runs, for each kind of process.

    python benchmarks/recovery.py                       # every victim (about 15 minutes)
    python benchmarks/recovery.py --victims cpu-main,redis

The service is what ``qhsm serve`` runs (``workers.supervisor.Stack``: an embedded Redis and
a control, a CPU and, with the D-Wave stand-in, a QPU worker, each restarted with backoff when
it dies) with the API as a process of its own (``qhsm api``, started again 1 s after it dies, as
a container would be). Every setting is the default (watchdog stall 300 s, lost after 30 s,
heartbeat 2 s). Per victim: the job runs once undisturbed, then again with the victim killed
once the job has made progress (for ``control-start``: the control worker dies holding the
job's start task, its pool process stopped first so that it never runs it). Reported: both
wall times, the delay the kill cost, whether the result is identical. Target: every job
finishes, identical, within 120 s of the kill.

Jobs: Tsukuba with ``sa`` (the defaults, max disparity 16); for ``qpu-main`` a 24x48 synthetic
pair with ``qpu`` against the local stand-in of D-Wave's Solver API of the tests
(``tests/service/sapi_stub.py``, token a sentinel).
"""

from __future__ import annotations

import argparse
import io
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from api.client import Client
from api.users import UserStore, ensure_local_admin
from shared.config import LevelConfig, get_settings
from shared.datasets import default_middlebury_dir, load_scene
from shared.synthetic import make_scene
from workers.embedded_redis import free_port
from workers.supervisor import Stack

ROOT = Path(__file__).parents[1]
VICTIMS = ["control-main", "control-pool", "control-start", "cpu-main", "cpu-pool", "redis", "api"]
TARGET = 120.0


def png(image) -> bytes:
    import cv2

    return cv2.imencode(".png", np.rint(image * 255).astype(np.uint8))[1].tobytes()


class Api:
    """``qhsm api`` as a process of its own, restarted when it dies (:meth:`start` again)."""

    def __init__(self, settings, folder: Path) -> None:
        self.port = free_port()
        self.env = {
            **os.environ,
            "QHSM_REDIS_URL": settings.redis_url,
            "QHSM_DATA_DIR": str(settings.data_dir),
        }
        self.log = folder / "api.log"
        self.process: subprocess.Popen | None = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self) -> Api:
        command = [sys.executable, "-m", "shared.cli", "api", "--host", "127.0.0.1",
                   "--port", str(self.port), "--log-level", "warning"]  # fmt: skip
        with self.log.open("ab") as out:
            self.process = subprocess.Popen(command, env=self.env, stdout=out, stderr=out)
        import httpx

        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            try:
                if httpx.get(f"{self.url}/healthz", timeout=1).status_code == 200:
                    return self
            except httpx.HTTPError:
                time.sleep(0.2)
        raise RuntimeError(f"the API did not start: {self.log.read_text()[-2000:]}")

    def stop(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.terminate()
            self.process.wait(30)


def wait_state(client: Client, job_id: str, timeout: float = 1800) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            status = client.status(job_id)
        except Exception:  # the API or Redis is down a moment
            time.sleep(0.5)
            continue
        if status["state"] in ("succeeded", "failed", "cancelled"):
            return status
        time.sleep(0.2)
    raise RuntimeError(f"job {job_id} not finished after {timeout} s")


def progressed(client: Client, job_id: str, fraction: float) -> None:
    """Wait until the job's second level is this far (its first is done)."""
    while True:
        status = client.status(job_id)
        progress = status["progress"]
        if status["state"] not in ("running", "queued"):
            return
        second = progress["level"] >= min(2, progress["levels"]) and progress["bundles_total"]
        if second and progress["bundles_done"] >= fraction * progress["bundles_total"]:
            return
        time.sleep(0.05)


def worker(stack: Stack, kind: str):
    return next(w for w in stack.workers if w.name.startswith(kind))


def run(client: Client, pair, params) -> tuple[str, float]:
    started = time.monotonic()
    job = client.submit(*pair, params)
    return job["id"], started


def result(client: Client, job_id: str) -> np.ndarray:
    return np.load(io.BytesIO(client.disparity(job_id, "npy")))


def kill(pid: int) -> None:
    os.kill(pid, signal.SIGKILL)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--victims", default=",".join([*VICTIMS, "qpu-main"]))
    parser.add_argument("--json", help="also write the figures here")
    args = parser.parse_args()
    victims = args.victims.split(",")
    folder = Path(tempfile.mkdtemp(prefix="qhsm-recovery-"))
    stub = None
    if "qpu-main" in victims:
        sys.path.insert(0, str(ROOT / "tests" / "service"))
        from sapi_stub import SapiStub

        stub = SapiStub(token="benchmark-sentinel-token").start()
        os.environ.update(DWAVE_API_TOKEN=stub.token, DWAVE_API_ENDPOINT=stub.endpoint)
    settings = get_settings().model_copy(
        update={"data_dir": folder / "data", "redis_url": None, "api_port": free_port()}
    )
    tsukuba = load_scene(default_middlebury_dir() / "tsukuba")
    sa_pair = tsukuba.left.read_bytes(), tsukuba.right.read_bytes()
    sa_params = {"solver": "sa", "max_disparity": 16}
    tiny = make_scene(24, 48, max_disparity=8, seed=3)
    qpu_pair = png(tiny.left), png(tiny.right)
    qpu_params = {
        "solver": "qpu", "preset": "paper", "max_disparity": 8, "median": False,
        "bilateral": False, "levels": [LevelConfig(downsample=1, candidates=3).model_dump()],
        "solver_params": {"num_reads": 10},
    }  # fmt: skip
    rows = []
    load = os.getloadavg()[0]
    with Stack(settings) as stack:
        api = Api(stack.settings, folder).start()
        key, _ = ensure_local_admin(UserStore.from_settings(stack.settings), settings.data_dir)
        client = Client(api.url, key=key)
        try:
            references: dict[str, tuple[float, np.ndarray]] = {}

            def reference(name: str, pair, params) -> tuple[float, np.ndarray]:
                if name not in references:
                    job_id, started = run(client, pair, params)
                    status = wait_state(client, job_id)
                    assert status["state"] == "succeeded", status
                    references[name] = (time.monotonic() - started, result(client, job_id))
                return references[name]

            for victim in victims:
                pair, params = (qpu_pair, qpu_params) if victim == "qpu-main" else (
                    sa_pair, sa_params
                )  # fmt: skip
                name = "qpu" if victim == "qpu-main" else "sa"
                undisturbed, expected = reference(name, pair, params)
                if victim == "control-start":
                    control = worker(stack, "control")
                    for child in control.children():
                        os.kill(child, signal.SIGSTOP)
                    job_id, started = run(client, pair, params)
                    time.sleep(5)  # its start task taken, never run
                    killed = time.monotonic()
                    kill(control.pid)
                else:
                    job_id, started = run(client, pair, params)
                    progressed(client, job_id, 0.4)
                    killed = time.monotonic()
                    if victim == "api":
                        kill(api.process.pid)
                        api.process.wait()
                        time.sleep(1)
                        api.start()
                    elif victim == "redis":
                        kill(stack.redis.process.pid)
                    else:
                        kind, part = victim.split("-")
                        target = worker(stack, "dwave" if kind == "qpu" else kind)
                        kill(target.pid if part == "main" else target.children()[0])
                status = wait_state(client, job_id)
                finished = time.monotonic()
                same = status["state"] == "succeeded" and np.array_equal(
                    result(client, job_id), expected
                )
                row = {
                    "victim": victim,
                    "state": status["state"],
                    "identical": bool(same),
                    "undisturbed_s": round(undisturbed, 1),
                    "with_kill_s": round(finished - started, 1),
                    "delay_s": round(finished - started - undisturbed, 1),
                    "kill_to_end_s": round(finished - killed, 1),
                    "error": status.get("error"),
                }
                rows.append(row)
                print(json.dumps(row), flush=True)
                time.sleep(3)  # the supervisor's restarts settle
        finally:
            api.stop()
            if stub is not None:
                stub.stop()
    summary = {
        "rows": rows,
        "all_recovered": all(r["identical"] and r["delay_s"] <= TARGET for r in rows),
        "worst_delay_s": max(r["delay_s"] for r in rows),
        "median_delay_s": statistics.median(r["delay_s"] for r in rows),
        "load_average_start": load,
        "load_average_end": os.getloadavg()[0],
    }
    print(json.dumps(summary, indent=2))
    if args.json:
        Path(args.json).write_text(json.dumps(summary, indent=2))
    return 0 if summary["all_recovered"] else 1


if __name__ == "__main__":
    sys.exit(main())
