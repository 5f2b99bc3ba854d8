"""The window kernels' fast paths (issue 28, kernel speed): two chains at a time, the message's
three ranges of label shifts, the read-back's difference table, against the O(K^2) kernels
on grids whose neighbouring windows lie far apart (beyond a window's own width)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared import trws_kernels
from shared.config import LevelConfig, Regularizer
from shared.grid import GridMRF, grid_mrf, solve_chains
from shared.grid_inference import trws

LEVEL = LevelConfig(slope=0.2, truncation=0.4, edge_threshold=0.3, edge_factor=0.3)


def far_windows(
    seed: int,
    height: int,
    width: int,
    labels: int,
    spread: int,
    regularizer: Regularizer = Regularizer.TRUNCATED,
) -> GridMRF:
    """Consecutive windows whose first labels spread over 0..spread: neighbours' windows can
    overlap, touch or lie apart."""
    rng = np.random.default_rng(seed)
    unary = rng.random((height, width, labels)).astype(np.float32)
    first = rng.integers(0, spread + 1, (height, width))
    candidates = first[:, :, None] + np.arange(labels)
    return grid_mrf(unary, candidates, rng.random((height, width)), LEVEL, regularizer)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    height=st.integers(1, 5),  # odd counts of chains: the last one solved alone
    width=st.integers(1, 7),
    labels=st.integers(1, 4),
    along_columns=st.booleans(),
)
def test_window_chains_are_the_general_chains_optima_whatever_the_shift(
    seed, height, width, labels, along_columns
):
    mrf = far_windows(seed, height, width, labels, spread=3 * labels + 2)
    assert mrf.first is not None
    general = replace(mrf, first=None)
    found, energies = solve_chains(mrf, along_columns)
    expected_labels, expected = solve_chains(general, along_columns)
    np.testing.assert_allclose(energies, expected, rtol=1e-12, atol=1e-12)
    assert mrf.energy(found) == pytest.approx(general.energy(expected_labels), rel=1e-12)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    height=st.integers(1, 5),
    width=st.integers(1, 7),
    labels=st.integers(1, 4),
    spread=st.sampled_from([0, 6, 90]),  # 90: differences beyond the general path's table
    regularizer=st.sampled_from([Regularizer.TRUNCATED, Regularizer.LINEAR]),
    vertical=st.booleans(),
)
def test_window_energy_and_neighbour_costs_are_the_general_paths_floats(
    seed, height, width, labels, spread, regularizer, vertical
):
    """The DD's energies and the chain primal's neighbour costs pick its labels: the window
    paths (labels from ``first``, one difference table) must give the very same floats."""
    mrf = far_windows(seed, height, width, labels, spread, regularizer)
    assert mrf.first is not None
    general = replace(mrf, first=None)
    labelling = np.random.default_rng(seed + 1).integers(0, labels, (height, width))
    assert mrf.energy(labelling) == general.energy(labelling)
    costs = mrf.neighbour_unary(labelling, vertical)
    assert costs.tobytes() == general.neighbour_unary(labelling, vertical).tobytes()


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), labels=st.integers(2, 4))
def test_trws_window_messages_are_the_general_messages_whatever_the_shift(seed, labels):
    mrf = far_windows(seed, 4, 5, labels, spread=3 * labels + 2)
    general = replace(mrf, first=None)
    windowed, brute = trws(mrf, iterations=3), trws(general, iterations=3)
    assert windowed.lower_bound == pytest.approx(brute.lower_bound, rel=1e-9)
    assert windowed.energy == pytest.approx(brute.energy, rel=1e-9)


def test_a_trws_label_scores_its_unary_and_messages_from_ahead_in_float32():
    """What numba's just-in-time typing made of the kernel (the maps' digests pin it), spelt out
    so that an ahead-of-time build computes it too (the one that typed the score float64 from
    the start chose other labels at near-ties): candidate 0's 1 + 2^-24 and candidate 1's
    1 + 2^-26 both round to 1 in float32, a tie the first candidate wins."""
    tiny = np.float32(2.0**-25)
    one_pixel = (1, 1, 2)
    unary = np.ones(one_pixel, dtype=np.float32)
    from_right = np.array([[[tiny, tiny / 2]]], dtype=np.float32)  # forward: from ahead
    from_down = np.array([[[tiny, 0.0]]], dtype=np.float32)
    labels = np.full((1, 1), -1, dtype=np.int32)
    trws_kernels._trws_pass(
        unary,
        np.array([[[0, 1]]], dtype=np.int32),
        np.zeros((1, 1), dtype=np.int32),
        True,
        np.zeros((1, 0)),
        np.zeros((0, 1)),
        0.2,
        0.4,
        np.zeros(one_pixel, dtype=np.float32),
        from_right,
        np.zeros(one_pixel, dtype=np.float32),
        from_down,
        True,
        labels,
    )
    assert labels[0, 0] == 0


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    height=st.integers(1, 5),
    width=st.integers(1, 7),
    windows=st.booleans(),
    along_columns=st.booleans(),
)
def test_labels_written_transposed_are_the_same_labels_and_energies(
    seed, height, width, windows, along_columns
):
    """``transpose``: the kernels write (chain, x) at ``labels[x, chain]``, the same optima
    bit for bit (dual decomposition's column chains give the grid's layout without a copy)."""
    mrf = far_windows(seed, height, width, labels=3, spread=4)
    if not windows:
        mrf = replace(mrf, first=None)
    extra = np.random.default_rng(seed).standard_normal(mrf.unary.shape).astype(np.float32)
    labels, energies = solve_chains(mrf, along_columns, extra, -1.0, scale=0.5)
    turned, turned_energies = solve_chains(
        mrf, along_columns, extra, -1.0, scale=0.5, transpose=True
    )
    assert turned.shape == (width, height) and turned.flags.c_contiguous
    np.testing.assert_array_equal(turned.T, labels)
    np.testing.assert_array_equal(turned_energies, energies)
