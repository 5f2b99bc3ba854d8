"""`qhsm serve`'s start (``Stack.launch`` / ``Stack.wait_ready``, ``wait_for_workers``,
``cmd_serve``) on stand-ins (no Redis, no Celery): the workers boot at once and are waited for
with one shared deadline; one that exits while booting fails the start at once with the end of
its log; serve builds its API while the workers boot and serves only once they all answer."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from shared.cli_options import CommandError
from workers.supervisor import WorkerProcess, WorkerStartError, wait_for_workers

#: A stand-in for a Celery worker still booting (it never answers the fake inspect).
BOOTING = "import time\nwhile True:\n    time.sleep(0.05)"
#: One that dies at start-up as a worker with a broken import does.
BROKEN = "import sys\nprint('ModuleNotFoundError: No module named boom', flush=True)\nsys.exit(3)"


def stand_in(folder: Path, name: str, code: str) -> WorkerProcess:
    worker = WorkerProcess(name, [name], 1, {}, folder / f"{name}.log")
    with worker.log_file.open("wb") as out:
        worker.process = subprocess.Popen(
            [sys.executable, "-c", code], stdout=out, stderr=subprocess.STDOUT
        )
    return worker


class FakeCelery:
    """``celery.control.inspect(...).active_queues()``: a worker answers from its ready time
    (seconds after the fake was made) on; ``None`` never."""

    def __init__(self, ready: dict[str, float | None]) -> None:
        self.ready = ready
        self.started = time.monotonic()
        self.control = self

    def inspect(self, timeout: float, destination: list[str]) -> FakeCelery:
        self.destination = destination
        return self

    def active_queues(self) -> dict[str, list]:
        now = time.monotonic() - self.started
        return {
            name: [] for name in self.destination
            if self.ready.get(name) is not None and self.ready[name] <= now
        }  # fmt: skip


def test_workers_ready_at_different_times_share_one_deadline():
    """Three workers ready 0.4, 0.8 and 1.2 s in: all within a 2 s deadline, which a deadline
    each after the previous one's readiness (sequential starts) would not meet."""
    celery = FakeCelery({"a": 0.4, "b": 0.8, "c": 1.2})
    started = time.monotonic()
    wait_for_workers(celery, ["a", "b", "c"], timeout=2.0)
    assert 1.2 <= time.monotonic() - started < 2.0


def test_the_deadline_names_only_the_workers_still_missing():
    celery = FakeCelery({"a": 0.0, "b": None})
    started = time.monotonic()
    with pytest.raises(RuntimeError, match=r"did not come up in 1 s: \['b'\]"):
        wait_for_workers(celery, ["a", "b"], timeout=1.0)
    assert time.monotonic() - started >= 1.0


def test_a_worker_that_exits_while_booting_fails_the_wait_at_once(tmp_path):
    booting = stand_in(tmp_path, "cpu", BOOTING)
    broken = stand_in(tmp_path, "control", BROKEN)
    celery = FakeCelery({})
    started = time.monotonic()
    try:
        with pytest.raises(WorkerStartError) as failure:
            wait_for_workers(
                celery, [booting.hostname, broken.hostname], 60.0, started=[booting, broken]
            )
        assert time.monotonic() - started < 10  # not the 60 s deadline
        message = str(failure.value)
        assert broken.hostname in message and "exit code 3" in message
        assert "No module named boom" in message and str(broken.log_file) in message
        assert booting.hostname not in message
    finally:
        booting.kill()


class Recorder:
    """Stands in for ``Stack`` and the API server in ``cmd_serve``, recording the calls."""

    def __init__(self, fail_wait: Exception | None = None) -> None:
        self.calls: list[str] = []
        self.fail_wait = fail_wait

    def stack(self, settings, concurrency=None) -> Recorder:
        self.settings = settings
        return self

    def launch(self) -> Recorder:
        self.calls.append("launch")
        return self

    def wait_ready(self) -> Recorder:
        self.calls.append("wait_ready")
        if self.fail_wait is not None:
            raise self.fail_wait
        return self

    def stop(self) -> None:
        self.calls.append("stop")

    def describe(self) -> str:
        return "stand-in stack"

    def server(self, settings, log_level, cleanup) -> Recorder:
        self.calls.append("build api")
        return self

    def run(self, sockets) -> None:
        self.calls.append("serve")


def run_serve(monkeypatch, tmp_path, recorder: Recorder) -> None:
    import api.server
    import workers.supervisor
    from api import serve_cli
    from shared.cli import build_parser
    from workers.embedded_redis import free_port

    monkeypatch.setattr(workers.supervisor, "Stack", recorder.stack)
    monkeypatch.setattr(api.server, "stoppable_server", recorder.server)
    monkeypatch.setattr(serve_cli, "announce_web_page", lambda settings, url: None)
    arguments = ["serve", "--port", str(free_port()), "--data-dir", str(tmp_path)]
    serve_cli.cmd_serve(build_parser().parse_args(arguments))


def test_serve_builds_its_api_while_the_workers_boot_and_serves_once_they_answer(
    monkeypatch, tmp_path
):
    recorder = Recorder()
    run_serve(monkeypatch, tmp_path, recorder)
    assert recorder.calls == ["launch", "build api", "wait_ready", "serve", "stop"]


def test_serve_reports_a_worker_that_died_while_booting_and_stops_the_rest(monkeypatch, tmp_path):
    worker = stand_in(tmp_path, "control", BROKEN)
    worker.process.wait()
    recorder = Recorder(fail_wait=WorkerStartError(worker))
    with pytest.raises(CommandError, match=r"(?s)exited at start-up .*No module named boom"):
        run_serve(monkeypatch, tmp_path, recorder)
    assert recorder.calls == ["launch", "build api", "wait_ready", "stop"]  # never served
