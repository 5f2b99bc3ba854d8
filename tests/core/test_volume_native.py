"""The least-cost kernel in C (``shared/volume_native.c``, issue 28): numba's ``least_costs``
values and disparities bit for bit, on every target it is built for, and the calls it cannot
take left to numba."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import shared.volume_kernels
from shared import kernels, native
from shared.kernel_build import compiler_command
from shared.volume_native import NativeLeastCosts

COMPILER = compiler_command() or ["cc"]
pytestmark = pytest.mark.skipif(
    shutil.which(COMPILER[0]) is None, reason=f"no C compiler ({COMPILER[0]}) to build it with"
)


@pytest.fixture(scope="module", params=["native", "generic"])
def least(request, tmp_path_factory) -> NativeLeastCosts:
    """Built for this CPU's x86-64 level (8 pixels a vector with AVX), and for the generic
    target (4)."""
    cpu = kernels.target_cpu() if request.param == "native" else ""
    path = tmp_path_factory.mktemp("native") / "volume.so"
    library = native.load(native.compile_library(COMPILER, path, cpu, "volume"), "volume")
    assert library is not None
    return NativeLeastCosts(library)


def _kept(slots: int, rows: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    return np.full((slots, rows, width), np.inf, np.float32), np.zeros(
        (slots, rows, width), np.int32
    )


@settings(max_examples=80, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    count=st.integers(1, 30),
    rows=st.integers(1, 4),
    width=st.integers(1, 37),  # whole vectors of 4 or 8 pixels and a row's tail
    slots=st.integers(1, 6),
    ties=st.booleans(),
)
def test_the_c_least_costs_are_numbas(least, seed, count, rows, width, slots, ties):
    rng = np.random.default_rng(seed)
    volume = rng.random((count, rows, width), dtype=np.float32)
    if ties:  # a few values: equal costs, where the earlier disparity stays first
        volume = np.round(volume * 3).astype(np.float32)
    ours, numbas = _kept(slots, rows, width), _kept(slots, rows, width)
    assert least(volume, *ours) is None
    shared.volume_kernels.least_costs(volume, *numbas)
    np.testing.assert_array_equal(ours[0], numbas[0])
    np.testing.assert_array_equal(ours[1], numbas[1])


def test_calls_it_cannot_take_are_left_to_numba(least):
    volume = np.ones((5, 2, 9), np.float32)
    assert least(volume, *_kept(17, 2, 9)) is NotImplemented  # more than 16 costs kept
    values, indices = _kept(4, 2, 9)
    assert least(volume, values, indices[:, :1].copy()) is NotImplemented
    assert least(volume, *_kept(4, 2, 8)) is NotImplemented


def test_the_kernel_takes_the_c_kernel_when_it_is_built(monkeypatch):
    kernel = kernels.least_costs
    if kernel.native is None:
        pytest.skip("the C kernels are not built here (qhsm build-kernels)")
    taken, built = [], kernel.native
    monkeypatch.setattr(kernel, "native", lambda *arguments: taken.append(1) or built(*arguments))
    volume = np.random.default_rng(1).random((20, 6, 30), dtype=np.float32)
    ours, numbas = _kept(4, 6, 30), _kept(4, 6, 30)
    kernel(volume, *ours)
    shared.volume_kernels.least_costs(volume, *numbas)
    assert taken == [1]
    np.testing.assert_array_equal(ours[1], numbas[1])
