"""The real ``qpu`` and ``hybrid`` adapters against a mocked D-Wave cloud, the way dwave-system
tests its own samplers: ``Client`` gets no session and "fetches" dwave-cloud-client's mock solver
data (a Pegasus P16 QPU, a hybrid BQM solver), whose ``sample_bqm`` returns canned answers or
raises D-Wave's errors. Nothing leaves the machine; the API token is a sentinel that must never
appear in what we raise or log."""

from __future__ import annotations

import logging
from concurrent.futures import Future
from typing import Any
from unittest import mock

import dimod
import numpy as np
import pytest
import requests
from dwave.cloud import Client
from dwave.cloud import exceptions as cloud
from dwave.cloud.api import exceptions as api
from dwave.cloud.solver import BQMSolver, StructuredSolver
from dwave.cloud.testing import mocks
from solver_helpers import optimum, stereo_costs, with_record

from shared.encodings import get_codec
from shared.energy import mrf_energy
from shared.solvers import SolverError, SolverUnavailableError, TransientSolverError
from shared.solvers.hybrid import LeapHybridSolver
from shared.solvers.meters import qpu_time
from shared.solvers.qpu.dwave import QPUSolver
from shared.solvers.qpu.embedding_cache import DirectoryStore, EmbeddingCache
from shared.solvers.qpu.qpu_settings import chain_strength

SENTINEL = "DEV-sentinel-7f3c9a1e-never-print-me"

#: What SAPI reports for one QPU problem (microseconds), as in dwave-system's MockSolver.
QPU_TIMING_US = {
    "qpu_sampling_time": 3830.0,
    "qpu_anneal_time_per_sample": 20.0,
    "qpu_readout_time_per_sample": 35.0,
    "qpu_access_time": 18572.76,
    "qpu_access_overhead_time": 1080.0,
    "qpu_programming_time": 14742.76,
    "qpu_delay_time_per_sample": 21.0,
    "total_post_processing_time": 2042.0,
    "post_processing_overhead_time": 2042.0,
}
#: What Leap's hybrid BQM solver reports (microseconds).
HYBRID_TIMING_US = {"qpu_access_time": 40123, "run_time": 2997614, "charge_time": 2990000}


class CannedComputation:
    """The part of ``dwave.cloud.computation.Future`` the samplers read: ``sampleset`` (which
    raises what SAPI raised) and ``done``."""

    def __init__(self, sampleset: dimod.SampleSet | None, error: Exception | None = None):
        self._sampleset = sampleset
        self._error = error
        self.id = "canned-problem-id"

    def done(self) -> bool:
        return True

    @property
    def sampleset(self) -> dimod.SampleSet:
        if self._error is not None:
            raise self._error
        return self._sampleset


class FakeLeap:
    """The mocked cloud: records submissions, answers with ``answer(bqm, params)`` or raises
    ``error`` (at submission or, with ``fail_on_resolve``, when the answer is read)."""

    def __init__(self) -> None:
        self.submissions: list[tuple[dimod.BinaryQuadraticModel, dict[str, Any]]] = []
        self.answer = None
        self.error: Exception | None = None
        self.fail_on_resolve = True
        self.fetch_error: Exception | None = None

    def respond(self, bqm, params: dict[str, Any], info: dict[str, Any]) -> CannedComputation:
        self.submissions.append((bqm, params))
        if self.error is not None and not self.fail_on_resolve:
            raise self.error
        if self.error is not None:
            return CannedComputation(None, self.error)
        samples = self.answer(bqm, params)
        sampleset = dimod.SampleSet.from_samples_bqm((samples, list(bqm.variables)), bqm, info=info)
        return CannedComputation(sampleset)


@pytest.fixture(scope="module")
def pegasus_data() -> dict:
    """A Pegasus P16 Advantage as SAPI describes it, with its published timing data."""
    data = mocks.qpu_pegasus_solver_data(16)
    data["properties"]["problem_timing_data"] = mocks.qpu_problem_timing_data("advantage")
    data["properties"]["parameters"].update(
        {name: "" for name in ("annealing_time", "anneal_schedule", "initial_state")}
    )
    return data


