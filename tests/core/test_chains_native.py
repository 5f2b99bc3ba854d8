"""The chain kernel in C (``shared/chains_native.c``, issue 28): numba's ``_chains_windows``
labels and energies bit for bit, and numba's ``_neighbour_costs`` of a window grid, on every
target it is built for, and the calls they cannot take left to numba."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

import shared.grid_kernels
from shared import kernels, native
from shared.chains_native import NativeChains, NativeNeighbourCosts
from shared.kernel_build import compiler_command

COMPILER = compiler_command() or ["cc"]
pytestmark = pytest.mark.skipif(
    shutil.which(COMPILER[0]) is None, reason=f"no C compiler ({COMPILER[0]}) to build it with"
)


@pytest.fixture(scope="module", params=["native", "generic"])
def library(request, tmp_path_factory):
    """Built for this CPU's x86-64 level, and for the generic target (no ``-march``)."""
    cpu = kernels.target_cpu() if request.param == "native" else ""
    path = tmp_path_factory.mktemp("native") / "chains.so"
    loaded = native.load(native.compile_library(COMPILER, path, cpu, "chains"), "chains")
    assert loaded is not None
    return loaded


@pytest.fixture(scope="module")
def chains_kernel(library):
    return NativeChains(library)


@pytest.fixture(scope="module")
def neighbours(library):
    return NativeNeighbourCosts(library)


def _arguments(seed: int, chains: int, length: int, count: int, turned: bool, ties: bool):
    """A windowed chain problem as dual decomposition passes it: half unaries plus signed
    multipliers, windows that move by any amount, edge weights of zero or more."""
    rng = np.random.default_rng(seed)
    base = rng.random((chains, length, count), dtype=np.float32)
    extra = rng.normal(0, 0.3, (chains, length, count)).astype(np.float32)
    if ties:  # a few values only: equal messages, where the first of equal labels must win
        base, extra = np.round(base * 2) / 2, np.round(extra * 2) / 2
    steps = rng.choice([0, 0, 0, 1, -1, 2, -3, count + 1], (chains, length))
    first = np.cumsum(steps, axis=1).astype(np.int32)
    first -= min(int(first.min()), 0)
    weight = rng.choice([0.0, 0.3, 1.0, 1.7], (chains, max(length - 1, 0)))
    labels = np.zeros((length, chains) if turned else (chains, length), dtype=np.int32)
    scale, sign = rng.choice([0.5, 1.0]), rng.choice([1.0, -1.0, 0.0])
    slope, truncation = float(rng.choice([0.1, 0.25, 1.0])), float(rng.choice([0.2, 0.4, 3.0]))
    return base, float(scale), extra, float(sign), first, weight, slope, truncation, labels, turned


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    chains=st.integers(1, 27),  # 12 (or 6) chains a step: whole steps and a step's tail
    length=st.integers(1, 24),
    count=st.integers(1, 9),
    turned=st.booleans(),
    ties=st.booleans(),
)
@example(seed=0, chains=13, length=9, count=6, turned=True, ties=True)
def test_the_c_kernel_gives_numbas_labels_and_energies(
    chains_kernel, seed, chains, length, count, turned, ties
):
    ours = _arguments(seed, chains, length, count, turned, ties)
    numbas = _arguments(seed, chains, length, count, turned, ties)
    energies = chains_kernel(*ours)
    assert energies is not None
    assert np.array_equal(energies, shared.grid_kernels._chains_windows(*numbas))
    assert np.array_equal(ours[8], numbas[8])  # the labels, in the layout asked for


def test_a_window_wider_than_its_buffer_is_left_to_numba(chains_kernel):
    assert chains_kernel(*_arguments(1, 3, 5, 65, False, False)) is NotImplemented


def _empty(chains: int, length: int) -> tuple:
    costs = np.zeros((chains, length, 4), np.float32)
    return (
        costs, 1.0, costs.copy(), 1.0, np.zeros((chains, length), np.int32),
        np.zeros((chains, max(length - 1, 0))), 0.1, 0.4, np.zeros((chains, length), np.int32),
        False,
    )  # fmt: skip


def test_empty_chains_are_left_to_numba_and_no_chains_give_no_energies(chains_kernel):
    assert chains_kernel(*_empty(3, 0)) is NotImplemented
    energies = chains_kernel(*_empty(0, 5))
    assert energies is not None and energies.shape == (0,)


def test_arrays_whose_shapes_disagree_are_left_to_numba(chains_kernel):
    arguments = list(_arguments(2, 4, 6, 3, False, False))
    arguments[8] = np.zeros((6, 4), dtype=np.int32)  # the turned layout, not asked for
    assert chains_kernel(*arguments) is NotImplemented
    arguments = list(_arguments(2, 4, 6, 3, False, False))
    arguments[5] = arguments[5][:, :-1].copy()  # one edge weight short
    assert chains_kernel(*arguments) is NotImplemented


