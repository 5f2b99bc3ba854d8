"""The qpu code path on MockDWaveSampler and its embedding cache (errors: test_dwave_cloud)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from solver_helpers import optimum, stereo_costs, with_record

from shared.encodings import get_codec
from shared.energy import mrf_energy
from shared.solvers import SolverError, SolverUnavailableError
from shared.solvers.exact import solve_chains
from shared.solvers.meters import qpu_time
from shared.solvers.qpu.dwave import SimulatedQPUSolver
from shared.solvers.qpu.embedding_cache import DirectoryStore, EmbeddingCache, default_cache
from shared.solvers.registry import get_solver

#: These tests are about the QPU path itself: roof duality would solve their tiny rows on the host.
WHOLE = {"preprocess": "none"}
MOCK_QPU_ACCESS_US = 8550.28  # MockDWaveSampler's fixed demonstration timing (not charged)


@pytest.fixture(scope="module")
def mock_qpu():
    """One MockDWaveSampler for the module (building the P16 graph takes ~0.5 s)."""
    return SimulatedQPUSolver().sampler()


def sim_solver(mock_qpu, cache: EmbeddingCache) -> SimulatedQPUSolver:
    solver = with_record(SimulatedQPUSolver(cache=cache), "qpu-sim")
    solver._sampler, solver._target = mock_qpu, "pegasus16-test"
    return solver


@pytest.mark.parametrize("encoding", ["one-hot", "domain-wall"])
def test_qpu_sim_solves_a_small_row(encoding, mock_qpu, tmp_path):
    costs = stereo_costs(1, 4)
    codec = get_codec(encoding)
    bqm = codec.encode(costs)
    solver = sim_solver(mock_qpu, EmbeddingCache(DirectoryStore(tmp_path)))
    # qpu's 500 reads (qpu-sim's default is 100: test_mock_qpu); 100 descents from random
    # states can miss this row's optimum
    result = solver.solve(bqm, seed=4, num_reads=500, preprocess="none")
    decoded = codec.decode(costs, result.sample)
    assert mrf_energy(costs, decoded.labels) == pytest.approx(optimum(costs), rel=1e-9)
    assert result.energy == pytest.approx(bqm.energy(result.sample))
    assert result.info["simulated"] is True and result.info["num_reads"] == 500
    assert 0.0 <= result.info["chain_break_fraction"] <= 1.0
    assert result.info["qubits"] >= bqm.num_variables
    assert result.info["chains"] == bqm.num_variables
    # Not the mock's fixed demonstration value: the timing model for the actual embedding.
    modeled = qpu_time.qpu_access_seconds(result.info["qubits"], {"num_reads": 500})
    assert result.timing == {"qpu_access_time": pytest.approx(modeled)}
    assert result.timing["qpu_access_time"] != pytest.approx(MOCK_QPU_ACCESS_US * 1e-6)
    assert result.info["qpu_access_time"] == result.timing["qpu_access_time"]


def test_chain_strength_is_uniform_torque_compensation_with_prefactor_1414(mock_qpu, tmp_path):
    bqm = get_codec("domain-wall").encode(stereo_costs(1, 6))
    result = sim_solver(mock_qpu, EmbeddingCache(DirectoryStore(tmp_path))).solve(
        bqm, seed=0, preprocess="none"
    )
    _, (_, _, quadratic), _ = bqm.to_numpy_vectors()
    average_degree = 2 * bqm.num_interactions / bqm.num_variables
    expected = 1.414 * np.sqrt(np.mean(quadratic**2)) * np.sqrt(average_degree)
    assert result.info["chain_strength"] == pytest.approx(expected)


def test_embedding_is_found_once_per_structure_and_persisted(mock_qpu, tmp_path):
    store = DirectoryStore(tmp_path / "embeddings")
    solver = sim_solver(mock_qpu, EmbeddingCache(store))
    codec = get_codec("domain-wall")
    first = solver.solve(codec.encode(stereo_costs(1, 6, seed=1)), seed=0, num_reads=10, **WHOLE)
    # Another row with other biases but the same structure: served from memory.
    second = solver.solve(codec.encode(stereo_costs(1, 6, seed=2)), seed=0, num_reads=10, **WHOLE)
    assert first.info["embedding_cache"] == "computed"
    assert first.info["embedding_cache_hit"] is False
    assert second.info["embedding_cache"] == "memory"
    assert second.info["embedding_key"] == first.info["embedding_key"]
    # A fresh cache on the same directory (another worker): served from the store.
    again = sim_solver(mock_qpu, EmbeddingCache(store)).solve(
        codec.encode(stereo_costs(1, 6, seed=3)), seed=0, num_reads=10, **WHOLE
    )
    assert again.info["embedding_cache"] == "store"
    # A different structure (wider row) needs its own embedding.
    wider = solver.solve(codec.encode(stereo_costs(1, 7)), seed=0, num_reads=10, **WHOLE)
    assert wider.info["embedding_cache"] == "computed"
    files = [path.name for path in Path(tmp_path / "embeddings").glob("*.json")]
    assert len([name for name in files if not name.startswith("size-")]) == 2
    # Each embedding's size is kept for estimates, under the solver's name and the structure.
    assert len([name for name in files if name.startswith("size-qpu-sim-")]) == 2
    digest = first.info["embedding_key"].rsplit("-", 1)[1]
    size = EmbeddingCache(store).known_size("qpu-sim", digest)
    assert size is not None and size.qubits == first.info["qubits"]
    assert size.chains == 6 * 3 and size.longest_chain == first.info["longest_chain"]


def test_directory_store_is_shared_with_a_fresh_process(mock_qpu, tmp_path):
    """The default cache keeps embeddings under QHSM_DATA_DIR/embeddings across processes."""
    bqm = get_codec("domain-wall").encode(stereo_costs(1, 5))
    first = with_record(SimulatedQPUSolver(), "qpu-sim").solve(bqm, seed=0, num_reads=10, **WHOLE)
    assert first.info["embedding_cache"] == "computed"
    assert default_cache().store.directory == tmp_path / "data" / "embeddings"
    script = (
        "import json, sys; sys.path.insert(0, sys.argv[1]);"
        "from solver_helpers import stereo_costs;"
        "from shared.encodings import get_codec;"
        "from shared.solvers.registry import get_solver;"
        "bqm = get_codec('domain-wall').encode(stereo_costs(1, 5, seed=9));"
        "r = get_solver('qpu-sim').solve(bqm, seed=0, num_reads=10, preprocess='none');"
        "print(json.dumps([r.info['embedding_cache'], r.info['embedding_key']]))"
    )
    output = subprocess.run(
        [sys.executable, "-c", script, str(Path(__file__).parent)],
        env=os.environ.copy(),
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
    )
    source, key = json.loads(output.stdout.strip().splitlines()[-1])
    assert source == "store" and key == first.info["embedding_key"]


def test_no_embedding_is_a_clear_solver_error(tmp_path):
    """A complete graph on 8 variables does not fit a 10-qubit path graph."""
    from solver_helpers import random_bqm

    bqm = random_bqm(8, seed=0)
    bqm.add_quadratic_from({(u, v): 1.0 for u in range(8) for v in range(u + 1, 8)})
    path = [(i, i + 1) for i in range(9)]
    cache = EmbeddingCache(DirectoryStore(tmp_path))
    with pytest.raises(SolverError, match=r"no minor embedding.*domain-wall"):
        cache.lookup(bqm, path, "path10", timeout=1)
    # The next bundle of the same structure fails at once instead of searching again.
    started = time.perf_counter()
    with pytest.raises(SolverError, match=r"no minor embedding"):
        cache.lookup(bqm, path, "path10", timeout=1)
    assert time.perf_counter() - started < 0.5
    assert not list(tmp_path.glob("*.json"))


@pytest.mark.parametrize("name", ["qpu", "hybrid"])
def test_cloud_solvers_without_token_say_what_to_configure(name):
    solver = get_solver(name)
    availability = solver.available()
    assert not availability.ok and "set DWAVE_API_TOKEN" in availability.reason
    bqm = get_codec("domain-wall").encode(stereo_costs(1, 3))
    with pytest.raises(SolverUnavailableError, match="set DWAVE_API_TOKEN"):
        solver.solve(bqm, seed=0, **WHOLE)


def test_hybrid_sim_solves_a_small_row():
    costs = stereo_costs(1, 6)
    codec = get_codec("domain-wall")
    result = get_solver("hybrid-sim").solve(codec.encode(costs), seed=1, max_iter=3, **WHOLE)
    assert result.info["simulated"] is True
    # charged what Leap's hybrid solver would bill for this size (its minimum time limit)
    bqm_size = codec.encode(costs).num_variables
    assert result.timing["charge_time"] == qpu_time.hybrid_charge_seconds(bqm_size) == 3.0
    assert qpu_time.charged_seconds(result.timing) == 3.0
    labels = codec.decode(costs, result.sample).labels
    assert mrf_energy(costs, labels) == pytest.approx(optimum(costs), rel=1e-9)


def test_qpu_sim_charge_and_estimates_use_the_actual_embedding(tmp_path, capsys, monkeypatch):
    """Before any embedding the estimate assumes 2 qubits per variable and one bundle per call
    (an upper bound); after a run, `qhsm estimate --local` uses the embeddings and what roof duality
    leaves of the bundles, and is the charge within 10 %."""
    # whichever tiles the search finds, the estimate must use them: 2 tries instead of 10 keep
    # its failed searches on the smaller sublattices short (21 s -> 8 s of this test)
    monkeypatch.setenv("QHSM_EMBEDDING_TRIES", "2")
    import cv2

    from shared.cli import main
    from shared.config import MatchConfig
    from shared.images import load_pair
    from shared.inference import solve_level_in_process
    from shared.pipeline import run_pipeline
    from shared.synthetic import make_scene

    scene = make_scene(12, 20, max_disparity=6, seed=5)
    left, right = tmp_path / "left.png", tmp_path / "right.png"
    cv2.imwrite(str(left), np.rint(scene.left * 255).astype(np.uint8))
    cv2.imwrite(str(right), np.rint(scene.right * 255).astype(np.uint8))
    argv = ["estimate", str(left), str(right), "--local", "--json", "--solver", "qpu-sim",
            "--encoding", "domain-wall", "--max-disparity", "6",
            "--param", "num_reads=20"]  # fmt: skip
    assert main(argv) == 0
    before = json.loads(capsys.readouterr().out)
    assert not any(level["embedding_known"] for level in before["levels"])

    config = MatchConfig(solver="qpu-sim", encoding="domain-wall", max_disparity=6,
                         solver_params={"num_reads": 20})  # fmt: skip
    charged = []

    def solve_level(inputs, cfg):
        solution = solve_level_in_process(inputs, cfg)
        charged.append(qpu_time.charged_seconds(solution.timing))
        return solution

    # the pair as the estimate read it (8-bit files): which tiles certify is discrete
    run_pipeline(*load_pair(left, right), config, solve_level)
    charge = sum(charged)
    # before any run: 2 qubits a variable and one bundle per QPU call (no copies known yet,
    # while the run packed several into each call): an upper bound for rows, within 10 % for
    # the grid's 3-row tiles (their embeddings need longer chains)
    assert charge <= 1.10 * before["seconds"]
    # not the mock's fixed demonstration timing
    assert charge / before["bundles"] != pytest.approx(MOCK_QPU_ACCESS_US * 1e-6, rel=0.05)

    assert main(argv) == 0
    after = json.loads(capsys.readouterr().out)
    assert all(level["embedding_known"] for level in after["levels"])
    # what roof duality leaves is surveyed with exact's coarser maps, not qpu-sim's: within 10 %
    assert after["seconds"] == pytest.approx(charge, rel=0.1)
    assert 0 < after["bundles_sent"] <= after["bundles"]


def test_warm_started_qpu_sim_is_charged_the_reverse_anneal_its_estimate_assumes(
    mock_qpu, tmp_path
):
    costs = stereo_costs(1, 5)
    codec = get_codec("domain-wall")
    bqm = codec.encode(costs)
    start = codec.encode_labels(np.zeros((1, 5), dtype=np.int32), costs.num_labels)
    solver = sim_solver(mock_qpu, EmbeddingCache(DirectoryStore(tmp_path)))
    params = {"num_reads": 30, "annealing_time": 80.0, "warm_start": True}
    result = solver.solve(
        bqm, seed=0, initial_state=start, num_reads=30, annealing_time=80.0, **WHOLE
    )
    expected = qpu_time.bundle_seconds(
        "qpu-sim",
        bqm.num_variables,
        qpu_time.sampler_params(params, warm=True),
        num_qubits=result.info["qubits"],
    )
    assert result.info["warm_start"] is True
    assert result.timing["qpu_access_time"] == pytest.approx(expected)
    cold = qpu_time.qpu_access_seconds(result.info["qubits"], {"num_reads": 30})
    assert result.timing["qpu_access_time"] != pytest.approx(cold)


def test_the_stand_in_is_a_pegasus_p16_mock_sampling_by_steepest_descent(mock_qpu):
    from dwave.samplers import SteepestDescentSampler
    from dwave.system.testing import MockDWaveSampler

    assert isinstance(mock_qpu, MockDWaveSampler)
    assert mock_qpu.properties["topology"] == {"type": "pegasus", "shape": [16]}
    assert isinstance(mock_qpu.substitute_sampler, SteepestDescentSampler)
    assert mock_qpu.parameter_warnings is False


def test_qpu_sim_takes_qpus_read_budget_and_is_charged_the_reads_it_took(mock_qpu, tmp_path):
    from shared.solvers.params import DEFAULT_NUM_READS, SimulatedQPUParams
    from shared.solvers.qpu.embedding_cache import EmbeddingSize

    # the stand-in reads what qpu reads (20, measured: docs/benchmarks.md), charged the same
    assert SimulatedQPUParams.model_fields["num_reads"].default == DEFAULT_NUM_READS == 20
    bqm = get_codec("domain-wall").encode(stereo_costs(1, 6, seed=3))
    solver = sim_solver(mock_qpu, EmbeddingCache(DirectoryStore(tmp_path)))
    default = solver.solve(bqm, seed=1, **WHOLE)
    asked = solver.solve(bqm, seed=1, num_reads=7, **WHOLE)
    assert default.info["num_reads"] == DEFAULT_NUM_READS and asked.info["num_reads"] == 7
    # a bundle's estimate (no num_reads given) is what the bundle is charged
    size = EmbeddingSize(default.info["qubits"], default.info["chains"], 1)
    estimated = qpu_time.bundle_seconds("qpu-sim", bqm.num_variables, {}, embedding=size)
    assert default.timing["qpu_access_time"] == pytest.approx(estimated)
    assert asked.timing["qpu_access_time"] < default.timing["qpu_access_time"]
    qpu = qpu_time.bundle_seconds("qpu", bqm.num_variables, {}, embedding=size)
    assert qpu == pytest.approx(estimated)


def test_qpu_sim_starts_its_first_read_from_the_warm_start(mock_qpu, tmp_path):
    costs = stereo_costs(1, 12, labels=5, seed=3)
    codec = get_codec("domain-wall")
    best = codec.encode_labels(solve_chains(costs), costs.num_labels)
    solver = sim_solver(mock_qpu, EmbeddingCache(DirectoryStore(tmp_path)))
    result = solver.solve(codec.encode(costs), seed=0, initial_state=best, num_reads=2, **WHOLE)
    assert result.info["warm_start"] is True
    labels = codec.decode(costs, result.sample).labels
    assert mrf_energy(costs, labels) == pytest.approx(optimum(costs), rel=1e-9)


def test_one_embedding_composite_per_shape_whatever_the_biases(mock_qpu, tmp_path):
    from unittest import mock

    import dwave.system

    solver = sim_solver(mock_qpu, EmbeddingCache(DirectoryStore(tmp_path)))
    codec = get_codec("domain-wall")
    with mock.patch.object(
        dwave.system, "FixedEmbeddingComposite", wraps=dwave.system.FixedEmbeddingComposite
    ) as built:
        results = [
            solver.solve(codec.encode(stereo_costs(1, 6, seed=s)), seed=s, num_reads=5, **WHOLE)
            for s in range(3)
        ]
        assert built.call_count == 1
        solver.solve(codec.encode(stereo_costs(1, 7)), seed=0, num_reads=5, **WHOLE)
        assert built.call_count == 2
    assert [r.info["embedding_cache"] for r in results] == ["computed", "memory", "memory"]


def test_a_reused_embedding_composite_gives_what_a_fresh_one_gives(mock_qpu, tmp_path):
    codec = get_codec("domain-wall")
    first, second = (codec.encode(stereo_costs(1, 6, seed=s)) for s in (4, 5))
    warm = sim_solver(mock_qpu, EmbeddingCache(DirectoryStore(tmp_path / "a")))
    warm.solve(first, seed=2, num_reads=20, **WHOLE)
    reused = warm.solve(second, seed=9, num_reads=20, **WHOLE)
    fresh = sim_solver(mock_qpu, EmbeddingCache(DirectoryStore(tmp_path / "b")))
    again = fresh.solve(second, seed=9, num_reads=20, **WHOLE)
    assert (reused.sample == again.sample).all() and reused.energy == again.energy