@pytest.fixture
def leap(monkeypatch, pegasus_data) -> FakeLeap:
    """DWaveSampler / LeapHybridSampler see the mock solvers; the token is the sentinel."""
    fake = FakeLeap()
    qpu = StructuredSolver(data=pegasus_data, client=None)
    hybrid = BQMSolver(data=mocks.hybrid_bqm_solver_data(), client=None)

    def sample_qpu(bqm, **params):
        return fake.respond(bqm, params, {"timing": dict(QPU_TIMING_US), "problem_id": "p1"})

    def upload(bqm_file, **kwargs):
        done: Future = Future()
        done.set_result("uploaded-problem-id")
        fake.uploaded = dimod.BinaryQuadraticModel.from_file(bqm_file)
        return done

    def sample_hybrid(problem_id, **params):
        return fake.respond(fake.uploaded, params, dict(HYBRID_TIMING_US))

    def fetch_solvers(client, *args, **kwargs):
        if fake.fetch_error is not None:
            raise fake.fetch_error
        return [qpu] if type(client).__module__.endswith(".qpu") else [hybrid]

    monkeypatch.setattr(qpu, "sample_bqm", sample_qpu)
    monkeypatch.setattr(hybrid, "upload_bqm", upload)
    monkeypatch.setattr(hybrid, "sample_bqm", sample_hybrid)
    monkeypatch.setattr(Client, "create_session", lambda client: mock.Mock())
    monkeypatch.setattr(Client, "_fetch_solvers", fetch_solvers)
    monkeypatch.setenv("DWAVE_API_TOKEN", SENTINEL)
    return fake


def qpu_solver(tmp_path) -> QPUSolver:
    return with_record(
        QPUSolver(cache=EmbeddingCache(DirectoryStore(tmp_path / "embeddings"))), "qpu"
    )


def hybrid_solver(leap: FakeLeap) -> LeapHybridSolver:
    return with_record(LeapHybridSolver(), "hybrid")


def assert_no_token(error: BaseException, caplog) -> None:
    assert SENTINEL not in str(error) and SENTINEL not in repr(error)
    assert error.__cause__ is None and error.__suppress_context__  # no chained cloud error
    assert SENTINEL not in caplog.text


# --- qpu: submission, timing, chain breaks -------------------------------------------------


def extend_chain(embedding: dict, variable: int, edges: list, extra: int) -> dict:
    """A still-valid embedding in which ``variable``'s chain has ``extra`` more free qubits."""
    used = {q for chain in embedding.values() for q in chain}
    neighbours: dict[int, set[int]] = {}
    for u, v in edges:
        neighbours.setdefault(u, set()).add(v)
        neighbours.setdefault(v, set()).add(u)
    chain = list(embedding[variable])
    while extra:
        free = next(q for c in chain for q in sorted(neighbours[c]) if q not in used)
        chain.append(free)
        used.add(free)
        extra -= 1
    return {**embedding, variable: chain}


def test_qpu_submits_our_embedding_with_torque_compensated_chains(leap, tmp_path, caplog):
    caplog.set_level(logging.DEBUG)
    costs = stereo_costs(1, 6)
    codec = get_codec("domain-wall")
    bqm = codec.encode(costs)
    solver = qpu_solver(tmp_path)
    base = solver.sampler()
    assert base.properties["topology"] == {"type": "pegasus", "shape": [16]}
    # Our embedding, with a 3-qubit chain on variable 0 so that a broken chain has a majority.
    embedding, _, key = solver.cache.lookup(bqm, base.edgelist, solver._target, seed=0)
    length = len(embedding[0])
    embedding = extend_chain(embedding, 0, base.edgelist, extra=max(3 - length, length % 2 == 0))
    solver.cache._memory[key] = embedding

    labels = np.asarray([[0, 1, 2, 3, 1, 0]], dtype=np.int32)
    bits = codec.encode_labels(labels, costs.num_labels)
    long_chain = embedding[0]

    def answer(embedded, params):
        # Every qubit of every chain set to its variable's bit, then one qubit of the long
        # chain flipped: a broken chain that majority vote must resolve.
        row = {q: int(bits[v]) for v, chain in embedding.items() for q in chain}
        row[long_chain[0]] = 1 - row[long_chain[0]]
        order = list(embedded.variables)
        return np.asarray([[row[q] for q in order]], dtype=np.int8)

    leap.answer = answer
    result = solver.solve(bqm, num_reads=7, annealing_time=50.0, preprocess="none")

    [(submitted, params)] = leap.submissions
    assert set(submitted.variables) == {q for chain in embedding.values() for q in chain}
    assert params["num_reads"] == 7 and params["annealing_time"] == 50.0
    strength = chain_strength(bqm)
    assert result.info["chain_strength"] == pytest.approx(strength)
    spin = submitted.change_vartype(dimod.SPIN, inplace=False)
    for chain in embedding.values():
        # Inside a chain only chain couplings exist: -strength (Ising), a spanning tree at least.
        inside = [spin.adj[u][v] for u in chain for v in chain if u < v and v in spin.adj[u]]
        assert len(inside) >= len(chain) - 1
        assert inside == pytest.approx([-strength] * len(inside))
    # The broken chain resolved by majority vote to the intended labelling.
    assert np.array_equal(codec.decode(costs, result.sample).labels, labels)
    assert result.info["chain_break_fraction"] == pytest.approx(1 / bqm.num_variables)
    assert result.info["qubits"] == sum(len(c) for c in embedding.values())
    assert result.info["longest_chain"] == len(long_chain) and result.info["simulated"] is False
    # SAPI's microseconds, reported in seconds; the charge is the reported access time.
    assert result.timing == {k: pytest.approx(v * 1e-6) for k, v in QPU_TIMING_US.items()}
    assert qpu_time.charged_seconds(result.timing) == pytest.approx(0.01857276)
    assert SENTINEL not in caplog.text


