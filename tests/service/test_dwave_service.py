"""The real ``qpu`` and ``hybrid`` adapters end to end through the service, offline: a local
stand-in for D-Wave's Solver API (``sapi_stub``) that dwave-cloud-client talks to through
``DWAVE_API_ENDPOINT``, with the API token set to a sentinel. Two deployments: ``qhsm serve``
(its control and CPU workers never get the token) and the compose file's worker split (each
worker with the queues and environment docker-compose.yml gives it). Each job must succeed,
give exactly the in-process run's disparity with the same sampler, and be charged what the
sample sets report; the token appears in no response, log line or Redis value.

Kept small (an 8x20 pair, one level, 10 reads): the stub anneals every problem it gets."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import harness
import httpx
import numpy as np
import pytest
import redis
import yaml
from sapi_stub import HYBRID_CHARGE_US, SapiStub, qpu_access_us

from shared.config import LevelConfig, MatchConfig, Settings
from shared.images import decode_image
from shared.pipeline import run_pipeline
from shared.solvers import registry
from shared.solvers.qpu import embedding_cache
from shared.synthetic import make_scene
from workers.embedded_redis import free_port

pytestmark = pytest.mark.service

SENTINEL = "DEV-sentinel-20-never-print-me"
ROOT = Path(__file__).parents[2]
SCENE = make_scene(8, 20, max_disparity=4, seed=5)
#: The pair as uploaded (8-bit PNG), and as the service decodes it.
UPLOADS = harness.png(SCENE.left), harness.png(SCENE.right)
VIEWS = [decode_image(data, name) for data, name in zip(UPLOADS, ("left", "right"), strict=True)]
READS = 10
PARAMS = {
    "preset": "paper",
    "levels": [LevelConfig(downsample=1, candidates=3).model_dump()],
    "max_disparity": 4,
    "median": False,
    "bilateral": False,
    "encoding": "domain-wall",
    "seed": 7,
}
#: Roof duality would solve this small pair's rows on the host: off, so that problems are sent.
JOBS = {
    "qpu": {**PARAMS, "solver": "qpu",
            "solver_params": {"num_reads": READS, "preprocess": "none"}},
    "hybrid": {**PARAMS, "solver": "hybrid", "solver_params": {"preprocess": "none"}},
}  # fmt: skip


@pytest.fixture(scope="module")
def sapi():
    stub = SapiStub(token=SENTINEL).start()
    yield stub
    stub.stop()


def leap_env(stub: SapiStub) -> dict[str, str]:
    return {"DWAVE_API_TOKEN": SENTINEL, "DWAVE_API_ENDPOINT": stub.endpoint}


def in_process(solver: str, stub: SapiStub, store, monkeypatch) -> np.ndarray:
    """The job's disparity matched in this process with the same sampler and embeddings."""
    for name, value in leap_env(stub).items():
        monkeypatch.setenv(name, value)
    monkeypatch.setattr(registry, "_INSTANCES", {})  # adapters built with this environment
    monkeypatch.setattr(embedding_cache, "_default_cache", embedding_cache.EmbeddingCache(store))
    config = MatchConfig.model_validate(JOBS[solver])
    return run_pipeline(*VIEWS, config).disparity


def run_job(client, solver: str) -> tuple[dict, np.ndarray]:
    job_id = harness.submit(client, *UPLOADS, JOBS[solver])
    status = harness.wait_for(client, job_id, timeout=240)
    assert status["state"] == "succeeded", status
    return status, harness.download(client, job_id)


def usage_of(client, job_id: str) -> dict:
    [entry] = [
        job for user in client.get("/v1/usage").json()["users"] for job in user["jobs"]
        if job["id"] == job_id
    ]  # fmt: skip
    return entry


def charged(client, job_id: str) -> float:
    return usage_of(client, job_id)["qpu_seconds"]


