"""Every solver that runs here without credentials passes dimod's own sampler conformance
suite: ``dimod.testing.load_sampler_bqm_tests`` (SPIN and BINARY BQMs of each BQM class, any
hashable labels, empty BQMs, ``sample_ising`` / ``sample_qubo``) and ``assert_sampler_api`` /
``assert_composite_api``. The solvers are read from the registry (and the ``dimod:`` allowlist),
so a solver registered later is covered without editing this file. ``qpu`` and ``hybrid`` need
Leap: their real adapters run the same suite against Ocean's own mocks (dwave-system's
``MockDWaveSampler`` as ``DWaveSampler``, its ``MockLeapHybridSolver`` behind a mocked cloud
``Client``)."""

from __future__ import annotations

import os
import unittest
import uuid
from typing import Any
from unittest import mock

import dimod
import dimod.testing
import numpy as np
import pytest
from dimod.testing.asserts import assert_composite_api, assert_sampler_api
from dwave.system.testing import MockDWaveSampler, MockLeapHybridSolver
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.solvers import registry
from shared.solvers.canonical import Canonical
from shared.solvers.plugins import BUILTIN_SAMPLERS
from shared.solvers.records import DIMOD_PREFIX
from shared.solvers.registry import get_solver


def _ships_with_qhsm(name: str) -> bool:
    """Whether a registered solver is the project's own: the service tests' plugin registers
    deliberately broken or flaky doubles (``fake-*``), which this suite must not hold to dimod."""
    factory = registry.spec(name).factory
    module = factory.split(":")[0] if isinstance(factory, str) else factory.__module__
    return module.split(".")[0] == "shared"


def _offline_solvers() -> list[str]:
    """The project's registered solvers that spend no D-Wave time, and every allowed
    ``dimod:`` sampler."""
    names = [
        name
        for name in registry.solver_names()
        if _ships_with_qhsm(name) and not registry.spec(name).uses_qpu_time
    ]
    return [*names, *(DIMOD_PREFIX + path for path in BUILTIN_SAMPLERS)]


class MockQPU(MockDWaveSampler):
    """``DWaveSampler`` as dwave-system's tests replace it: the client's options (token,
    solver, region) accepted, a Pegasus graph (P6: a few hundred ms to build)."""

    def __init__(self, **config: Any) -> None:
        super().__init__(topology_type="pegasus", topology_shape=[6], parameter_warnings=False)


class LabelledMockLeapHybridSolver(MockLeapHybridSolver):
    """dwave-system's ``MockLeapHybridSolver`` (steepest descent, Leap's properties) with what
    the real cloud client adds: a ``label`` parameter (kept in :attr:`labels`), and the
    problem's id and label in the answer's info."""

    def __init__(self) -> None:
        self.labels: list[str | None] = []

    def sample_bqm(self, sapi_problem_id: Any, time_limit: float, label: str | None = None):
        self.labels.append(label)
        future = super().sample_bqm(sapi_problem_id, time_limit)
        future.sampleset.info.update(problem_id=uuid.uuid4().hex, problem_label=label)
        return future


def _mock_leap_client() -> Any:
    """``LeapHybridSampler``'s cloud ``Client`` as dwave-system's tests mock it, its solver
    :class:`LabelledMockLeapHybridSolver`."""
    client = mock.MagicMock()
    client.get_solver.return_value = LabelledMockLeapHybridSolver()
    return mock.patch(
        "dwave.system.samplers.leap_hybrid_sampler.Client", **{"from_config.return_value": client}
    )


#: Each solver that needs Leap, and what stands in for Leap in its test (Ocean's own mocks).
CLOUD_MOCKS = {
    "qpu": lambda: mock.patch("dwave.system.DWaveSampler", MockQPU),
    "hybrid": _mock_leap_client,
}
OFFLINE = _offline_solvers()
CLOUD = [name for name in registry.solver_names() if registry.spec(name).uses_qpu_time]


def _factory(name: str, fresh: bool = False):
    def sampler() -> dimod.Sampler:
        return registry.build(name) if fresh else get_solver(name)

    sampler.__name__ = name.replace("-", "_").replace(":", "_").replace(".", "_")
    return sampler


class _Available(unittest.TestCase):
    solver = ""

    def setUp(self) -> None:
        availability = get_solver(self.solver).available()
        if not availability.ok:
            self.skipTest(availability.reason)


