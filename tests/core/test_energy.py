"""Cost arrays: the data term, the three regularisers and the energy of a labelling."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from shared.config import LevelConfig, Regularizer
from shared.energy import level_costs, mrf_energy

LEVEL = LevelConfig(
    downsample=1, candidates=3, edge_threshold=0.15, slope=0.5, truncation=0.75, edge_factor=0.1
)


def _images():
    left = np.array([[0.1, 0.2, 0.9, 0.4], [0.3, 0.3, 0.3, 0.8]], dtype=np.float32)
    right = np.array([[0.5, 0.1, 0.2, 0.7], [0.2, 0.6, 0.3, 0.1]], dtype=np.float32)
    candidates = np.broadcast_to(np.array([0, 1, 2], dtype=np.int32), (2, 4, 3)).copy()
    return left, right, candidates


def test_data_term_compares_left_x_with_right_x_minus_d():
    left, right, candidates = _images()
    costs = level_costs(left, right, candidates, LEVEL, Regularizer.TRUNCATED)
    assert costs.unary[0, 3, 1] == pytest.approx((0.4 - 0.2) ** 2)  # x=3, d=1 -> right x=2
    assert costs.unary[1, 2, 2] == pytest.approx((0.3 - 0.2) ** 2)  # x=2, d=2 -> right x=0
    assert costs.unary[0, 0, 2] == pytest.approx((0.1 - 0.5) ** 2)  # x - d < 0: border pixel


def test_truncated_regulariser_is_edge_aware():
    left, right, candidates = _images()
    costs = level_costs(left, right, candidates, LEVEL, Regularizer.TRUNCATED)
    # (0,0)-(0,1): |0.1 - 0.2| = 0.1 <= thr: min(0.75, 0.5 |dp - dq|)
    assert costs.pair_h[0, 0, 0, 1] == pytest.approx(0.5)
    assert costs.pair_h[0, 0, 0, 2] == pytest.approx(0.75)
    # (0,1)-(0,2): |0.2 - 0.9| > thr: times m = 0.1
    assert costs.pair_h[0, 1, 0, 2] == pytest.approx(0.075)
    # vertical (0,3)-(1,3): |0.4 - 0.8| > thr
    assert costs.pair_v[0, 3, 2, 0] == pytest.approx(0.075)
    assert np.all(costs.pair_h[..., [0, 1, 2], [0, 1, 2]] == 0)


def test_linear_regulariser_ignores_edges_and_truncation():
    left, right, candidates = _images()
    costs = level_costs(left, right, candidates, LEVEL, Regularizer.LINEAR)
    assert costs.pair_h[0, 1, 0, 2] == pytest.approx(1.0)


def test_no_regulariser_leaves_only_the_data_term():
    left, right, candidates = _images()
    costs = level_costs(left, right, candidates, LEVEL, Regularizer.NONE)
    assert not costs.pair_h.any() and not costs.pair_v.any()


def test_energy_of_a_labelling_sums_every_term_once():
    left, right, candidates = _images()
    costs = level_costs(left, right, candidates, LEVEL, Regularizer.TRUNCATED)
    labels = np.array([[0, 1, 2, 2], [1, 1, 0, 2]])
    expected = sum(costs.unary[y, x, labels[y, x]] for y in range(2) for x in range(4))
    expected += sum(
        costs.pair_h[y, x, labels[y, x], labels[y, x + 1]] for y in range(2) for x in range(3)
    )
    expected += sum(costs.pair_v[0, x, labels[0, x], labels[1, x]] for x in range(4))
    assert mrf_energy(costs, labels) == pytest.approx(expected)


def test_costs_of_a_row_block_equal_the_block_of_the_level_costs():
    left, right, candidates = _images()
    full = level_costs(left, right, candidates, LEVEL, Regularizer.TRUNCATED)
    block = level_costs(left[1:], right[1:], candidates[1:], LEVEL, Regularizer.TRUNCATED)
    np.testing.assert_array_equal(block.unary, full.rows(1, 2).unary)
    np.testing.assert_array_equal(block.pair_h, full.rows(1, 2).pair_h)
    assert block.pair_v.shape[0] == 0


def test_row_energies_are_the_single_row_bundle_energies(random_costs):
    from shared.energy import row_energies

    costs = random_costs(np.random.default_rng(0), 4, 7, 3)
    labels = np.random.default_rng(1).integers(0, 3, (4, 7))
    expected = [mrf_energy(costs.rows(r, r + 1), labels[r : r + 1]) for r in range(4)]
    np.testing.assert_allclose(row_energies(costs, labels), expected, rtol=1e-12)


@given(
    shape=st.tuples(st.integers(1, 6), st.integers(1, 6), st.integers(1, 3)),
    axis=st.sampled_from([0, 1]),
    data=st.data(),
)
def test_a_block_of_costs_keeps_its_pixels_and_the_edges_inside_it(shape, axis, data):
    """Rows/columns [start, stop): the MRF energy of the block equals the whole MRF's energy
    restricted to the block's pixels and the edges with both ends in it."""
    from shared.energy import Costs

    height, width, labels = shape
    rng = np.random.default_rng(data.draw(st.integers(0, 2**16)))
    costs = Costs(
        candidates=np.zeros(shape, dtype=np.int32),
        unary=rng.random(shape),
        pair_h=rng.random((height, width - 1, labels, labels)),
        pair_v=rng.random((height - 1, width, labels, labels)),
    )
    size = shape[axis]
    start = data.draw(st.integers(0, size - 1))
    stop = data.draw(st.integers(start + 1, size))
    block = costs.rows(start, stop) if axis == 0 else costs.columns(start, stop)
    labels_map = rng.integers(0, labels, (height, width))
    inside = labels_map[start:stop] if axis == 0 else labels_map[:, start:stop]
    # the same block as a stand-alone MRF: cut the whole map down to it
    mask = np.zeros((height, width), dtype=bool)
    if axis == 0:
        mask[start:stop] = True
    else:
        mask[:, start:stop] = True
    rows, cols = np.nonzero(mask)
    expected = costs.unary[rows, cols, labels_map[rows, cols]].sum()
    h_keep = mask[:, :-1] & mask[:, 1:]
    r, c = np.nonzero(h_keep)
    expected += costs.pair_h[r, c, labels_map[r, c], labels_map[r, c + 1]].sum()
    v_keep = mask[:-1] & mask[1:]
    r, c = np.nonzero(v_keep)
    expected += costs.pair_v[r, c, labels_map[r, c], labels_map[r + 1, c]].sum()
    assert mrf_energy(block, inside) == pytest.approx(expected)
