"""A local stand-in for D-Wave's Solver API (SAPI), so that the real ``qpu`` and ``hybrid``
adapters (DWaveSampler, LeapHybridSampler, dwave-cloud-client's HTTP client) run end to end
offline: point ``DWAVE_API_ENDPOINT`` at :attr:`SapiStub.endpoint`.

It serves what those clients ask for: the solver list (dwave-cloud-client's own mock data: a
Pegasus P16 Advantage with its published timing data, and a hybrid BQM solver), problem
submission with the answer in the response (``qp`` answers for the QPU, ``bq`` sample sets for
the hybrid solver), status polls, and the multipart BQM upload the hybrid solver uses. Answers
are deterministic (simulated annealing seeded by the problem's bytes), so the same problem gets
the same answer in any process, and each carries the timing a real solver reports, which is what
the service charges. It checks the token on every request (401 otherwise) and records each
problem (:attr:`SapiStub.problems`) and every token it was sent.
"""

from __future__ import annotations

import base64
import hashlib
import io
import json
import threading
import traceback
import uuid
import zlib
from dataclasses import dataclass, field
from datetime import UTC, datetime
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any
from urllib.parse import parse_qs, urlsplit

import dimod
import numpy as np
from dwave.cloud.solver import StructuredSolver
from dwave.cloud.testing import mocks
from dwave.samplers import SimulatedAnnealingSampler

QPU_NAME = "Advantage_stub"
HYBRID_NAME = "hybrid_binary_quadratic_model_stub"
#: Microseconds a QPU problem takes: fixed overhead plus per read (SAPI's own fields).
QPU_PROGRAMMING_US, QPU_PER_READ_US = 15_000.0, 100.0
#: What the hybrid solver bills, microseconds (Leap's ``charge_time``).
HYBRID_CHARGE_US, HYBRID_QPU_US = 2_990_000, 40_123


def qpu_data() -> dict:
    data = mocks.qpu_pegasus_solver_data(16, name=QPU_NAME, graph_id="stub-graph")
    data["properties"]["problem_timing_data"] = mocks.qpu_problem_timing_data("advantage")
    data["properties"]["parameters"].update(
        {name: "" for name in ("annealing_time", "initial_state", "reinitialize_state")}
    )
    data["avg_load"] = 0.0
    return data


def hybrid_data() -> dict:
    data = mocks.hybrid_bqm_solver_data(name=HYBRID_NAME)
    data["avg_load"] = 0.0
    return data


def qpu_access_us(num_reads: int) -> float:
    """The ``qpu_access_time`` the stub reports for a problem of ``num_reads`` reads."""
    return QPU_PROGRAMMING_US + QPU_PER_READ_US * num_reads


def _b64(array: np.ndarray) -> str:
    return base64.b64encode(array.tobytes()).decode("ascii")


def _now() -> str:
    return datetime.now(UTC).isoformat()


def _anneal(bqm: dimod.BinaryQuadraticModel, seed_bytes: bytes, reads: int) -> dimod.SampleSet:
    """Deterministic samples: annealing seeded by the problem's own bytes."""
    seed = zlib.crc32(seed_bytes) % 2**31  # dwave-samplers takes seeds below 2^32 - 1
    return SimulatedAnnealingSampler().sample(bqm, num_reads=reads, num_sweeps=200, seed=seed)


