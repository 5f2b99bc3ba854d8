"""Gurobi: exact on bundles inside the pip licence, a clear error outside it."""

from __future__ import annotations

import dimod
import pytest
from solver_helpers import optimum, random_bqm, stereo_costs

from shared.config import get_settings
from shared.encodings import get_codec
from shared.energy import mrf_energy
from shared.solvers import SolverError
from shared.solvers.gurobi import PIP_LICENCE_VARIABLES, licence_kind
from shared.solvers.registry import get_solver


@pytest.mark.parametrize("encoding", ["one-hot", "domain-wall"])
def test_gurobi_matches_exact_on_a_row_inside_the_licence(encoding):
    costs = stereo_costs(1, 12)  # 48 / 36 variables
    codec = get_codec(encoding)
    bqm = codec.encode(costs)
    assert bqm.num_variables <= PIP_LICENCE_VARIABLES
    result = get_solver("gurobi").solve(bqm, seed=0, time_limit=30, mip_gap=0.0, threads=1)
    assert result.info["optimal"] is True
    labels = codec.decode(costs, result.sample).labels
    assert mrf_energy(costs, labels) == pytest.approx(optimum(costs), rel=1e-9)
    assert result.timing["solver"] <= result.wall_time


def test_bundle_above_the_pip_licence_names_the_limit_and_the_fix():
    if licence_kind(get_settings()) != "pip":
        pytest.skip("a full Gurobi licence is configured")
    bqm = get_codec("one-hot").encode(stereo_costs(1, 60))  # 240 variables
    with pytest.raises(SolverError) as caught:
        get_solver("gurobi").solve(bqm, seed=0)
    message = str(caught.value)
    assert "240 variables" in message
    assert f"at most {PIP_LICENCE_VARIABLES} variables" in message
    assert "GRB_LICENSE_FILE" in message and "GRB_WLSACCESSID" in message


def test_availability_reports_the_licence_kind(monkeypatch, tmp_path):
    solver = get_solver("gurobi")
    reason = solver.available().reason
    assert "size-limited pip licence" in reason and "200 variables" in reason
    monkeypatch.setenv("GRB_LICENSE_FILE", str(tmp_path / "gurobi.lic"))
    assert solver.available().reason == "full licence (GRB_LICENSE_FILE)"


@pytest.mark.parametrize("seed", range(4))
def test_tiny_coefficients_are_not_lost_in_gurobi_tolerances(seed):
    """MRF energies are small; unscaled, Gurobi calls a non-optimal state optimal here."""
    bqm = random_bqm(14, seed)
    bqm.scale(1e-8)
    ground = dimod.ExactSolver().sample(bqm).first.energy
    result = get_solver("gurobi").solve(bqm, seed=0)
    assert result.energy == pytest.approx(ground, rel=1e-9, abs=1e-18)
    assert result.info["bound"] == pytest.approx(ground, rel=1e-6)