def test_qpu_solves_a_row_optimally_when_the_cloud_answers_the_optimum(leap, tmp_path):
    """The mock answers the exact ground state of the embedded problem (all reads)."""
    costs = stereo_costs(1, 5, seed=3)
    codec = get_codec("one-hot")
    bqm = codec.encode(costs)

    def answer(embedded, params):
        from shared.solvers.exact import solve_chains

        labels = solve_chains(costs)
        bits = codec.encode_labels(labels, costs.num_labels)
        embedding = solver.cache._memory[next(iter(solver.cache._memory))]
        row = {q: int(bits[v]) for v, chain in embedding.items() for q in chain}
        return np.asarray([[row[q] for q in embedded.variables]] * 3, dtype=np.int8)

    leap.answer = answer
    solver = qpu_solver(tmp_path)
    result = solver.solve(bqm, preprocess="none")
    assert leap.submissions[0][1]["num_reads"] == 20  # our default (docs/benchmarks.md)
    assert result.info["num_reads"] == 3 and result.info["chain_break_fraction"] == 0.0
    labels = codec.decode(costs, result.sample).labels
    assert mrf_energy(costs, labels) == pytest.approx(optimum(costs), rel=1e-9)


def test_worker_estimates_use_the_live_solvers_timing_data(leap, tmp_path, monkeypatch):
    """With a token, the reservation comes from the solver's own problem_timing_data."""
    from shared.solvers import registry
    from shared.solvers.meters import meter_for

    monkeypatch.setattr(registry, "_INSTANCES", {})  # a fresh qpu adapter, not kept after
    live = meter_for("qpu").timing_source(registry.resolve("qpu"))
    assert live is not None
    expected = live.estimate_qpu_access_time(200, num_reads=100) * 1e-6
    assert qpu_time.bundle_seconds(
        "qpu", 100, {"num_reads": 100}, num_qubits=200, solver=live
    ) == pytest.approx(expected)


# --- hybrid: timing and charge_time --------------------------------------------------------


def test_hybrid_reports_leaps_charge_time_in_seconds(leap, caplog):
    caplog.set_level(logging.DEBUG)
    costs = stereo_costs(1, 6)
    codec = get_codec("domain-wall")
    bqm = codec.encode(costs)
    leap.answer = lambda b, p: np.zeros((2, b.num_variables), dtype=np.int8)
    solver = hybrid_solver(leap)
    result = solver.solve(bqm, initial_state=np.zeros(bqm.num_variables), preprocess="none")
    [(_, params)] = leap.submissions
    # Leap's minimum for this size (the mock solver's curve: 1 s at 1 variable, 2 s at 1024)
    assert params["time_limit"] == pytest.approx(1.0 + (bqm.num_variables - 1) / 1023)
    assert result.timing == {k: pytest.approx(v * 1e-6) for k, v in HYBRID_TIMING_US.items()}
    assert qpu_time.charged_seconds(result.timing) == pytest.approx(2.99)  # charge_time wins
    assert result.info["warm_start_ignored"] is True
    assert SENTINEL not in caplog.text


def test_hybrid_time_limit_is_passed_on(leap):
    bqm = get_codec("domain-wall").encode(stereo_costs(1, 4))
    leap.answer = lambda b, p: np.zeros((1, b.num_variables), dtype=np.int8)
    hybrid_solver(leap).solve(bqm, time_limit=12.5, preprocess="none")
    assert leap.submissions[0][1]["time_limit"] == 12.5