def check_job(client, stub: SapiStub, solver: str, expected: np.ndarray) -> None:
    """Succeeds, equals the in-process run, is charged from the sample sets' timing."""
    before = len(stub.problems)
    status, disparity = run_job(client, solver)
    assert np.array_equal(disparity, expected)
    problems = stub.problems[before:]
    bundles = status["levels"][0]["bundles"]
    assert bundles == SCENE.left.shape[0]  # whole rows
    # qpu: several rows per QPU call (disjoint copies of the row's embedding); hybrid: the
    # level's rows as one BQM
    assert 1 <= len(problems) < bundles
    if solver == "hybrid":
        assert len(problems) == 1
    per_problem = (qpu_access_us(READS) if solver == "qpu" else HYBRID_CHARGE_US) * 1e-6
    assert charged(client, status["id"]) == pytest.approx(len(problems) * per_problem)
    # on Leap each problem is labelled with its task and number; its id is kept with the job
    label = re.compile(rf"qhsm job {status['id']} level 1 bundle \S+ #\d+")
    assert all(label.fullmatch(problem["label"] or "") for problem in problems), problems
    ids = sorted(problem["id"] for problem in problems)
    kept = usage_of(client, status["id"])["problem_ids"]
    assert sorted(status["problem_ids"]) == ids == sorted(kept)
    assert SENTINEL not in json.dumps(status)


def no_token_in_redis(url: str, prefix: str) -> None:
    client = redis.Redis.from_url(url)
    for key in client.scan_iter(match=f"{prefix}:*", count=1000):
        kind = client.type(key).decode()
        values = {
            "string": lambda k: [client.get(k)],
            "hash": lambda k: list(client.hgetall(k).values()),
            "list": lambda k: client.lrange(k, 0, -1),
            "set": lambda k: list(client.smembers(k)),
            "zset": lambda k: [m for m, _ in client.zrange(k, 0, -1, withscores=True)],
        }.get(kind, lambda k: [])(key)
        assert not any(SENTINEL.encode() in (value or b"") for value in values), key


# --- qhsm serve -------------------------------------------------------------------------------


