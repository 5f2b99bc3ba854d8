"""Meters as registered things (issue 21): every solver's ``SolverSpec.meter`` names one, a
plugin's meter is estimated and charged like the built-in ones, each reads its own charge."""

from __future__ import annotations

import pytest

from shared.config import MatchConfig
from shared.solvers import meters, registry
from shared.solvers.meters import LevelLoad, Meter, qpu_time
from shared.solvers.registry import resolve


class FlatMeter(Meter):
    """A service that bills a fixed fee per problem (``fee_time``)."""

    name = "flat"
    charge_keys = ("fee_time",)

    def bundle_seconds(self, call) -> float:
        return 0.5

    def level_seconds(self, solver, params, load: LevelLoad, live=None):
        return load.sent * 0.5, None


@pytest.fixture
def flat(monkeypatch) -> str:
    monkeypatch.setattr(meters, "_METERS", dict(meters._METERS))
    monkeypatch.setattr(registry, "_SPECS", dict(registry._SPECS))
    meters.register_meter(FlatMeter())
    registry.register("flat-solver", "shared.solvers.anneal:simulated_annealing", meter="flat")
    return "flat-solver"


def test_every_registered_solver_names_a_registered_meter():
    for name in registry.solver_names():
        meter = registry.spec(name).meter
        assert meter is None or meter in meters.meter_names(), name
    assert meters.meter_for("qpu-sim").embeds and not meters.meter_for("hybrid-sim").embeds
    assert meters.meter_for("sa") is None


def test_a_plugins_meter_estimates_and_charges_its_solver(flat):
    config = MatchConfig(solver=flat, preset="paper", max_disparity=6)
    job = qpu_time.job_seconds(resolve(config), (16, 24), 6)
    assert job.seconds == pytest.approx(0.5 * job.bundles_sent) and job.seconds > 0
    assert job.as_dict()["metered"]
    assert meters.bundle_seconds(flat, 100) == 0.5
    assert meters.meter_for(flat).charged_seconds({"fee_time": 2.0, "qpu_access_time": 1.0}) == 2.0


def test_an_unknown_meter_is_named(monkeypatch):
    monkeypatch.setattr(registry, "_SPECS", dict(registry._SPECS))
    registry.register("metered-nowhere", "shared.solvers.exact:ExactSolver", meter="nowhere")
    with pytest.raises(KeyError, match="unknown meter 'nowhere'"):
        meters.meter_for("metered-nowhere")


def test_each_meter_reads_its_own_charge():
    timing = {"qpu_access_time": 0.04, "charge_time": 3.0}
    assert meters.meter_for("qpu").charged_seconds(timing) == 0.04
    assert meters.meter_for("hybrid").charged_seconds(timing) == 3.0
    assert meters.meter_for("hybrid").charged_seconds({"qpu_access_time": 0.04}) == 0.04
    assert meters.charged_seconds(timing) == 3.0  # no meter at hand: charge_time first
    assert meters.meter_for("qpu").charged_seconds({"qpu_access_time": -1.0}) == 0.0
