"""Issue 19: the metered solvers solve classically what roof duality fixes and charge only
what they send; the hybrid solvers send a level's rests as one problem; estimates know both."""

from __future__ import annotations

import json

import dimod
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from solver_helpers import optimum, stereo_costs, with_record

from shared.encodings import get_codec
from shared.energy import mrf_energy
from shared.solvers.hybrid import blocks
from shared.solvers.meters import qpu_time
from shared.solvers.qpu.packing import joined
from shared.solvers.registry import get_solver

QUICK_HYBRID = {"max_iter": 2, "sa_sweeps": 100, "qpu_reads": 10}


def frustrated(width: int, seed: int) -> dimod.BinaryQuadraticModel:
    """A domain-wall row roof duality only partly solves: Potts smoothness (not submodular)
    over random data costs, and two pixels with one clearly best label (fixed)."""
    costs = stereo_costs(1, width, labels=4, seed=1)
    costs.unary[:] = np.random.default_rng(seed).random(costs.unary.shape)
    costs.unary[0, :2] = [0.0, 9.0, 9.0, 9.0]
    costs.pair_h[:] = 0.6 * (1 - np.eye(4))
    return get_codec("domain-wall").encode(costs)


@pytest.mark.parametrize("solver", ["qpu-sim", "hybrid-sim"])
def test_a_bundle_roof_duality_solves_is_solved_on_the_host_and_charged_nothing(solver):
    # a two-pixel row with a large unary gap: roof duality fixes every variable
    costs = stereo_costs(1, 2, labels=3, seed=2)
    costs.unary[:] = np.array([0.0, 5.0, 5.0])
    bqm = get_codec("domain-wall").encode(costs)
    result = get_solver(solver).solve(bqm, seed=0)
    assert result.info["residual_variables"] == 0 and result.info["fixed_fraction"] == 1.0
    assert result.timing == {} and qpu_time.charged_seconds(result.timing) == 0.0
    assert "embedding_cache" not in result.info  # nothing reached the (mock) QPU
    labels = get_codec("domain-wall").decode(costs, result.sample).labels
    assert mrf_energy(costs, labels) == pytest.approx(optimum(costs))


@given(st.lists(st.integers(0, 50), max_size=30), st.integers(1, 60))
@settings(max_examples=50, deadline=None)
def test_blocks_keep_order_and_stay_within_the_limit(sizes, limit):
    groups = blocks(sizes, limit)
    assert [i for group in groups for i in group] == list(range(len(sizes)))
    for group in groups:
        assert len(group) == 1 or sum(sizes[i] for i in group) <= limit


def test_joined_bqms_keep_each_energy():
    parts = [get_codec("domain-wall").encode(stereo_costs(1, w, seed=w)) for w in (3, 4)]
    whole = joined(parts)
    rng = np.random.default_rng(0)
    samples = [rng.integers(0, 2, part.num_variables) for part in parts]
    assert whole.num_variables == sum(part.num_variables for part in parts)
    assert whole.energy(np.concatenate(samples)) == pytest.approx(
        sum(part.energy(sample) for part, sample in zip(parts, samples, strict=True))
    )


def test_hybrid_sim_charges_a_batch_as_one_problem_shared_pro_rata():
    bqms = [frustrated(8, s) for s in range(4)]
    results = get_solver("hybrid-sim").solve_batch(
        [(bqm, s, None) for s, bqm in enumerate(bqms)], **QUICK_HYBRID
    )
    left = [r.info["residual_variables"] for r in results]
    assert 0 < sum(left) < sum(bqm.num_variables for bqm in bqms)
    charged = [qpu_time.charged_seconds(r.timing) for r in results]
    # Leap's minimum for the joined rests once, not its 3 s minimum per bundle
    assert sum(charged) == pytest.approx(qpu_time.hybrid_charge_seconds(sum(left)))
    for share, size in zip(charged, left, strict=True):
        assert share == pytest.approx(sum(charged) * size / sum(left))
    for bqm, result in zip(bqms, results, strict=True):
        assert result.energy == pytest.approx(bqm.energy(result.sample))


class _FakeLeap:
    """LeapHybridSampler's interface, solving by steepest descent, counting problems."""

    properties = {"maximum_number_of_variables": 1_000_000}  # noqa: RUF012

    def __init__(self):
        self.problems: list[int] = []

    def sample(self, bqm, **params):
        from dwave.samplers import SteepestDescentSolver

        self.problems.append(bqm.num_variables)
        sampleset = SteepestDescentSolver().sample(bqm, num_reads=5, seed=0)
        sampleset.info.update(charge_time=3_000_000, run_time=3_000_000, qpu_access_time=40_000)
        return sampleset


