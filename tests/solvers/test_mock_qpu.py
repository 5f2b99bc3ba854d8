"""The offline stand-in's sampler configuration, read budget and per-shape reuse (qpu-sim)."""

from __future__ import annotations

from unittest import mock

import dwave.system
import pytest
from dwave.samplers import SteepestDescentSampler
from dwave.system.testing import MockDWaveSampler
from solver_helpers import stereo_costs

from shared.encodings import get_codec
from shared.solvers import qpu_time
from shared.solvers.dwave import DEFAULT_NUM_READS, QPUSolver, SimulatedQPUSolver
from shared.solvers.embedding_cache import DirectoryStore, EmbeddingCache, EmbeddingSize
from shared.solvers.mock_qpu import SIM_NUM_READS, mock_sampler


@pytest.fixture(scope="module")
def base():
    """One mock for the module (building the P16 graph takes ~0.5 s)."""
    return mock_sampler()


def sim_solver(base, tmp_path) -> SimulatedQPUSolver:
    solver = SimulatedQPUSolver(cache=EmbeddingCache(DirectoryStore(tmp_path)))
    solver._sampler, solver._target = base, "pegasus16-test"
    return solver


def test_the_stand_in_is_a_pegasus_p16_mock_sampling_by_steepest_descent(base):
    assert isinstance(base, MockDWaveSampler)
    assert base.properties["topology"] == {"type": "pegasus", "shape": [16]}
    assert isinstance(base.substitute_sampler, SteepestDescentSampler)
    assert base.parameter_warnings is False


def test_qpu_sim_takes_its_own_read_budget_and_charges_for_the_reads_it_took(base, tmp_path):
    bqm = get_codec("domain-wall").encode(stereo_costs(1, 6, seed=3))
    solver = sim_solver(base, tmp_path)
    default = solver.solve(bqm, seed=1)
    asked = solver.solve(bqm, seed=1, num_reads=7)
    assert SIM_NUM_READS < DEFAULT_NUM_READS == QPUSolver.default_num_reads
    assert default.info["num_reads"] == SIM_NUM_READS and asked.info["num_reads"] == 7
    # the estimate of a bundle (no num_reads given) is what the bundle is charged
    size = EmbeddingSize(default.info["qubits"], default.info["chains"], 1)
    estimated = qpu_time.bundle_seconds("qpu-sim", bqm.num_variables, {}, embedding=size)
    assert default.timing["qpu_access_time"] == pytest.approx(estimated)
    assert asked.timing["qpu_access_time"] < default.timing["qpu_access_time"]
    # qpu's estimate keeps its 500 reads
    qpu = qpu_time.bundle_seconds("qpu", bqm.num_variables, {}, embedding=size)
    assert qpu == pytest.approx(qpu_time.qpu_access_seconds(size.qubits, {"num_reads": 500}))
    assert qpu > estimated


def test_one_embedding_composite_per_shape_whatever_the_biases(base, tmp_path):
    solver = sim_solver(base, tmp_path)
    codec = get_codec("domain-wall")
    with mock.patch.object(
        dwave.system, "FixedEmbeddingComposite", wraps=dwave.system.FixedEmbeddingComposite
    ) as built:
        results = [
            solver.solve(codec.encode(stereo_costs(1, 6, seed=s)), seed=s, num_reads=5)
            for s in range(3)
        ]
        assert built.call_count == 1
        solver.solve(codec.encode(stereo_costs(1, 7)), seed=0, num_reads=5)
        assert built.call_count == 2
    assert [r.info["embedding_cache"] for r in results] == ["computed", "memory", "memory"]


def test_the_reused_composite_gives_what_a_fresh_one_gives(base, tmp_path):
    codec = get_codec("domain-wall")
    first, second = (codec.encode(stereo_costs(1, 6, seed=s)) for s in (4, 5))
    warm = sim_solver(base, tmp_path / "a")
    warm.solve(first, seed=2, num_reads=20)
    reused = warm.solve(second, seed=9, num_reads=20)
    fresh = sim_solver(base, tmp_path / "b").solve(second, seed=9, num_reads=20)
    assert (reused.sample == fresh.sample).all() and reused.energy == fresh.energy
