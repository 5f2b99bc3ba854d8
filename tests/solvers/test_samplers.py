"""Every QUBO solver is a dimod sampler; the composites do what they say; any installed dimod
sampler runs by name (``dimod:PACKAGE.MODULE.CLASS``); plugins come from entry points."""

from __future__ import annotations

import sys

import dimod
import numpy as np
import pytest
from dwave.samplers import SteepestDescentSolver
from solver_helpers import optimum, random_bqm, stereo_costs

from shared.config import MatchConfig
from shared.encodings import get_codec
from shared.energy import mrf_energy
from shared.pipeline import run_pipeline
from shared.solvers import SolverError, SolverSpec, UnknownSolverError, registry, solve
from shared.solvers.base import sample_array
from shared.solvers.composites import (
    EmbeddingCacheComposite,
    RoofDualityComposite,
    SolverComposite,
)
from shared.solvers.meters.qpu_time import is_metered, meter_of
from shared.solvers.qpu.embedding_cache import DirectoryStore, EmbeddingCache
from shared.solvers.registry import get_solver
from shared.synthetic import make_scene

SD = "dimod:dwave.samplers.SteepestDescentSolver"


@pytest.mark.parametrize("name", registry.solver_names())
def test_every_registered_qubo_solver_is_a_dimod_sampler(name):
    solver = get_solver(name)
    assert isinstance(solver, dimod.Sampler), name
    assert isinstance(solver.parameters, dict) and isinstance(solver.properties, dict)
    assert registry.spec(name).row_solver == hasattr(solver, "solve_rows")


def test_capabilities_are_declared_once_in_the_registry():
    meters = {"qpu": "qpu", "qpu-sim": "qpu", "hybrid": "hybrid", "hybrid-sim": "hybrid"}
    for name in ["exact", "sa", "tabu", "steepest-descent", "gurobi", *meters]:
        assert meter_of(name) == registry.spec(name).meter == meters.get(name), name
    assert meter_of("no-such-solver") is None and not is_metered("no-such-solver")
    assert is_metered("qpu-sim") and not get_solver("qpu-sim").uses_qpu_time
    assert get_solver("qpu").uses_qpu_time and not is_metered(SD)
    assert [n for n in registry.solver_names() if registry.spec(n).row_solver] == ["exact"]
    assert registry.resolve(SD).spec.queue_name == "dimod" and "dimod" in registry.queue_names()
    assert get_solver("sa").description == registry.spec("sa").description


def test_the_sample_set_carries_timing_in_seconds_and_the_solver_info():
    bqm = get_codec("domain-wall").encode(stereo_costs(1, 6))
    sampleset = get_solver("tabu").sample(bqm, seed=1, timeout=5)
    assert isinstance(sampleset, dimod.SampleSet) and sampleset.info["num_reads"] == 4
    result = solve(get_solver("sa"), bqm, seed=1, preprocess="none")  # dwave-samplers: ns
    assert result.timing and all(0 <= value < 60 for value in result.timing.values())
    assert result.energy == pytest.approx(bqm.energy(result.sample))


def test_roof_duality_composite_fixes_variables_and_completes_every_sample():
    costs = stereo_costs(1, 8)
    bqm = get_codec("domain-wall").encode(costs)
    sampleset = RoofDualityComposite(SteepestDescentSolver()).sample(bqm, num_reads=3, seed=0)
    assert sampleset.info["fixed_fraction"] > 0
    assert len(sampleset.variables) == bqm.num_variables
    energies = bqm.energies((sampleset.record.sample, list(sampleset.variables)))
    np.testing.assert_allclose(sampleset.record.energy, energies)
    best = sample_array(sampleset.first.sample, bqm.num_variables)
    labels = get_codec("domain-wall").decode(costs, best).labels
    assert mrf_energy(costs, labels) == pytest.approx(optimum(costs), rel=1e-9)
    none = RoofDualityComposite(SteepestDescentSolver()).sample(bqm, preprocess="none")
    assert none.info["fixed_fraction"] == 0
    with pytest.raises(SolverError, match="unknown preprocess 'magic'"):
        RoofDualityComposite(SteepestDescentSolver()).sample(bqm, preprocess="magic")