class _MockedLeap(unittest.TestCase):
    """A token (a dummy) and Ocean's mock of the solver's cloud service for every test."""

    solver = ""

    def setUp(self) -> None:
        self.enterContext(mock.patch.dict(os.environ, {"DWAVE_API_TOKEN": "mock-token"}))
        self.enterContext(CLOUD_MOCKS[self.solver]())


def _suite(name: str, base: type[unittest.TestCase], fresh: bool = False) -> None:
    case = type(f"TestDimodSuite_{_factory(name).__name__}", (base,), {"solver": name})
    globals()[case.__name__] = dimod.testing.load_sampler_bqm_tests(_factory(name, fresh))(case)


for _name in OFFLINE:
    _suite(_name, _Available)
for _name in CLOUD:  # a fresh adapter per test: the mocked cloud stays out of the registry's
    _suite(_name, _MockedLeap, fresh=True)


def test_every_cloud_solver_has_an_ocean_mock_here():
    assert sorted(CLOUD) == sorted(CLOUD_MOCKS)


@pytest.mark.parametrize("name", OFFLINE + CLOUD)
def test_the_sampler_api(name):
    sampler = registry.build(name)
    assert_sampler_api(sampler)
    if isinstance(sampler, dimod.Composite):
        assert_composite_api(sampler)


_labels = st.one_of(
    st.integers(-3, 8), st.text("abc", max_size=2), st.tuples(st.integers(0, 2), st.just("x"))
)


@st.composite
def _bqms(draw) -> dimod.BinaryQuadraticModel:
    """Small BQMs of either vartype on any hashable labels."""
    variables = draw(st.lists(_labels, unique=True, max_size=5))
    bias = st.floats(-5, 5, allow_nan=False)
    bqm = dimod.BinaryQuadraticModel(draw(st.sampled_from([dimod.SPIN, dimod.BINARY])))
    for v in variables:
        bqm.add_linear(v, draw(bias))
    for i, u in enumerate(variables):
        for v in variables[i + 1 :]:
            if draw(st.booleans()):
                bqm.add_quadratic(u, v, draw(bias))
    bqm.offset = draw(bias)
    return bqm


@given(_bqms(), st.integers(0, 2**31))
@settings(max_examples=60, deadline=None)
def test_the_canonical_form_keeps_every_energy_and_maps_warm_starts_back(bqm, seed):
    """Every state of the canonical BINARY 0..n-1 form has the energy of the state it maps
    back to, and a warm start given in the caller's form is the same state there."""
    form = Canonical.of(bqm)
    assert form.bqm.vartype is dimod.BINARY
    assert list(form.bqm.variables) == list(range(bqm.num_variables))
    if form.solved() is not None:
        assert bqm.num_variables == 0 and form.restore(form.solved()).first.energy == bqm.offset
        return
    answer = form.restore(dimod.ExactSolver().sample(form.bqm))
    assert answer.vartype is bqm.vartype and set(answer.variables) == set(bqm.variables)
    dimod.testing.assert_sampleset_energies(answer, bqm)
    values = np.random.default_rng(seed).integers(0, 2, size=(1, bqm.num_variables))
    if bqm.vartype is dimod.SPIN:
        values = 2 * values - 1
    given_order = list(bqm.variables)[::-1]  # columns in another order than the BQM's
    states, labels = form.states((values[:, ::-1], given_order))
    assert form.bqm.energies((states, labels))[0] == pytest.approx(
        bqm.energies((values, list(bqm.variables)))[0]
    )


def test_a_warm_start_in_the_callers_labels_and_vartype_reaches_the_solver():
    """Steepest descent (through the roof-duality composite, which reads states by column) from
    a SPIN state on string labels, given in another order, ends where dwave-samplers' own
    descent from that state ends."""
    from dwave.samplers import SteepestDescentSolver

    bqm = dimod.generators.gnp_random_bqm(list("abcdefgh"), 0.6, dimod.SPIN, random_state=4)
    start = ([[1, -1, 1, 1, -1, -1, 1, -1]], list("hgfedcba"))
    descent = get_solver(DIMOD_PREFIX + "dwave.samplers.SteepestDescentSolver")
    ours = descent.sample(bqm, initial_states=start, preprocess="none")
    theirs = SteepestDescentSolver().sample(bqm, initial_states=start)
    assert ours.vartype is dimod.SPIN and ours.first.sample == theirs.first.sample
