"""Leap traceability and clear failures of the real ``qpu`` and ``hybrid`` adapters, offline:
every problem carries the task's label with its number, the ids SAPI returns are logged; an
unreachable or refusing endpoint is a transient error that names the endpoint and the cause,
a refused token a final one, also while a level is planned (no solve yet)."""

from __future__ import annotations

import json
import socket
import threading
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import dimod
import pytest
from dwave.cloud import Client
from solver_helpers import stereo_costs
from test_dimod_conformance import CLOUD_MOCKS

from shared.encodings import get_codec
from shared.solvers import SolverError, SolverUnavailableError, TransientSolverError, registry
from shared.solvers.qpu.problems import DEFAULT_LABEL, sent_problems, task_label

#: A triangle of antiferromagnetic couplings: roof duality fixes nothing, so it is sent.
FRUSTRATED = dimod.BinaryQuadraticModel(
    {}, {("a", "b"): 1.0, ("b", "c"): 1.0, ("a", "c"): 1.0}, 0.0, dimod.SPIN
)


@pytest.fixture
def token(monkeypatch):
    monkeypatch.setenv("DWAVE_API_TOKEN", "test-token")


@pytest.mark.parametrize("name", ["qpu", "hybrid"])
def test_every_problem_carries_the_tasks_label_and_its_id_is_kept(name, token):
    """Ocean's mocks (MockDWaveSampler, MockLeapHybridSolver behind a mocked client) see the
    label; the ids they return are the task's, in order."""
    labels: list[str] = []
    with CLOUD_MOCKS[name]() as mocked:
        solver = registry.build(name)
        spy = _spy_labels(solver, labels, mocked)
        with sent_problems(task_label("c0ffee", 1, "12")) as log:
            for _ in range(2):
                solver.sample(FRUSTRATED, preprocess="none")
        solver.sample(FRUSTRATED, preprocess="none")  # outside any task
    assert labels == [
        "qhsm job c0ffee level 2 bundle 12 #1",
        "qhsm job c0ffee level 2 bundle 12 #2",
        DEFAULT_LABEL,
    ]
    assert len(log.ids) == 2 and len(set(log.ids)) == 2 and all(log.ids), spy


def _spy_labels(solver, labels: list[str], mocked) -> str:
    """Record the label of every problem the adapter's base sampler is given."""
    if solver.name == "qpu":
        base = solver.sampler()._child  # the MockDWaveSampler under the labelling wrapper
        original = base.sample

        def sample(bqm, **params):
            labels.append(params["label"])
            return original(bqm, **params)

        base.sample = sample
        return "qpu"
    hybrid = mocked.from_config.return_value.get_solver.return_value
    hybrid.labels = labels  # LabelledMockLeapHybridSolver keeps them
    return "hybrid"


def _closed_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture
def refusing_sapi() -> Iterator[callable]:
    """A local endpoint answering every request with the given HTTP status."""
    status = {"code": 503}

    class Handler(BaseHTTPRequestHandler):
        def log_message(self, *args) -> None:
            pass

        def do_GET(self) -> None:
            body = json.dumps({"error_code": status["code"], "error_msg": "stub says no"}).encode()
            self.send_response(status["code"])
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()

    def endpoint(code: int) -> str:
        status["code"] = code
        return f"http://127.0.0.1:{server.server_address[1]}/sapi/v2/"

    yield endpoint
    server.shutdown()
    server.server_close()


@pytest.fixture
def no_client_retries(monkeypatch):
    """dwave-cloud-client's own HTTP retries off (10 by default): the service retries tasks."""
    monkeypatch.setitem(Client.DEFAULTS, "http_retry_total", 0)


def _plan(solver) -> None:
    """What planning a level asks of the solver before any bundle is solved."""
    if solver.name == "qpu":
        solver.widest_bundle(encoding="domain-wall", candidates=4, height=3, row_width=40, margin=2)
    else:
        solver.solve(get_codec("domain-wall").encode(stereo_costs(1, 3)), preprocess="none")


@pytest.mark.parametrize("name", ["qpu", "hybrid"])
@pytest.mark.parametrize(
    ("how", "cause"),
    [("unreachable", "ConnectionRefusedError"), ("503", "InternalServerError: stub says no")],
)
def test_an_endpoint_that_cannot_be_reached_or_refuses_is_a_transient_error_naming_it(
    name, how, cause, token, monkeypatch, refusing_sapi, no_client_retries
):
    if how == "unreachable":
        endpoint = f"http://127.0.0.1:{_closed_port()}/sapi/v2/"
    else:
        endpoint = refusing_sapi(int(how))
    monkeypatch.setenv("DWAVE_API_ENDPOINT", endpoint)
    with pytest.raises(TransientSolverError) as caught:
        _plan(registry.build(name))
    message = str(caught.value)
    assert message.startswith(f"{name}: ") and f"endpoint {endpoint}" in message
    assert cause in message and "retry later" in message


@pytest.mark.parametrize("name", ["qpu", "hybrid"])
def test_a_refused_token_fails_at_once(name, token, monkeypatch, refusing_sapi, no_client_retries):
    monkeypatch.setenv("DWAVE_API_ENDPOINT", refusing_sapi(401))
    with pytest.raises(SolverError) as caught:
        _plan(registry.build(name))
    assert type(caught.value) is SolverUnavailableError  # not transient: never retried
    assert "rejected the API token" in str(caught.value)


def test_planning_retries_an_unreachable_endpoint_with_backoff_then_fails_naming_it(
    token, monkeypatch, no_client_retries
):
    """The issue's case: a qpu job whose planning could not reach D-Wave failed at once as an
    "internal error". The planning task now retries (eagerly here: no waiting) and then fails
    the job with the endpoint and the cause."""
    from workers import orchestration, tasks
    from workers.context import WorkerContext

    endpoint = f"http://127.0.0.1:{_closed_port()}/sapi/v2/"
    monkeypatch.setenv("DWAVE_API_ENDPOINT", endpoint)
    attempts: list[int] = []

    def plan(store, job_id, index):
        attempts.append(index)
        _plan(registry.build("qpu"))

    failed: list[str] = []
    monkeypatch.setattr(orchestration, "plan_level", plan)
    monkeypatch.setattr(tasks, "_fail", lambda ctx, job_id, message, *_: failed.append(message))
    settings = tasks.current().settings.model_copy(update={"task_retries": 2})
    context = WorkerContext(settings, _store=object())  # the planning is replaced: no Redis
    monkeypatch.setattr(tasks, "current", lambda: context)
    delays: list[float] = []
    backoff = orchestration.retry_delay
    monkeypatch.setattr(
        orchestration, "retry_delay", lambda s, n: delays.append(backoff(s, n)) or delays[-1]
    )
    tasks.plan_level.apply(args=("job", 0))
    assert len(attempts) == 3 and delays == sorted(delays) and delays[1] == 2 * delays[0]
    [message] = failed
    assert f"endpoint {endpoint}" in message and "ConnectionRefusedError" in message
    assert "still failing after 2 retries" in message and "internal error" not in message
