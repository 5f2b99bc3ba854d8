"""Per-solver parameter schemas (issue 10, item 2): every registered solver declares one, the
adapters' own defaults and presets are inside it, and anything outside is refused with a
message that states the allowed range."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from shared.solvers import InvalidSolverParamsError
from shared.solvers.params import AnnealParams, NoParams, SolverParams
from shared.solvers.registry import check_params, params_schema, solver_names


def test_every_registered_solver_has_a_schema():
    for name in solver_names():
        assert issubclass(params_schema(name), SolverParams), name
    assert params_schema("exact") is NoParams
    assert params_schema("sa") is AnnealParams


def test_adapter_defaults_and_presets_are_inside_their_schemas():
    from shared.solvers.anneal import SA_PRESETS
    from shared.solvers.registry import get_solver

    for preset, values in SA_PRESETS.items():
        assert check_params("sa", {"preset": preset, **values})["preset"] == preset
    assert set(AnnealParams.model_fields["preset"].annotation.__args__) == set(SA_PRESETS)
    for name in ("tabu", "steepest-descent", "hybrid-sim", "gurobi", "qpu", "hybrid"):
        assert check_params(name, get_solver(name).defaults) == get_solver(name).defaults
    assert get_solver("tabu").defaults == {"num_reads": 4, "timeout": 25}
    check_params("gurobi", {"time_limit": 60, "mip_gap": 0, "threads": 1})
    check_params("qpu", {"num_reads": 500, "annealing_time": 20, "warm_start": True})
    # other DWaveSampler parameters pass on to the sampler, which checks them itself
    assert check_params("qpu", {"answer_mode": "raw"}) == {"answer_mode": "raw"}


@pytest.mark.parametrize(
    ("solver", "params", "said"),
    [
        # the two reproductions of the issue: a stalled worker and a 261 GiB allocation
        ("sa", {"num_reads": 10, "num_sweeps": 100_000_000}, "num_sweeps (int, 1..100000)"),
        ("sa", {"num_reads": 10, "num_sweeps": 100_000_000}, "less than or equal to 100000"),
        ("sa", {"num_reads": 1e9}, "num_reads (int, 1..1000)"),
        ("tabu", {"timeout": 10**9}, "timeout (int, 1..60000)"),
        # the work of a bundle is bounded too, presets included
        ("sa", {"num_reads": 1000, "num_sweeps": 100_000}, "num_reads x num_sweeps = 100000000"),
        ("sa", {"preset": "paper", "num_sweeps": 100_000}, "num_reads x num_sweeps = 50000000"),
        ("tabu", {"num_reads": 1000, "timeout": 60_000}, "is above 600 s per bundle"),
        ("qpu-sim", {"num_reads": 0}, "num_reads (int, 1..10000)"),
        ("hybrid-sim", {"max_time": float("inf")}, "max_time (float, 0..600)"),
        ("gurobi", {"TimeLimit": 1e9}, "time_limit (float, 0..600)"),
        ("gurobi", {"time_limit": 1e9}, "less than or equal to 600"),
        ("exact", {"num_reads": 1}, "Allowed parameters: warm_start (bool)"),
    ],
)
def test_out_of_range_parameters_are_refused_with_the_allowed_range(solver, params, said):
    with pytest.raises(InvalidSolverParamsError) as error:
        check_params(solver, params)
    message = str(error.value)
    assert message.startswith(f"solver_params for {solver!r}: ")
    assert said in message


@given(st.integers(min_value=1, max_value=100_000))
def test_sa_sweeps_inside_the_range_pass_unchanged(sweeps):
    assert check_params("sa", {"num_sweeps": sweeps}) == {"num_sweeps": sweeps}


@given(st.integers(min_value=100_001) | st.integers(max_value=0))
def test_sa_sweeps_outside_the_range_are_refused(sweeps):
    with pytest.raises(InvalidSolverParamsError, match="num_sweeps"):
        check_params("sa", {"num_sweeps": sweeps})


def test_only_given_parameters_are_kept_with_json_types():
    assert check_params("sa", {"num_reads": "7", "beta_range": [0.1, 5]}) == {
        "num_reads": 7,
        "beta_range": [0.1, 5.0],
    }