def test_solver_composite_passes_warm_starts_the_dimod_way():
    bqm = random_bqm(12, seed=3)
    start = np.ones(bqm.num_variables, dtype=np.int8)
    descent = SolverComposite(SteepestDescentSolver(), warm_overrides={"num_reads": 1})
    descent.name = "steepest-descent"
    states = (start.reshape(1, -1), list(range(bqm.num_variables)))
    warm = descent.sample(bqm, initial_states=states, num_reads=7)
    expected = SteepestDescentSolver().sample(bqm, initial_states=states)
    assert warm.info["warm_start"] and len(warm) == 1
    assert warm.first.energy == pytest.approx(expected.first.energy)
    # a sampler that takes no initial states runs cold, and says so
    exact = SolverComposite(dimod.ExactSolver()).sample(bqm, initial_states=states)
    assert exact.info["warm_start"] is False


def test_embedding_cache_composite_reuses_the_stored_embedding(tmp_path):
    from dwave.system.testing import MockDWaveSampler

    mock = MockDWaveSampler(topology_type="pegasus", topology_shape=[4])
    cache = EmbeddingCache(DirectoryStore(tmp_path))
    composite = EmbeddingCacheComposite(mock, cache, "pegasus4", "qpu-sim")
    bqm = get_codec("domain-wall").encode(stereo_costs(1, 4))
    first = composite.sample(bqm, num_reads=5, chain_strength=2.0)
    assert first.info["embedding_cache"] == "computed" and first.info["qubits"] > 0
    again = EmbeddingCacheComposite(
        mock, EmbeddingCache(DirectoryStore(tmp_path)), "pegasus4", "qpu-sim"
    )
    second = again.sample(bqm, num_reads=5, chain_strength=2.0)
    assert (
        second.info["embedding_cache_hit"]
        and second.info["embedding_key"] == first.info["embedding_key"]
    )
    assert set(second.variables) == set(bqm.variables)


def test_a_dimod_sampler_by_name_runs_through_the_composites():
    solver = get_solver(SD)
    assert isinstance(solver, dimod.Sampler)
    assert isinstance(solver.children[0], RoofDualityComposite)
    bqm = get_codec("domain-wall").encode(stereo_costs(1, 8))
    result = solver.solve(bqm, seed=2, initial_state=np.zeros(bqm.num_variables, np.int8))
    assert result.info["preprocess"] == "roof-duality" and result.info["warm_start"]


def test_a_dimod_sampler_refuses_a_parameter_it_does_not_take():
    """dimod samplers only warn about unknown keywords and ignore them: a typo would go unseen."""
    bqm = get_codec("domain-wall").encode(stereo_costs(1, 8))
    with pytest.raises(SolverError, match=r"unknown parameters num_raeds; it takes .*num_reads"):
        get_solver(SD).solve(bqm, seed=2, num_raeds=5)
    taken = get_solver(SD).solve(bqm, seed=2, num_reads=3, preprocess="none")
    assert taken.info["num_reads"] == 3


def test_a_dimod_sampler_matches_a_synthetic_scene_in_process():
    pair = make_scene(12, 32, max_disparity=6, seed=2)
    common = {"max_disparity": 6, "seed": 3, "encoding": "domain-wall"}
    ours = run_pipeline(pair.left, pair.right, MatchConfig(solver=SD, **common))
    builtin = run_pipeline(pair.left, pair.right, MatchConfig(solver="exact", **common))
    assert ours.disparity.shape == pair.left.shape[:2]

    def bad(disparity: np.ndarray) -> float:
        return float(np.mean(np.abs(disparity - pair.disparity) > 1))

    # roof duality then descent: as few bad pixels as the exact row DP, give or take
    assert bad(ours.disparity) <= bad(builtin.disparity) + 0.03
    assert np.mean(np.abs(ours.disparity - pair.disparity)) < 1.0


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("dimod:this.X", "is not among the dimod samplers this service allows"),
        ("dimod:lib2to3.__main__.X", "is not among the dimod samplers this service allows"),
        ("dimod:dimod.Structured", "is not among the dimod samplers this service allows"),
        ("dimod:no_such_package.Sampler", "cannot import no_such_package"),
        ("dimod:dimod.Structured", "not a dimod.Sampler subclass"),
        ("dimod:dwave.samplers.NoSuchSampler", "has no NoSuchSampler"),
        ("dimod:Sampler", "dimod:PACKAGE.MODULE.CLASS"),
    ],
    ids=["zen", "2to3", "not-allowed", "missing", "not-a-sampler", "no-class", "malformed"],
)
def test_a_bad_dimod_name_says_what_to_do_and_imports_nothing_not_allowed(
    name, message, monkeypatch
):
    """Only allowed classes are imported; the deployment's own (QHSM_DIMOD_SAMPLERS) that do
    not load say why."""
    if "not among" not in message:  # the operator allowed it; it does not load
        path = name.removeprefix("dimod:")
        monkeypatch.setenv("QHSM_DIMOD_SAMPLERS", f'{{"{path}": {{}}}}')
    module = name.removeprefix("dimod:").rpartition(".")[0]
    before = set(sys.modules)
    with pytest.raises(UnknownSolverError) as caught:
        get_solver(name)
    assert message in str(caught.value) and "QHSM_DIMOD_SAMPLERS" in str(caught.value)
    if "not among" in message:
        assert module not in set(sys.modules) - before


