"""The exact row DP against brute force on the MRF and against dimod.ExactSolver on the QUBO."""

from __future__ import annotations

import itertools

import dimod
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.encodings import onehot
from shared.energy import mrf_energy
from shared.solvers import SolverError
from shared.solvers.base import sample_array
from shared.solvers.exact import ExactSolver, solve_chains
from shared.solvers.registry import get_solver


@given(
    width=st.integers(1, 6),
    labels=st.integers(2, 4),
    rows=st.integers(1, 3),
    seed=st.integers(0, 2**31),
)
@settings(max_examples=60, deadline=None)
def test_row_dp_finds_the_brute_force_optimum_of_every_row(random_costs, width, labels, rows, seed):
    costs = random_costs(np.random.default_rng(seed), rows, width, labels)
    labelling = solve_chains(costs)
    for row in range(rows):
        chain = costs.rows(row, row + 1)
        best = min(
            mrf_energy(chain, np.array([assignment]))
            for assignment in itertools.product(range(labels), repeat=width)
        )
        assert mrf_energy(chain, labelling[row : row + 1]) == pytest.approx(best)


def test_row_dp_matches_dimod_exact_solver_on_the_qubo(random_costs):
    costs = random_costs(np.random.default_rng(11), 1, 4, 4)
    bqm = onehot.encode(costs)
    ground = dimod.ExactSolver().sample(bqm).first
    decoded = onehot.decode(costs, sample_array(ground.sample, bqm.num_variables))
    labels = solve_chains(costs)
    assert mrf_energy(costs, labels) == pytest.approx(ground.energy)
    np.testing.assert_array_equal(labels, decoded.labels)


def test_exact_refuses_taller_bundles_with_a_clear_message():
    with pytest.raises(SolverError, match="single-row bundles"):
        ExactSolver.check_bundle_height(2)


def test_exact_adapter_brute_forces_small_bqms_and_refuses_large_ones():
    solver = get_solver("exact")
    assert solver.available().ok
    bqm = dimod.generators.gnp_random_bqm(10, 0.5, dimod.BINARY, random_state=3)
    result = solver.solve(bqm, seed=0)
    assert result.energy == pytest.approx(dimod.ExactSolver().sample(bqm).first.energy)
    with pytest.raises(SolverError, match="only up to"):
        solver.solve(dimod.generators.gnp_random_bqm(40, 0.1, dimod.BINARY), seed=0)