def test_hybrid_sends_a_batch_as_one_bqm_and_splits_its_samples(monkeypatch):
    from shared.solvers.hybrid import LeapHybridSolver

    solver = with_record(LeapHybridSolver(), "hybrid")
    fake = _FakeLeap()
    solver._sampler = fake
    bqms = [frustrated(8, s) for s in range(3)]
    results = solver.solve_batch([(bqm, 0, None) for bqm in bqms])
    sent = [r.info["residual_variables"] for r in results]
    assert fake.problems == [sum(sent)]
    assert sum(r.timing["charge_time"] for r in results) == pytest.approx(3.0)
    for bqm, result in zip(bqms, results, strict=True):
        assert result.energy == pytest.approx(bqm.energy(result.sample))
        assert isinstance(result.sampleset, dimod.SampleSet)


def test_hybrid_sim_estimate_is_its_charge_within_10_percent(tmp_path, capsys):
    import cv2

    from shared.cli import main
    from shared.config import MatchConfig
    from shared.images import load_pair
    from shared.pipeline import run_pipeline
    from shared.synthetic import make_scene

    scene = make_scene(12, 20, max_disparity=6, seed=5)
    left, right = tmp_path / "left.png", tmp_path / "right.png"
    cv2.imwrite(str(left), np.rint(scene.left * 255).astype(np.uint8))
    cv2.imwrite(str(right), np.rint(scene.right * 255).astype(np.uint8))
    params = [f"--param={key}={value}" for key, value in QUICK_HYBRID.items()]
    argv = ["estimate", str(left), str(right), "--local", "--json", "--solver", "hybrid-sim",
            "--max-disparity", "6", *params]  # fmt: skip
    assert main(argv) == 0
    estimate = json.loads(capsys.readouterr().out)
    config = MatchConfig(solver="hybrid-sim", max_disparity=6, solver_params=QUICK_HYBRID)
    # the pair as the estimate read it (8-bit files): which tiles certify is discrete
    result = run_pipeline(*load_pair(left, right), config)
    charge = sum(qpu_time.charged_seconds(level.timing) for level in result.levels)
    # one problem per level, billed for the variables the host left (not 3 s per row)
    sent = [level.info["variables_sent"] for level in result.levels]
    assert charge == pytest.approx(sum(qpu_time.hybrid_level_seconds(n) for n in sent))
    assert estimate["seconds"] == pytest.approx(charge, rel=0.1)
    for level, planned in zip(result.levels, estimate["levels"], strict=True):
        assert 0 < level.info["variables_sent"] <= level.info["variables"]
        # the host settles the level: only the tiles around its unsettled pixels are sent
        assert 0 < level.residual["pixels_sent"] < level.residual["pixels"]
        assert level.residual["certified"] == planned["pixels_certified"]


def test_qpu_sim_packs_rests_into_one_call_on_disjoint_copies(tmp_path):
    from shared.solvers.qpu.dwave import SimulatedQPUSolver
    from shared.solvers.qpu.embedding_cache import DirectoryStore, EmbeddingCache
    from shared.solvers.qpu.packing import MAX_COPIES

    solver = with_record(
        SimulatedQPUSolver(cache=EmbeddingCache(DirectoryStore(tmp_path))), "qpu-sim"
    )
    bqms = [frustrated(8, s) for s in range(MAX_COPIES + 2)]
    results = solver.solve_batch([(bqm, s, None) for s, bqm in enumerate(bqms)], num_reads=5)
    per_call = [r.info["bundles_per_call"] for r in results]
    assert per_call == [MAX_COPIES] * MAX_COPIES + [2, 2]  # a small row: 8 copies fit
    first = results[:MAX_COPIES]
    call = qpu_time.qpu_access_seconds(first[0].info["call_qubits"], {"num_reads": 5})
    # one programming for eight bundles, shared by their qubits
    assert sum(r.timing["qpu_access_time"] for r in first) == pytest.approx(call)
    for r in first:
        share = r.info["qubits"] / r.info["call_qubits"]
        assert r.timing["qpu_access_time"] == pytest.approx(call * share)
    for bqm, result in zip(bqms, results, strict=True):
        assert result.energy == pytest.approx(bqm.energy(result.sample))
        assert 0 < result.info["residual_variables"] < bqm.num_variables
