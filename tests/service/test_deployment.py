"""Deployment files, checked without a Docker engine: the compose file parses, every service runs
a real command on real queues, secrets reach only the workers that need them, and everything the
Dockerfile copies exists."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
import yaml
from harness import compose_command

from shared.cli import build_parser
from shared.config import Settings
from shared.solvers import registry
from shared.solvers.records import SolverSpec
from shared.solvers.registry import queue_names

ROOT = Path(__file__).resolve().parents[2]
SERVICES = {
    "redis",
    "api",
    "worker-control",
    "worker-pricing",
    "worker-cpu",
    "worker-gurobi",
    "worker-qpu",
    "worker-hybrid",
    "flower",
}
WORKERS = {name for name in SERVICES if name.startswith("worker-")}


@pytest.fixture(scope="module")
def compose() -> dict:
    return yaml.safe_load((ROOT / "docker-compose.yml").read_text())


def option(command: list[str], flag: str) -> str:
    """The value of ``flag`` in a service's command (a worker's queues derived as it runs)."""
    command = compose_command(command)
    return command[command.index(flag) + 1]


def test_compose_declares_every_role(compose):
    assert set(compose["services"]) == SERVICES
    redis = compose["services"]["redis"]
    assert "--appendonly" in redis["command"] and option(redis["command"], "--appendonly") == "yes"
    volume = redis["volumes"][0].split(":")[0]
    assert volume in compose["volumes"]


def test_services_share_nothing_but_redis(compose):
    """Issue 22: a worker on another host has only Redis in common with the API, so no service
    but Redis mounts a volume (and none is told a shared data directory)."""
    with_volumes = [name for name, s in compose["services"].items() if s.get("volumes")]
    assert with_volumes == ["redis"]
    assert set(compose["volumes"]) == {"redis"}
    assert "QHSM_DATA_DIR" not in (ROOT / "docker-compose.yml").read_text()


def test_every_command_is_a_real_entry_point_on_real_queues(compose):
    subcommands = build_parser()._subparsers._group_actions[0].choices
    queues = set(queue_names()) | {Settings().control_queue, Settings().pricing_queue}
    consumed = set()
    for name, service in compose["services"].items():
        if name == "redis":
            continue
        command = compose_command(service["command"])
        if command[0] == "qhsm":
            assert command[1] in subcommands, f"{name}: no `qhsm {command[1]}` command"
            continue
        if name == "flower":
            assert command[:4] == ["celery", "-A", "workers", "flower"]
            continue
        assert command[:4] == ["celery", "-A", "workers", "worker"], name
        service_queues = option(command, "-Q").split(",")
        assert set(service_queues) <= queues, f"{name}: unknown queues"
        consumed |= set(service_queues)
        assert "container_name" not in service and "ports" not in service  # scalable
    assert {Settings().control_queue, Settings().pricing_queue} <= consumed
    assert {"exact", "sa", "gurobi", "qpu", "hybrid", "dimod"} <= consumed
    assert option(compose["services"]["worker-qpu"]["command"], "-c") == "1"


def unconsumed_queues(compose: dict) -> set[str]:
    """Queues of registered solvers (and ``dimod``) that no worker service of the compose file
    consumes."""
    consumed: set[str] = set()
    for service in compose["services"].values():
        command = compose_command(service.get("command") or [])
        if command[:4] == ["celery", "-A", "workers", "worker"]:
            consumed |= set(option(command, "-Q").split(","))
    return set(queue_names()) - consumed


def test_every_registered_solvers_queue_has_a_worker_service(compose, monkeypatch):
    """Issue 21: the worker services take their queues from the registry, so a solver added to
    it is consumed; one whose group of workers has no service is caught here."""
    assert unconsumed_queues(compose) == set()
    monkeypatch.setattr(registry, "_SPECS", dict(registry._SPECS))
    registry.register(SolverSpec("new-cpu", "shared.solvers.exact:ExactSolver", queue="new-cpu"))
    assert unconsumed_queues(compose) == set()  # a CPU solver: worker-cpu takes its queue
    registry.register(
        SolverSpec("on-gpus", "shared.solvers.exact:ExactSolver", queue="gpu", workers="gpu")
    )
    assert unconsumed_queues(compose) == {"gpu"}  # no worker-gpu service: not consumed


def test_the_dwave_token_reaches_only_qpu_and_hybrid_workers(compose):
    with_token = {
        name
        for name, service in compose["services"].items()
        if "DWAVE_API_TOKEN" in (service.get("environment") or {})
    }
    assert with_token == {"worker-qpu", "worker-hybrid"}
    text = (ROOT / "docker-compose.yml").read_text()
    assert not re.search(r"DWAVE_API_TOKEN:[ \t]*[^\s#]", text), (
        "a token value is written in the file"
    )


def test_dockerfile_copies_existing_files_and_runs_a_real_command():
    lines = (ROOT / "Dockerfile").read_text().splitlines()
    copies = [shlex.split(line)[1:-1] for line in lines if line.startswith("COPY ")]
    assert copies
    for sources in copies:
        for source in sources:
            assert (ROOT / source).exists(), f"Dockerfile copies missing {source}"
    cmd = next(line for line in lines if line.startswith("CMD "))
    assert '"qhsm", "api"' in cmd
    ignored = (ROOT / ".dockerignore").read_text().split()
    assert "data" in ignored and ".git" in ignored


def test_orchestration_has_a_worker_of_its_own(compose):
    control = Settings().control_queue
    consumers = {
        name: option(compose["services"][name]["command"], "-Q").split(",") for name in WORKERS
    }
    assert [name for name, queues in consumers.items() if control in queues] == ["worker-control"]
    assert consumers["worker-control"] == [control]


def test_every_worker_has_a_ping_health_check(compose):
    for name in WORKERS:
        service = compose["services"][name]
        node = option(service["command"], "-n").replace("%h", "$$HOSTNAME")
        check = service["healthcheck"]["test"]
        assert check[0] == "CMD-SHELL", name
        assert f"celery -A workers inspect ping -d {node}" in check[1], name
        assert service["healthcheck"]["retries"] >= 1


def test_flower_is_an_opt_in_profile_on_task_events(compose):
    from workers.app import celery_config

    flower = compose["services"]["flower"]
    assert flower["profiles"] == ["monitoring"]
    assert all(port.startswith("127.0.0.1:") for port in flower["ports"])  # Flower has no login
    assert not [
        name for name, s in compose["services"].items() if name != "flower" and "profiles" in s
    ]
    config = celery_config(Settings())
    assert config["worker_send_task_events"] and config["task_send_sent_event"]
    assert "flower" in (ROOT / "pyproject.toml").read_text()
    assert re.search(r"\.\[[a-z,]*\bmonitoring\b", (ROOT / "Dockerfile").read_text())


def test_a_worker_reads_the_settings_its_app_was_made_with():
    """Settings are read from the environment once and passed down: the app carries them (also
    through a pickle, where Celery rebuilds it with its own keywords only) and the worker's
    context (``workers.context``) is built from the app's."""
    import pickle

    from workers import tasks
    from workers.app import app, make_celery

    settings = Settings(key_prefix="qhsm-settings-test", task_retries=7)
    celery = make_celery(settings, with_tasks=False)
    assert celery.qhsm_settings is settings
    assert pickle.loads(pickle.dumps(celery)).qhsm_settings.key_prefix == Settings().key_prefix
    assert tasks.current().settings is app.qhsm_settings
