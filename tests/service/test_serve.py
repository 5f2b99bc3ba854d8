"""`qhsm serve` as a user runs it (a subprocess with its embedded Redis): a private store,
the queues of the workers it starts, supervision of what it starts, recovery of a job whose
worker or Redis was SIGKILLed, no orphans after SIGKILL of serve itself, a busy port refused up
front; `qhsm admin` on the data directory; the embedded Redis's AOF stays small."""

from __future__ import annotations

import os
import signal
import socket
import stat
import subprocess
import sys
import time
from pathlib import Path
from urllib.parse import urlsplit

import harness
import httpx
import numpy as np
import pytest
import redis

from shared.cli import main
from shared.config import MatchConfig, Settings
from shared.images import decode_image
from shared.pipeline import run_pipeline
from shared.synthetic import make_scene
from workers.embedded_redis import (
    EMBEDDED_URL_FILE,
    PID_FILE,
    EmbeddedRedis,
    free_port,
    safe_url,
)
from workers.store import JobStore
from workers.watchdog import resend_count

pytestmark = pytest.mark.service

HERE = Path(__file__).parent
ROOT = HERE.parents[1]
TOKEN = "sentinel-dwave-token-for-tests"
STALL_SECONDS = 3
#: `qhsm serve` as the console script runs it (``python -m shared.cli`` would make a second
#: ``CommandError`` class in ``__main__``)
QHSM = [sys.executable, "-c", "import sys; from shared.cli import main; sys.exit(main())"]
SERVE = [*QHSM, "serve"]


def serve_env(markers: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("QHSM_REDIS_URL", "REDIS_URL")}
    env.update(
        PYTHONPATH=os.pathsep.join([str(HERE), str(ROOT), env.get("PYTHONPATH", "")]),
        QHSM_ROWS_PER_TASK="4",
        QHSM_WATCHDOG_STALL_SECONDS=str(STALL_SECONDS),
        QHSM_TEST_SLOW_SECONDS="0.25",
        QHSM_TEST_MARKERS=str(markers),
        DWAVE_API_TOKEN=TOKEN,
    )
    return env


def start_serve(data_dir: Path, port: int, env: dict[str, str], log: Path) -> subprocess.Popen:
    command = [*SERVE, "--port", str(port), "--data-dir", str(data_dir), "--concurrency", "2"]
    with log.open("ab") as out:
        return subprocess.Popen(command, env=env, stdout=out, stderr=subprocess.STDOUT)