# --- errors: typed, actionable, token-free ---------------------------------------------------

LEAKY = f"token={SENTINEL}"

ERRORS = [
    # (raised by the cloud, our class, words the message must contain)
    (cloud.SolverAuthenticationError(f"Invalid token or access denied ({LEAKY})"),
     SolverUnavailableError, "DWAVE_API_TOKEN"),
    (api.ResourceAuthenticationError(f"401 {LEAKY}"), SolverUnavailableError, "authentication"),
    (api.ResourceLimitsExceededError(f"429 Too Many Requests {LEAKY}", error_code=429),
     TransientSolverError, "429"),
    (cloud.SolverOfflineError(f"solver is offline {LEAKY}"), TransientSolverError, "offline"),
    (api.RequestTimeout(f"read timed out {LEAKY}"), TransientSolverError, "retry later"),
    (cloud.PollingTimeout(f"polling timed out {LEAKY}"), TransientSolverError, "retry later"),
    (requests.ConnectionError(f"https://na-west-1.cloud.dwavesys.com/sapi/v2?{LEAKY}"),
     TransientSolverError, "connection failed"),
    (cloud.ProblemStructureError(f"Problem graph incompatible {LEAKY}"), SolverError,
     "too large"),
    (api.ResourceBadRequestError(f"Problem has too many variables {LEAKY}"), SolverError,
     "too large"),
    (cloud.SolverFailureError(f"bad h range {LEAKY}"), SolverError, "sampling failed"),
]  # fmt: skip


@pytest.mark.parametrize(("error", "kind", "words"), ERRORS)
@pytest.mark.parametrize("when", ["submit", "resolve"])
@pytest.mark.parametrize("name", ["qpu", "hybrid"])
def test_cloud_errors_become_typed_token_free_errors(
    error, kind, words, when, name, leap, tmp_path, caplog
):
    caplog.set_level(logging.DEBUG)
    leap.error, leap.fail_on_resolve = error, when == "resolve"
    solver = qpu_solver(tmp_path) if name == "qpu" else hybrid_solver(leap)
    bqm = get_codec("domain-wall").encode(stereo_costs(1, 3))
    with pytest.raises(kind, match=words) as caught:
        solver.solve(bqm, seed=0, preprocess="none")
    assert type(caught.value) is kind
    assert caught.value.args[0].startswith(f"{name}: ")
    assert_no_token(caught.value, caplog)


@pytest.mark.parametrize("name", ["qpu", "hybrid"])
def test_authentication_failure_when_connecting(name, leap, tmp_path, caplog):
    """SAPI refuses the token already when the solver list is fetched."""
    caplog.set_level(logging.DEBUG)
    leap.fetch_error = cloud.SolverAuthenticationError(f"Invalid token {SENTINEL}")
    solver = qpu_solver(tmp_path) if name == "qpu" else hybrid_solver(leap)
    with pytest.raises(SolverUnavailableError, match="rejected the API token") as caught:
        solver.solve(get_codec("domain-wall").encode(stereo_costs(1, 3)), preprocess="none")
    assert_no_token(caught.value, caplog)
    assert not leap.submissions


def test_a_bundle_too_large_for_the_qpu_is_refused_before_submission(leap, tmp_path):
    """More variables than the P16 solver has qubits: a clear error at once, nothing sent."""
    size = 6000
    bqm = dimod.BinaryQuadraticModel.from_numpy_vectors(
        np.ones(size), (np.arange(size - 1), np.arange(1, size), np.ones(size - 1)), 0.0, "BINARY"
    )
    with pytest.raises(SolverError, match="too large for the QPU: 6000 variables") as caught:
        qpu_solver(tmp_path).solve(bqm, preprocess="none")
    assert type(caught.value) is SolverError and not leap.submissions


def test_a_problem_too_large_for_the_hybrid_solver_is_refused_before_upload(leap):
    """The hybrid solver's maximum_number_of_variables is checked here, not by a failed upload."""
    leap.answer = lambda b, p: np.zeros((1, b.num_variables), dtype=np.int8)
    solver = hybrid_solver(leap)
    solver.solve(get_codec("domain-wall").encode(stereo_costs(1, 3)), preprocess="none")
    solver._sampler.properties["maximum_number_of_variables"] = 10
    with pytest.raises(SolverError, match="too large") as caught:
        solver.solve(get_codec("domain-wall").encode(stereo_costs(1, 6)), preprocess="none")
    assert "10 variables" in str(caught.value) and len(leap.submissions) == 1