@dataclass
class SapiStub:
    """The HTTP server (a daemon thread) and what it saw."""

    token: str
    problems: list[dict[str, Any]] = field(default_factory=list)
    tokens_seen: set[str] = field(default_factory=set)
    _uploads: dict[str, dict[int, bytes]] = field(default_factory=dict)
    _answers: dict[str, dict] = field(default_factory=dict)
    _server: ThreadingHTTPServer | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def __post_init__(self) -> None:
        self.qpu = qpu_data()
        self.hybrid = hybrid_data()
        self._qpu_solver = StructuredSolver(data=self.qpu, client=None)

    @property
    def endpoint(self) -> str:
        assert self._server is not None
        host, port = self._server.server_address[:2]
        return f"http://{host}:{port}/sapi/v2/"

    def start(self) -> SapiStub:
        stub = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args: Any) -> None:  # quiet
                pass

            def do_GET(self) -> None:
                stub._handle(self, "GET")

            def do_POST(self) -> None:
                stub._handle(self, "POST")

            def do_PUT(self) -> None:
                stub._handle(self, "PUT")

            def do_DELETE(self) -> None:
                stub._handle(self, "DELETE")

        self._server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        threading.Thread(target=self._server.serve_forever, daemon=True).start()
        return self

    def stop(self) -> None:
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None

    # --- requests ---------------------------------------------------------------------------

    def _handle(self, request: BaseHTTPRequestHandler, method: str) -> None:
        token = request.headers.get("X-Auth-Token", "")
        with self._lock:
            self.tokens_seen.add(token)
        body = self._body(request)
        encoding = request.headers.get("Content-Encoding", "")
        if encoding in ("deflate", "gzip"):  # the client compresses problem submissions
            body = zlib.decompress(body, 47 if encoding == "gzip" else 15)
        accept = request.headers.get("Accept", "").split(",")[0].strip()
        kind = accept if accept.startswith("application/vnd.dwave") else "application/json"
        if token != self.token:
            answer = {"error_code": 401, "error_msg": "Invalid token"}
            return self._reply(request, 401, answer, "application/json")
        url = urlsplit(request.path)
        path = url.path.removeprefix("/sapi/v2/").strip("/")
        query = parse_qs(url.query)
        try:
            status, answer = self._route(method, path, query, body)
        except Exception as error:  # a bug here: say it in the reply, as SAPI would
            traceback.print_exc()
            status, answer = 500, {"error_code": 500, "error_msg": f"stub: {error!r}"}
        self._reply(request, status, answer, kind)

    @staticmethod
    def _body(request: BaseHTTPRequestHandler) -> bytes:
        """The request body, sized or chunked (the client streams upload parts)."""
        if request.headers.get("Transfer-Encoding", "").lower() == "chunked":
            data = b""
            while size := int(request.rfile.readline().split(b";")[0].strip() or b"0", 16):
                data += request.rfile.read(size)
                request.rfile.readline()
            request.rfile.readline()
            return data
        length = int(request.headers.get("Content-Length") or 0)
        return request.rfile.read(length) if length else b""

    @staticmethod
    def _reply(request: BaseHTTPRequestHandler, status: int, answer: Any, kind: str) -> None:
        """The answer as JSON, in the media type (and version) the client asked for."""
        payload = json.dumps(answer).encode()
        request.send_response(status)
        request.send_header("Content-Type", kind)
        request.send_header("Content-Length", str(len(payload)))
        request.end_headers()
        request.wfile.write(payload)

    def _route(self, method: str, path: str, query: dict, body: bytes) -> tuple[int, Any]:
        parts = path.split("/")
        if parts[:2] == ["solvers", "remote"]:
            solvers = {QPU_NAME: self.qpu, HYBRID_NAME: self.hybrid}
            if len(parts) == 2:
                return 200, list(solvers.values())
            return (200, solvers[parts[2]]) if parts[2] in solvers else (404, {})
        if parts[0] == "problems":
            if method == "POST":
                problems = json.loads(body)
                if isinstance(problems, dict):
                    return 200, self._solve(problems)
                return 200, [self._solve(problem) for problem in problems]
            if len(parts) > 1 and parts[1]:
                return 200, self._answers[parts[1]]
            ids = ",".join(query.get("id", [""])).split(",")
            return 200, [self._status(self._answers[i]) for i in ids if i in self._answers]
        if parts[:2] == ["bqm", "multipart"]:
            return self._upload(method, parts[2:], body)
        return 404, {"error_code": 404, "error_msg": f"stub: no route {method} {path}"}

    def _upload(self, method: str, parts: list[str], body: bytes) -> tuple[int, Any]:
        if not parts:  # initiate
            upload = uuid.uuid4().hex
            self._uploads[upload] = {}
            return 200, {"id": upload}
        upload = parts[0]
        if parts[1:] == ["status"]:
            chunks = self._uploads[upload]
            uploaded = [
                {"part_number": number, "checksum": hashlib.md5(data).hexdigest()}
                for number, data in sorted(chunks.items())
                if number >= 0
            ]
            done = -1 in chunks
            return 200, {
                "status": "UPLOAD_COMPLETED" if done else "UPLOAD_IN_PROGRESS",
                "parts": uploaded,
            }
        if parts[1] == "part" and method == "PUT":
            self._uploads[upload][int(parts[2])] = body
            return 200, {}
        if parts[1:] == ["combine"]:
            chunks = self._uploads[upload]
            chunks[-1] = b"".join(chunks[number] for number in sorted(chunks) if number >= 0)
            return 200, {}
        return 404, {}

    # --- problems ---------------------------------------------------------------------------

    def _solve(self, problem: dict) -> dict:
        kind, params = problem["type"], problem.get("params", {})
        if kind in ("ising", "qubo"):
            answer = self._qpu_answer(kind, problem["data"], params)
            solver = QPU_NAME
        else:
            answer = self._hybrid_answer(problem["data"], params)
            solver = HYBRID_NAME
        problem_id = uuid.uuid4().hex
        message = {
            "id": problem_id,
            "type": kind,
            "status": "COMPLETED",
            "solver": solver,
            "submitted_on": _now(),
            "solved_on": _now(),
            "answer": answer,
        }
        with self._lock:
            digest = zlib.crc32(json.dumps(problem["data"], sort_keys=True).encode())
            self.problems.append(
                {
                    "id": problem_id,
                    "type": kind,
                    "params": params,
                    "data": digest,
                    "label": problem.get("label"),
                }
            )
            self._answers[problem_id] = message
        return message

    @staticmethod
    def _status(message: dict) -> dict:
        return {key: value for key, value in message.items() if key != "answer"}

    def _qpu_answer(self, kind: str, data: dict, params: dict) -> dict:
        bqm = self._decode_qp(data, dimod.SPIN if kind == "ising" else dimod.BINARY)
        active = np.asarray(sorted(bqm.variables), dtype=np.int32)
        reads = int(params.get("num_reads", 1))
        sampleset = _anneal(bqm, json.dumps(data, sort_keys=True).encode(), min(reads, 20))
        samples = sampleset.record.sample[:, [sampleset.variables.index(v) for v in active]]
        bits = (samples > 0).astype(np.uint8)
        timing = {
            "qpu_sampling_time": QPU_PER_READ_US * reads,
            "qpu_anneal_time_per_sample": 20.0,
            "qpu_readout_time_per_sample": 70.0,
            "qpu_access_time": qpu_access_us(reads),
            "qpu_access_overhead_time": 1000.0,
            "qpu_programming_time": QPU_PROGRAMMING_US,
            "qpu_delay_time_per_sample": 10.0,
            "total_post_processing_time": 500.0,
            "post_processing_overhead_time": 500.0,
        }
        return {
            "format": "qp",
            "num_variables": int(self.qpu["properties"]["num_qubits"]),
            "active_variables": _b64(active.astype("<i4")),
            "energies": _b64(sampleset.record.energy.astype("<f8")),
            "solutions": _b64(np.packbits(bits, axis=1)),
            "num_occurrences": _b64(sampleset.record.num_occurrences.astype("<i4")),
            "timing": timing,
        }

    def _decode_qp(self, data: dict, vartype: dimod.Vartype) -> dimod.BinaryQuadraticModel:
        """A ``qp`` problem: linear biases of every qubit (NaN: inactive), quadratic ones of
        the couplers between active qubits, both in the solver's encoding order (what
        ``dwave.cloud.coders.encode_problem_as_qp`` writes)."""
        solver = self._qpu_solver
        lin = np.frombuffer(base64.b64decode(data["lin"]), dtype="<f8")
        quad = np.frombuffer(base64.b64decode(data["quad"]), dtype="<f8")
        qubits = solver._encoding_qubits
        active = {q for q, bias in zip(qubits, lin, strict=True) if not np.isnan(bias)}
        couplers = [(a, b) for a, b in solver._encoding_couplers if a in active and b in active]
        linear = {q: float(bias) for q, bias in zip(qubits, lin, strict=True) if q in active}
        quadratic = {pair: float(bias) for pair, bias in zip(couplers, quad, strict=True) if bias}
        return dimod.BinaryQuadraticModel(linear, quadratic, 0.0, vartype)

    def _hybrid_answer(self, data: dict, params: dict) -> dict:
        raw = self._uploads[data["data"]][-1]
        bqm = dimod.BinaryQuadraticModel.from_file(io.BytesIO(raw))
        sampleset = _anneal(bqm, raw, 2).truncate(1)
        sampleset.info.update(
            charge_time=HYBRID_CHARGE_US, run_time=HYBRID_CHARGE_US, qpu_access_time=HYBRID_QPU_US
        )
        return {"format": "bq", "data": sampleset.to_serializable(use_bytes=False)}
