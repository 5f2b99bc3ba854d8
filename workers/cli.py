"""``qhsm worker``: one Celery worker of a running service, e.g. on a second machine.

A worker needs the service's Redis and nothing else: uploads, level inputs, embeddings and
results all travel through it (``workers/store.py``), so a worker host shares no files with the
API (README: "Adding a worker host"). The Redis URL comes from ``QHSM_REDIS_URL`` only, never
from an option, so its password stays out of the process list.
"""

from __future__ import annotations

import argparse
import os
import socket
import sys

from shared.cli_options import CommandError, setting_option, settings_from_args
from shared.config import Settings


def register(commands: argparse._SubParsersAction) -> None:
    worker = commands.add_parser(
        "worker",
        help="run one worker of the service whose Redis QHSM_REDIS_URL names (any host)",
    )
    worker.add_argument(
        "--queues",
        help="comma-separated queues: 'control' (orchestration), solver queues (`qhsm "
        "solvers`), 'dimod'; default: every solver that runs here without the D-Wave token",
    )
    setting_option(worker, "worker_concurrency", "--concurrency")
    worker.add_argument(
        "--name", help="worker name before '@host' (default: ROLE-PID, e.g. cpu-4242)"
    )
    worker.set_defaults(handler=cmd_worker)


def worker_queues(text: str | None, settings: Settings) -> list[str]:
    """The queues asked for (checked against the known ones), or this machine's CPU ones."""
    from workers.queues import local_queues, solver_queues

    if not text:
        return local_queues()[0]
    queues = [queue.strip() for queue in text.split(",") if queue.strip()]
    known = [settings.control_queue, *solver_queues()]
    unknown = [queue for queue in queues if queue not in known]
    if unknown or not queues:
        raise CommandError(
            f"unknown queue(s) {', '.join(unknown) or '(none given)'}; "
            f"choose from {', '.join(known)}"
        )
    return queues


def cmd_worker(args: argparse.Namespace) -> int:
    from workers.embedded_redis import safe_url
    from workers.queues import token_queues
    from workers.supervisor import DWAVE_SECRETS, worker_command

    settings = settings_from_args(args)
    if settings.redis_url is None:
        raise CommandError(
            "set QHSM_REDIS_URL to the service's Redis (e.g. redis://:PASSWORD@api-host:6379/0); "
            "a worker needs it and nothing else"
        )
    queues = worker_queues(args.queues, settings)
    dwave = bool(token_queues() & set(queues))
    role = "control" if queues == [settings.control_queue] else "dwave" if dwave else "cpu"
    hostname = f"{args.name or f'{role}-{os.getpid()}'}@{socket.gethostname()}"
    concurrency = settings.worker_concurrency or os.cpu_count() or 1
    if role == "control":
        concurrency = args.worker_concurrency or settings.control_concurrency
    elif dwave:  # one shared device: one task at a time keeps its queue fair
        concurrency = args.worker_concurrency or 1
    env = dict(os.environ)
    if not dwave:
        for name in DWAVE_SECRETS:
            env.pop(name, None)
    print(
        f"qhsm worker {hostname}: queues {','.join(queues)}, {concurrency} process(es), "
        f"Redis {safe_url(settings.redis_url)}, key prefix {settings.key_prefix}",
        file=sys.stderr,
        flush=True,
    )
    command = worker_command(hostname, queues, concurrency)
    os.execve(command[0], command, env)  # Celery from here on: its signals, its exit status
    return 0  # pragma: no cover (execve does not return)