def test_allowed_dimod_samplers_have_bounded_parameters(monkeypatch):
    """As for the built-in solvers: a sweep count that would run for hours is refused."""
    from shared.solvers import InvalidSolverParamsError
    from shared.solvers.registry import check_params

    anneal = "dimod:dwave.samplers.SimulatedAnnealingSampler"
    assert check_params(anneal, {"num_reads": 10, "num_sweeps": 1000}) == {
        "num_reads": 10,
        "num_sweeps": 1000,
    }
    for bad in ({"num_sweeps": 10**8}, {"num_reads": 1000, "num_sweeps": 100_000}, {"x": 1}):
        with pytest.raises(InvalidSolverParamsError):
            check_params(anneal, bad)
    with pytest.raises(InvalidSolverParamsError, match="unknown parameter"):
        check_params("dimod:dimod.ExactSolver", {"num_reads": 2})
    monkeypatch.setenv("QHSM_DIMOD_SAMPLERS", '{"dimod.NullSampler": {"num_reads": [1, 5]}}')
    assert check_params("dimod:dimod.NullSampler", {"num_reads": 5}) == {"num_reads": 5}
    with pytest.raises(InvalidSolverParamsError, match="less than or equal to 5"):
        check_params("dimod:dimod.NullSampler", {"num_reads": 6})


def test_an_exact_enumeration_refuses_a_bundle_above_its_size():
    bqm = get_codec("one-hot").encode(stereo_costs(1, 12, labels=4))
    with pytest.raises(SolverError, match="at most 24 variables per bundle"):
        get_solver("dimod:dimod.ExactSolver").solve(bqm, preprocess="none")
    small = get_codec("domain-wall").encode(stereo_costs(1, 4, labels=3))
    result = get_solver("dimod:dimod.ExactSolver").solve(small)
    assert result.energy == pytest.approx(float(dimod.ExactSolver().sample(small).first.energy))


def test_plugins_register_through_the_entry_point_group(tmp_path, monkeypatch):
    package = tmp_path / "qhsm_probe_plugin.py"
    package.write_text(
        "from shared.solvers import SolverSpec\n"
        "from shared.solvers.composites import SolverComposite\n"
        "import dimod\n"
        "PROBE = SolverSpec('ignored', lambda: SolverComposite(dimod.ExactSolver()),\n"
        "                  description='probe', queue='probe-queue')\n"
    )
    info = tmp_path / "qhsm_probe_plugin-0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: qhsm-probe-plugin\nVersion: 0\n")
    (info / "entry_points.txt").write_text("[qhsm.solvers]\nprobe = qhsm_probe_plugin:PROBE\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(registry, "_SPECS", dict(registry._SPECS))
    monkeypatch.setattr(registry, "_INSTANCES", {})
    monkeypatch.delitem(sys.modules, "qhsm_probe_plugin", raising=False)
    assert "probe" in registry.solver_names()
    assert registry.spec("probe") == SolverSpec(
        "probe", registry.spec("probe").factory, description="probe", queue="probe-queue"
    )
    assert registry.resolve("probe").spec.queue_name == "probe-queue"
    assert isinstance(get_solver("probe"), dimod.Sampler)


def test_solve_maps_bad_parameters_to_our_error_and_lets_other_exceptions_through():
    bqm = random_bqm(6, seed=1)
    with pytest.raises(SolverError, match="SteepestDescentSolver: invalid parameters"):
        solve(SteepestDescentSolver(), bqm, num_reads=-1)

    class Interrupted(Exception):  # like Celery's SoftTimeLimitExceeded
        pass

    class Stopped(dimod.ExactSolver):
        def sample(self, bqm, **params):
            raise Interrupted

    with pytest.raises(Interrupted):
        solve(SolverComposite(Stopped()), bqm)