def test_the_kernel_takes_the_c_kernel_first_and_numba_for_what_does_not_fit(chains_kernel):
    taken = []

    def c_kernel(*arguments):
        taken.append("native")
        return chains_kernel(*arguments)

    kernel = kernels.Kernel("_chains_windows", None, c_kernel)
    kernel._jit = lambda *arguments: (
        taken.append("jit") or shared.grid_kernels._chains_windows(*arguments)
    )
    fitting = _arguments(3, 5, 7, 4, False, False)
    kernel(*fitting)
    strided = list(_arguments(3, 5, 7, 4, False, False))
    strided[0] = np.asfortranarray(strided[0])
    kernel(*strided)
    wide = _arguments(3, 2, 3, 70, False, False)
    kernel(*wide)  # the C kernel declines: numba
    assert taken == ["native", "jit", "native", "jit"]


def test_a_compiler_without_the_cpu_level_builds_the_generic_target(tmp_path):
    built = native.compile_library(COMPILER, tmp_path / "chains.so", "x86-64-v99", "chains")
    assert native.load(built, "chains") is not None


def test_a_failed_compile_says_why_and_leaves_nothing(tmp_path):
    failing = shutil.which("false") or "false"
    with pytest.raises(RuntimeError, match="failed"):
        native.compile_library([failing], tmp_path / "chains.so", "x86-64-v2", "chains")
    assert list(tmp_path.iterdir()) == []


def test_a_damaged_library_is_not_loaded(tmp_path):
    (tmp_path / "chains.so").write_bytes(b"not a library")
    assert native.load(tmp_path / "chains.so", "chains") is None
    assert native.load(tmp_path / "missing.so", "chains") is None


def test_a_library_without_the_kernel_is_not_loaded(tmp_path):
    """Another source's library where the chain kernel's is expected is left."""
    built = native.compile_library(COMPILER, tmp_path / "chains.so", "", "volume")
    assert native.load(built, "volume") is not None
    assert native.load(built, "chains") is None


def _neighbour_arguments(seed: int, height: int, width: int, count: int, vertical: bool):
    """A window grid's edges as the chain primal step passes them (``GridMRF.edges``), fixed
    labels, and a buffer to write."""
    rng = np.random.default_rng(seed)
    first = rng.integers(0, 3 * count + 2, (height, width)).astype(np.int32)
    labels = rng.integers(0, count, (height, width)).astype(np.int32)
    weight_h = rng.choice([0.0, 0.3, 1.0, 1.7], (height, max(width - 1, 0)))
    weight_v = rng.choice([0.0, 0.3, 1.0, 1.7], (max(height - 1, 0), width))
    slope, truncation = float(rng.choice([0.1, 0.25, 1.0])), float(rng.choice([0.2, 0.4, 3.0]))
    out = np.full((height, width, count), np.nan, dtype=np.float32)
    placeholder = np.zeros((1, 1, 1), dtype=np.int32)  # a window grid's unused candidates
    return placeholder, first, True, weight_h, weight_v, slope, truncation, labels, vertical, out


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    height=st.integers(1, 9),
    width=st.integers(1, 9),
    count=st.sampled_from([1, 2, 3, 4, 5, 6, 7, 9]),  # the preset's 4 and 6 take their own loops
    vertical=st.booleans(),
)
def test_the_c_neighbour_costs_are_numbas(neighbours, seed, height, width, count, vertical):
    ours = _neighbour_arguments(seed, height, width, count, vertical)
    numbas = _neighbour_arguments(seed, height, width, count, vertical)
    assert neighbours(*ours) is None
    shared.grid_kernels._neighbour_costs(*numbas)
    assert np.array_equal(ours[-1], numbas[-1])  # every element written, the same floats


def test_neighbour_costs_of_other_candidates_or_shapes_are_left_to_numba(neighbours):
    arguments = list(_neighbour_arguments(4, 3, 5, 6, True))
    arguments[2] = False  # candidates that are not windows
    assert neighbours(*arguments) is NotImplemented
    arguments = list(_neighbour_arguments(4, 3, 5, 6, True))
    arguments[4] = arguments[4][:, :-1].copy()  # one vertical weight short
    assert neighbours(*arguments) is NotImplemented
    assert np.isnan(arguments[-1]).all()  # nothing written


def test_the_grid_takes_the_c_neighbour_costs(monkeypatch, neighbours):
    """``GridMRF.neighbour_unary`` goes through the kernel that calls the C library first."""
    taken = []

    def c_kernel(*arguments):
        taken.append("native")
        return neighbours(*arguments)

    monkeypatch.setattr(kernels.neighbour_costs, "native", c_kernel)
    monkeypatch.setattr(kernels.neighbour_costs, "compiled", None)
    *_, out = _neighbour_arguments(5, 4, 6, 4, True)
    arguments = _neighbour_arguments(5, 4, 6, 4, True)
    kernels.neighbour_costs(*arguments)
    assert taken == ["native"]
    shared.grid_kernels._neighbour_costs(*arguments[:-1], out)
    assert np.array_equal(arguments[-1], out)