@contextmanager
def qhsm_serve(folder: Path, stub: SapiStub):
    """`qhsm serve` with the token and the stub's endpoint in its environment."""
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("QHSM_", "REDIS_URL"))}
    env.update(leap_env(stub))
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), str(Path(__file__).parent)])
    log = folder / "serve.log"
    command = [
        sys.executable, "-m", "shared.cli", "serve", "--host", "127.0.0.1", "--port", str(port),
        "--data-dir", str(folder / "data"), "--concurrency", "1",
    ]  # fmt: skip
    with log.open("wb") as out:
        process = subprocess.Popen(command, env=env, stdout=out, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"
    # SIGKILL at the end (serve's workers and Redis die with it): serve's orderly stop is
    # test_serve.py's, and took 10-12 s here
    with harness.killed_at_exit(process):
        deadline = time.monotonic() + 120
        while not re.search(r"web page: ", log.read_text()):
            assert process.poll() is None, log.read_text()[-3000:]
            assert time.monotonic() < deadline, log.read_text()[-3000:]
            time.sleep(0.2)
        key = (folder / "data" / "api-key").read_text().strip()
        headers = {"Authorization": f"Bearer {key}"}
        # 30 s, not httpx's 5: on a loaded machine a first /healthz took longer (a ReadTimeout)
        with httpx.Client(base_url=url, headers=headers, timeout=30) as client:
            while client.get("/healthz").status_code != 200:
                time.sleep(0.2)
            yield client, log, folder / "data"


def test_qpu_and_hybrid_jobs_run_through_qhsm_serve_with_the_token(sapi, tmp_path, monkeypatch):
    """Under `qhsm serve` only the D-Wave worker has the token; a qpu job's level planning
    (the QPU graph, the widest segment that embeds, the embeddings) runs there too."""
    from workers.embedding_store import RedisEmbeddingStore

    with qhsm_serve(tmp_path, sapi) as (client, log, data):
        url = (data / "redis-url").read_text().strip()
        store = RedisEmbeddingStore(redis.Redis.from_url(url), prefix="qhsm:embedding:")
        for solver in ("qpu", "hybrid"):
            check_job(client, sapi, solver, in_process(solver, sapi, store, monkeypatch))
        no_token_in_redis(url, "qhsm")
    text = log.read_text()
    assert "dwave-" in text and SENTINEL not in text
    for worker_log in (data / "logs").glob("*.log"):
        assert SENTINEL not in worker_log.read_text(), worker_log
    assert sapi.tokens_seen == {SENTINEL}


# --- the compose file's worker split ----------------------------------------------------------


def compose_workers() -> dict[str, tuple[list[str], bool]]:
    """Worker services of docker-compose.yml: (queues, whether they get the D-Wave token)."""
    compose = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
    workers = {}
    for name, service in compose["services"].items():
        command = harness.compose_command(service.get("command") or [])
        if command[:4] != ["celery", "-A", "workers", "worker"]:
            continue
        queues = command[command.index("-Q") + 1].split(",")
        environment = service.get("environment") or {}
        workers[name] = (queues, "DWAVE_API_TOKEN" in environment)
    return workers


def test_qpu_and_hybrid_jobs_run_on_the_compose_files_worker_split(
    sapi, tmp_path, monkeypatch, redis_url
):
    """The workers of docker-compose.yml these jobs need, with their queues and only the
    environment the file gives them (the token to worker-qpu and worker-hybrid alone), against
    the same stub."""
    from workers.app import make_celery
    from workers.embedding_store import for_settings
    from workers.supervisor import WorkerProcess, wait_for_workers, worker_env

    url = redis_url
    settings = Settings(
        redis_url=url,
        key_prefix=harness.unique_prefix(),
        data_dir=tmp_path / "data",
        inspect_timeout=0.5,
        max_active_jobs_per_user=None,
    )
    split = compose_workers()
    assert {queues[0] for queues, _ in split.values()} >= {"control", "pricing", "qpu", "hybrid"}
    assert [name for name, (_, token) in split.items() if token] == ["worker-qpu", "worker-hybrid"]
    started = []
    try:
        needed = {"control", "pricing", "qpu", "hybrid"}  # a metered job is priced first
        for name, (queues, token) in split.items():
            if not needed & set(queues):
                continue
            env = worker_env(settings, url, dwave=False)
            env["PYTHONPATH"] = os.pathsep.join([str(ROOT), str(Path(__file__).parent)])
            env["QHSM_DATA_DIR"] = str(tmp_path / name)  # its own, as in its container
            if token:
                env.update(leap_env(sapi))
            tag = f"{name}-{settings.key_prefix}"
            worker = WorkerProcess(tag, queues, 1, env, tmp_path / "logs" / f"{name}.log")
            started.append(worker.start())
        wait_for_workers(make_celery(settings, with_tasks=False), [w.hostname for w in started])
        store = for_settings(settings, redis.Redis.from_url(url, decode_responses=True))
        with harness.api_client(settings) as client:
            for solver in ("qpu", "hybrid"):
                check_job(client, sapi, solver, in_process(solver, sapi, store, monkeypatch))
        no_token_in_redis(url, settings.key_prefix)
        for worker in started:
            assert SENTINEL not in worker.log_file.read_text()
        for name in split:  # the workers shared nothing with the API but Redis
            assert not (tmp_path / name).exists() or not any((tmp_path / name).iterdir())
    finally:
        harness.stop_workers(started)
        harness.drop_prefix(url, settings.key_prefix)


def test_the_stub_refuses_another_token(sapi):
    """The stand-in checks the token as SAPI does, so the tests above prove it got through."""
    response = httpx.get(f"{sapi.endpoint}solvers/remote/", headers={"X-Auth-Token": "wrong"})
    assert response.status_code == 401 and "Invalid token" in response.text