def wait_ready(process: subprocess.Popen, url: str, log: Path, timeout: float = 90.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise AssertionError(f"serve exited ({process.returncode}):\n{log.read_text()}")
        try:
            if httpx.get(f"{url}/readyz", timeout=2).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(0.2)
    raise AssertionError(f"serve not ready in {timeout} s:\n{log.read_text()}")


def descendants(pid: int) -> set[int]:
    """Every process below ``pid`` (from /proc)."""
    parents: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        parents.setdefault(ppid, []).append(int(entry.name))
    found, todo = set(), [pid]
    while todo:
        for child in parents.get(todo.pop(), []):
            found.add(child)
            todo.append(child)
    return found


def parent(pid: int) -> int:
    return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def using(folder: Path) -> list[str]:
    """Live processes whose command line or environment names ``folder`` (serve's children:
    the workers get QHSM_DATA_DIR, redis-server its config file)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or not alive(int(entry.name)):
            continue
        try:
            names = (entry / "cmdline").read_bytes() + (entry / "environ").read_bytes()
        except OSError:
            continue
        if str(folder).encode() in names:
            found.append(cmdline(int(entry.name)))
    return found


def cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


class Served:
    def __init__(self, folder: Path):
        self.folder = folder
        self.data_dir = folder / "data"
        self.markers = folder / "markers"
        self.markers.mkdir()
        self.log = folder / "serve.log"
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.env = serve_env(self.markers)
        self.process = start_serve(self.data_dir, self.port, self.env, self.log)
        wait_ready(self.process, self.url, self.log)
        key = (self.data_dir / "api-key").read_text().strip()
        self.http = httpx.Client(
            base_url=self.url, headers={"Authorization": f"Bearer {key}"}, timeout=10
        )

    @property
    def redis_url(self) -> str:
        return (self.data_dir / EMBEDDED_URL_FILE).read_text().strip()

    def redis_pid(self) -> int:
        return int((self.data_dir / "redis" / PID_FILE).read_text())

    def cpu_worker(self) -> int:
        """The CPU worker's main process (serve's child; its pool processes are below it)."""
        [pid] = [
            pid
            for pid in descendants(self.process.pid)
            if f"cpu-{self.process.pid}@" in cmdline(pid)
            and alive(pid)
            and parent(pid) == self.process.pid
        ]
        return pid

    def store(self) -> JobStore:
        return JobStore.from_settings(Settings(redis_url=self.redis_url))

    def stop(self) -> None:
        self.http.close()
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(30)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    served = Served(tmp_path_factory.mktemp("served"))
    yield served
    served.stop()


@pytest.fixture(scope="module")
def pair():
    scene = make_scene(32, 48, max_disparity=8, seed=5)
    left, right = harness.png(scene.left), harness.png(scene.right)
    return left, right


def reference(pair, params: dict) -> np.ndarray:
    import qhsm_test_plugin  # noqa: F401 - registers fake-slow in this process

    saved = os.environ.get("QHSM_TEST_SLOW_SECONDS")
    os.environ["QHSM_TEST_SLOW_SECONDS"] = "0"
    try:
        left, right = decode_image(pair[0], "left"), decode_image(pair[1], "right")
        return run_pipeline(left, right, MatchConfig.model_validate(params)).disparity
    finally:
        if saved is None:
            os.environ.pop("QHSM_TEST_SLOW_SECONDS", None)
        else:
            os.environ["QHSM_TEST_SLOW_SECONDS"] = saved


def submit_and_wait_for_progress(served: Served, pair, params: dict) -> str:
    left, right = pair
    response = served.http.post(
        "/v1/jobs",
        files={"left": ("l.png", left), "right": ("r.png", right)},
        data={"params": __import__("json").dumps(params)},
    )
    assert response.status_code == 202, response.text
    job_id = response.json()["id"]
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        status = served.http.get(f"/v1/jobs/{job_id}").json()
        if status["progress"]["bundles_done"] >= 1:
            return job_id
        time.sleep(0.05)
    raise AssertionError(f"job {job_id} made no progress")


def wait_terminal(served: Served, job_id: str, timeout: float) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        response = served.http.get(f"/v1/jobs/{job_id}")
        if response.status_code == 200 and response.json()["state"] in harness.TERMINAL:
            return response.json()
        time.sleep(0.2)
    raise AssertionError(f"job {job_id} not finished in {timeout} s:\n{served.log.read_text()}")


def download(served: Served, job_id: str) -> np.ndarray:
    import io

    response = served.http.get(f"/v1/jobs/{job_id}/disparity", params={"format": "npy"})
    assert response.status_code == 200, response.text
    return np.load(io.BytesIO(response.content))


# --- the embedded store is private -------------------------------------------------------------


def test_embedded_redis_needs_its_password_and_keeps_its_files_private(served):
    folder = served.data_dir / "redis"
    for path in [served.data_dir / EMBEDDED_URL_FILE, *folder.iterdir()]:
        assert stat.S_IMODE(path.stat().st_mode) == 0o600, path
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    assert any(path.name.startswith("appendonly") for path in folder.iterdir())
    port = int(served.redis_url.rsplit(":", 1)[1].split("/")[0])
    with pytest.raises(redis.AuthenticationError):
        redis.Redis(port=port).set("qhsm:user:mallory", "admin")
    assert redis.Redis.from_url(served.redis_url).ping()
    password = (folder / "password").read_text().strip()
    assert password in served.redis_url and password not in cmdline(served.redis_pid())
    environ = Path(f"/proc/{served.redis_pid()}/environ").read_bytes()
    assert TOKEN.encode() not in environ and b"DWAVE" not in environ


# --- pricing on serve's own pricing worker (issue 29) --------------------------------------------


def test_serve_prices_estimates_and_metered_jobs_on_its_pricing_worker(served, pair):
    """The embedded default: `qhsm serve` starts a worker for the pricing queue, so an estimate
    (polled by the client, as `qhsm estimate` does) and a metered job's pricing need no other
    process; the job goes pricing -> queued -> running -> succeeded."""
    from api.client import Client

    assert "pricing-" in served.log.read_text() or any(
        f"pricing-{served.process.pid}@" in cmdline(pid) for pid in descendants(served.process.pid)
    )
    client = Client(served.url, key=(served.data_dir / "api-key").read_text().strip())
    params = {"solver": "hybrid-sim", "preset": "paper", "max_disparity": 8, "seed": 3,
              "solver_params": {"max_iter": 1}}  # fmt: skip
    try:
        estimate = client.estimate(pair[0], pair[1], params)
        assert estimate["metered"] and estimate["seconds"] > 0 and estimate["fits"]
        job = client.submit(pair[0], pair[1], params)
        assert job["state"] == "pricing"
        status = wait_terminal(served, job["id"], timeout=180)
    finally:
        client.close()
    assert status["state"] == "succeeded", status["error"]
    assert status["qpu_seconds"] and status["disparity_range"]["max_disparity"] == 8
    assert "GET /v1/estimates/" not in served.log.read_text()  # polls are logged at debug


def test_serve_gives_the_control_queue_a_worker_of_its_own(served):
    """What `qhsm serve` starts: the control queue is consumed by one worker, and only that;
    the pricing queue likewise (estimates and metered jobs' pricing, issue 29)."""
    from workers.app import make_celery

    settings = Settings(redis_url=served.redis_url)
    started = set()  # the Celery workers among serve's children, by their `-n` hostname
    for pid in descendants(served.process.pid):
        args = Path(f"/proc/{pid}/cmdline").read_bytes().decode().split("\0")
        if parent(pid) == served.process.pid and "celery" in args and "-n" in args:
            started.add(args[args.index("-n") + 1])
    celery = make_celery(settings, with_tasks=False)
    replies = celery.control.inspect(timeout=2, destination=sorted(started)).active_queues()
    queues = {name: {queue["name"] for queue in got} for name, got in (replies or {}).items()}
    assert set(queues) == started and len(started) >= 2
    for queue in (settings.control_queue, settings.pricing_queue):
        assert [names for names in queues.values() if queue in names] == [{queue}]
    assert "sa" in set().union(*queues.values())


# --- supervision and the watchdog ----------------------------------------------------------------


def test_a_sigkilled_worker_is_restarted_and_its_job_finishes_identically(served, pair):
    params = harness.one_level(solver="fake-slow", seed=21)
    job_id = submit_and_wait_for_progress(served, pair, params)
    before = resend_count(served.store())
    victim = served.cpu_worker()
    os.kill(victim, signal.SIGKILL)

    status = wait_terminal(served, job_id, timeout=120)
    assert status["state"] == "succeeded", status["error"]
    assert np.array_equal(download(served, job_id), reference(pair, params))
    assert resend_count(served.store()) > before  # the watchdog, not the 6 h visibility timeout
    log = served.log.read_text()
    assert "exited unexpectedly (exit code -9)" in log and "restarted worker cpu-" in log
    assert served.cpu_worker() != victim


def test_a_redis_outage_gives_503_then_the_job_finishes(served, pair):
    params = harness.one_level(solver="fake-slow", seed=22)
    job_id = submit_and_wait_for_progress(served, pair, params)
    os.kill(served.redis_pid(), signal.SIGKILL)
    codes = set()
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline and 503 not in codes:
        response = served.http.get(f"/v1/jobs/{job_id}")
        codes.add(response.status_code)
        if response.status_code == 503:
            assert "Redis" in response.json()["detail"]
    assert 503 in codes and 500 not in codes

    status = wait_terminal(served, job_id, timeout=120)
    assert status["state"] == "succeeded", status["error"]
    assert np.array_equal(download(served, job_id), reference(pair, params))
    assert "restarted embedded redis-server" in served.log.read_text()


# --- qhsm admin on the data directory ------------------------------------------------------------


def test_admin_uses_the_running_serves_store(served, capsys, monkeypatch):
    monkeypatch.delenv("QHSM_REDIS_URL", raising=False)
    monkeypatch.delenv("REDIS_URL", raising=False)
    assert main(["admin", "--data-dir", str(served.data_dir), "list-users"]) == 0
    captured = capsys.readouterr()
    assert "running `qhsm serve`" in captured.err and "local" in captured.out


def test_admin_without_serve_starts_the_data_dirs_store(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("QHSM_REDIS_URL", raising=False)
    monkeypatch.delenv("REDIS_URL", raising=False)
    data_dir = tmp_path / "data"
    assert main(["admin", "--data-dir", str(data_dir), "list-users"]) == 1  # nothing served there
    error = capsys.readouterr().err
    assert f"no store in the data directory {data_dir}" in error and "--data-dir" in error
    assert not data_dir.exists()  # and none was started
    assert main(["admin", "--data-dir", str(data_dir), "create-user", "bob"]) == 0
    assert "store: a NEW, empty store in data dir" in capsys.readouterr().err
    assert main(["admin", "--data-dir", str(data_dir), "list-users"]) == 0
    captured = capsys.readouterr()
    assert "started for this command" in captured.err
    assert "bob" in captured.out  # persisted in the data directory, not some other Redis
    assert not (data_dir / "redis" / PID_FILE).exists()  # and stopped again


def test_admin_says_which_configured_store_it_used(settings, capsys, monkeypatch):
    monkeypatch.setenv("QHSM_KEY_PREFIX", settings.key_prefix)
    assert main(["admin", "--redis-url", settings.redis_url, "list-users"]) == 0
    err = capsys.readouterr().err
    assert f"store: Redis at {safe_url(settings.redis_url)} (from --redis-url)" in err
    password = urlsplit(settings.redis_url).password  # the embedded Redis has one
    assert password is None or (password not in err and ":***@127.0.0.1:" in err)


# --- orphans and the port -------------------------------------------------------------------------


def test_sigkill_of_serve_leaves_no_process_and_serve_starts_again(served):
    children = descendants(served.process.pid)
    assert len(children) >= 4  # redis-server, two workers, pool processes
    served.process.kill()
    served.process.wait()
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline and any(alive(pid) for pid in children):
        time.sleep(0.1)
    assert not [cmdline(pid) for pid in children if alive(pid)]

    again = start_serve(served.data_dir, served.port, served.env, served.log)
    served.process = again
    wait_ready(again, served.url, served.log)
    assert served.http.get("/v1/jobs").status_code == 200  # same store: the key still works


def test_sigterm_of_serve_stops_everything_it_started(served):
    children = descendants(served.process.pid)
    served.process.send_signal(signal.SIGTERM)
    assert served.process.wait(60) in (0, 128 + signal.SIGTERM)  # a clean exit
    assert not [cmdline(pid) for pid in children if alive(pid)]
    assert not (served.data_dir / EMBEDDED_URL_FILE).exists()


@pytest.mark.parametrize("command", ["serve", "demo"])
def test_a_busy_port_fails_before_anything_starts(tmp_path, command):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        started = time.monotonic()
        result = subprocess.run(
            [*QHSM, command, "--port", str(port), "--data-dir", str(tmp_path / "data")],
            env=serve_env(tmp_path),
            capture_output=True,
            text=True,
            timeout=60,
        )
    assert result.returncode != 0
    assert f"qhsm: port {port} on 127.0.0.1 is in use" in result.stderr
    assert "Traceback" not in result.stderr
    assert "starting Redis" not in result.stderr and "API on" not in result.stderr
    assert not (tmp_path / "data" / "redis").exists()
    assert time.monotonic() - started < 30


# --- the embedded Redis itself --------------------------------------------------------------------


def test_a_stale_redis_server_is_stopped_by_the_next_start(tmp_path):
    first = EmbeddedRedis(tmp_path / "redis").start()
    stale = first.process
    first.process = None  # as if its owner had been SIGKILLed without a parent-death signal
    second = EmbeddedRedis(tmp_path / "redis").start()
    try:
        assert stale.wait(10) is not None
        assert redis.Redis.from_url(second.url).ping()
    finally:
        second.stop()


def test_the_aof_is_rewritten_instead_of_growing(tmp_path):
    server = EmbeddedRedis(tmp_path / "redis").start()
    try:
        client = redis.Redis.from_url(server.url)
        blob = os.urandom(1 << 20)
        for i in range(40):  # 40 MB written, all deleted: like job data that comes and goes
            client.set(f"blob:{i}", blob)
            client.delete(f"blob:{i}")
            time.sleep(0.05)  # at the pace of jobs, not faster than a rewrite
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            if client.info("persistence")["aof_rewrite_in_progress"] == 0:
                size = sum(p.stat().st_size for p in (tmp_path / "redis").glob("appendonly*"))
                if size < 12 * 2**20:
                    break
            time.sleep(0.2)
        assert size < 12 * 2**20, f"AOF is {size / 2**20:.1f} MB after 40 MB written and deleted"
    finally:
        server.stop()


def test_ctrl_c_in_demo_is_one_line_and_stops_what_it_started(tmp_path, ctrl_c):
    """Ctrl-C while the demo's job runs: one line, exit 130, Redis and workers gone."""
    env = {k: v for k, v in os.environ.items() if k not in ("QHSM_REDIS_URL", "REDIS_URL")}
    demo = [*QHSM, "demo", "--scene", "synthetic", "--data-dir", str(tmp_path / "data")]
    # the first level line: printed whether or not a poll saw the job still queued
    got = ctrl_c([*demo, "--solver", "sa"], when="level 1/", env=env)
    assert got.returncode == 130 and "Traceback" not in got.stderr
    assert got.last_line == "qhsm: interrupted; stopping the demo's service"
    assert not got.left_processes and not using(tmp_path / "data")
    assert not (tmp_path / "data" / EMBEDDED_URL_FILE).exists()


def test_ctrl_c_stops_serve_and_everything_it_started_in_order(tmp_path, ctrl_c):
    """Ctrl-C reaches serve alone (its children have process groups of their own): no worker or
    Redis stops by itself and gets restarted while serve shuts down."""
    env = {k: v for k, v in os.environ.items() if k not in ("QHSM_REDIS_URL", "REDIS_URL")}
    serve = [*QHSM, "serve", "--port", str(free_port()), "--data-dir", str(tmp_path / "data")]
    got = ctrl_c(serve, when="web page: ", env=env)
    assert got.returncode == 0 and "Traceback" not in got.stderr
    assert "exited unexpectedly" not in got.stderr
    assert got.last_line == "qhsm serve: stopping the workers and Redis ..."
    assert not got.left_processes and not using(tmp_path / "data")
