"""A run's solver resolved once (issue 30 item 1): ``registry.resolve`` answers what the code
downstream asks about it, samplers know no registry, and the hybrid solver is no QPU adapter."""

from __future__ import annotations

import ast
import pickle
from pathlib import Path

import pytest

from shared.config import MatchConfig
from shared.solvers import SolverSpec, UnknownSolverError, registry
from shared.solvers.resolved import ResolvedSolver

ROOT = Path(__file__).resolve().parents[2]


def test_a_solver_resolves_to_its_kind_queue_and_meter():
    assert registry.resolve("exact").kind == "rows"
    assert registry.resolve("sa").kind == "qubo"
    assert registry.resolve("hybrid-sim").kind == "batch"
    assert registry.resolve("qpu-sim").kind == "batch"  # packed calls
    sim = registry.resolve("qpu-sim")
    assert (sim.spec.queue_name, sim.spec.meter, sim.spec.metered) == ("qpu-sim", "qpu", True)
    assert sim.plans_with_solver and not registry.resolve("hybrid-sim").plans_with_solver
    assert (registry.resolve("sa").spec.meter, registry.resolve("sa").spec.metered) == (None, False)


def test_exacts_grids_resolve_without_building_a_sampler():
    def never() -> None:
        raise AssertionError("the sampler was built")

    config = MatchConfig(solver="exact", max_disparity=6)
    solver = ResolvedSolver(registry.spec("exact"), config, never)
    assert solver.spec.row_solver and solver.kind == "rows" and solver.solves_grids
    assert not solver.certifies_tiles and not solver.plans_with_solver
    assert solver.bundle_width_setting() is None


def test_what_the_config_makes_of_the_solver():
    sa = MatchConfig(solver="sa", max_disparity=6)
    assert registry.resolve(sa).warm_start  # sa's record: warm-started by default
    assert not registry.resolve(sa.model_copy(update={"warm_start": False})).warm_start
    old_client = sa.model_copy(update={"warm_start": True, "solver_params": {"warm_start": 0}})
    assert not registry.resolve(old_client).warm_start  # solver_params wins, as before
    assert registry.resolve(sa).certifies_tiles  # grid inference, a QUBO solver
    rows = MatchConfig(solver="sa", max_disparity=6, inference="rows")
    assert not registry.resolve(rows).certifies_tiles
    with pytest.raises(ValueError, match="without a configuration"):
        _ = registry.resolve("sa").warm_start


def test_params_are_checked_against_the_resolved_solvers_schema():
    from shared.solvers import InvalidSolverParamsError

    config = MatchConfig(solver="sa", max_disparity=6, solver_params={"num_reads": 5})
    assert registry.resolve(config).checked_params()["num_reads"] == 5
    bad = config.model_copy(update={"solver_params": {"num_reads": 10**9}})
    with pytest.raises(InvalidSolverParamsError):
        registry.resolve(bad).checked_params()


def test_an_unknown_name_says_which_are_known():
    with pytest.raises(UnknownSolverError, match="known solvers: exact, sa"):
        registry.resolve("nope")


def test_a_resolved_solver_pickles_without_its_sampler():
    solver = registry.resolve(MatchConfig(solver="sa", max_disparity=6))
    assert solver.kind == "qubo"  # the sampler is built now
    assert "sampler" in solver.__dict__
    copy = pickle.loads(pickle.dumps(solver))
    assert "sampler" not in copy.__dict__
    assert copy.spec == solver.spec and copy.config == solver.config
    assert copy.sampler is registry.get_solver("sa")  # built again (here: the kept one)


def test_the_registry_refuses_a_row_solver_flag_its_sampler_contradicts(monkeypatch):
    monkeypatch.setattr(registry, "_SPECS", dict(registry._SPECS))
    registry.register(SolverSpec("rows-liar", "shared.solvers.anneal:tabu", row_solver=True))
    with pytest.raises(TypeError, match="row_solver=True"):
        registry.build("rows-liar")


def test_samplers_know_no_registry():
    """The sampler base class gets its record from whoever builds it: no module of the samplers'
    contract imports the registry, and a sampler built by hand has no record (no defaults)."""
    for name in ("base.py", "sampler.py", "records.py", "resolved.py", "errors.py"):
        tree = ast.parse((ROOT / "shared/solvers" / name).read_text())
        imported = {
            node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)
        } | {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import)
             for alias in node.names}  # fmt: skip
        assert "shared.solvers.registry" not in imported, name
    from shared.solvers.exact import ExactSolver

    by_hand = ExactSolver()
    assert by_hand.spec is None and by_hand.defaults == {}
    built = registry.build("qpu-sim")
    assert built.spec == registry.spec("qpu-sim") and built.defaults["num_reads"] == 20


def test_the_hybrid_solver_is_no_qpu_adapter():
    from shared.solvers.hybrid import KerberosSolver, LeapHybridSolver
    from shared.solvers.qpu.dwave import QPUSolver, _EmbeddedQPU

    assert not issubclass(LeapHybridSolver, _EmbeddedQPU)
    assert not issubclass(KerberosSolver, _EmbeddedQPU)
    assert issubclass(QPUSolver, _EmbeddedQPU)
