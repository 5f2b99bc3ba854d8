"""QUBO codecs: energies agree with the MRF, minimisers are valid, decode inverts encode."""

from __future__ import annotations

import itertools

import dimod
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.config import Encoding, Rectifier
from shared.encodings import domain_wall, get_codec, onehot
from shared.energy import Costs, mrf_energy
from shared.solvers.base import sample_array

CODECS = [Encoding.ONE_HOT, Encoding.DOMAIN_WALL]
shapes = st.tuples(st.integers(1, 3), st.integers(1, 4), st.integers(2, 5))


def _costs(seed: int, height: int, width: int, labels: int, scale: float = 1.0) -> Costs:
    rng = np.random.default_rng(seed)
    return Costs(
        candidates=np.broadcast_to(np.arange(labels, dtype=np.int32), (height, width, labels)),
        unary=rng.random((height, width, labels)),
        pair_h=scale * rng.random((height, width - 1, labels, labels)),
        pair_v=scale * rng.random((height - 1, width, labels, labels)),
    )


@pytest.mark.parametrize("encoding", CODECS)
@given(shape=shapes, seed=st.integers(0, 2**31), rectifier=st.sampled_from(list(Rectifier)))
@settings(max_examples=40, deadline=None)
def test_bqm_energy_equals_mrf_energy_on_valid_states(encoding, shape, seed, rectifier):
    costs = _costs(seed, *shape)
    codec = get_codec(encoding)
    bqm = codec.encode(costs, rectifier)
    labels = np.random.default_rng(seed + 1).integers(0, shape[2], shape[:2])
    bits = codec.encode_labels(labels, shape[2])
    assert bqm.num_variables == shape[0] * shape[1] * codec.variables_per_pixel(shape[2])
    assert bqm.energy(bits) == pytest.approx(mrf_energy(costs, labels), rel=1e-9, abs=1e-9)


@pytest.mark.parametrize("encoding", CODECS)
@given(shape=shapes, seed=st.integers(0, 2**31))
@settings(max_examples=40, deadline=None)
def test_decode_inverts_encode(encoding, shape, seed):
    costs = _costs(seed, *shape)
    codec = get_codec(encoding)
    labels = np.random.default_rng(seed).integers(0, shape[2], shape[:2]).astype(np.int32)
    decoded = codec.decode(costs, codec.encode_labels(labels, shape[2]))
    assert decoded.repaired == 0
    np.testing.assert_array_equal(decoded.labels, labels)


def _all_ground_states(bqm: dimod.BinaryQuadraticModel) -> list[np.ndarray]:
    sampleset = dimod.ExactSolver().sample(bqm)
    lowest = sampleset.lowest(atol=1e-12)
    return [sample_array(s, bqm.num_variables) for s in lowest.samples()]


def _brute_force_map(costs: Costs) -> float:
    height, width, labels = costs.unary.shape
    return min(
        mrf_energy(costs, np.array(assignment).reshape(height, width))
        for assignment in itertools.product(range(labels), repeat=height * width)
    )


# Small enough for dimod.ExactSolver (<= 18 binaries): (h, w, K) per codec.
BRUTE_SHAPES = {
    Encoding.ONE_HOT: [(1, 3, 3), (1, 4, 4), (2, 2, 3), (1, 2, 5), (3, 2, 2)],
    Encoding.DOMAIN_WALL: [(1, 4, 4), (2, 2, 4), (1, 3, 6), (2, 3, 3), (1, 6, 3)],
}


@pytest.mark.parametrize("encoding", CODECS)
@pytest.mark.parametrize("rectifier", list(Rectifier))
@pytest.mark.parametrize("seed", range(4))
def test_every_minimiser_is_valid_and_is_the_map(encoding, rectifier, seed):
    codec = get_codec(encoding)
    for shape in BRUTE_SHAPES[encoding]:
        # Pairwise costs large relative to unaries make invalid states most tempting.
        costs = _costs(seed, *shape, scale=3.0)
        bqm = codec.encode(costs, rectifier)
        for state in _all_ground_states(bqm):
            decoded = codec.decode(costs, state)
            assert decoded.repaired == 0, f"{encoding} ground state invalid for {shape}"
            assert mrf_energy(costs, decoded.labels) == pytest.approx(_brute_force_map(costs))


def test_one_hot_rectifier_matches_the_formula():
    costs = _costs(3, 2, 3, 3)
    chi = onehot.rectifier_weights(costs)
    # pixel (0, 1): neighbours left (0,0), right (0,2), below (1,1)
    worst = (
        costs.unary[0, 1]
        + costs.pair_h[0, 0].max(axis=0)
        + costs.pair_h[0, 1].max(axis=1)
        + costs.pair_v[0, 1].max(axis=1)
    )
    assert chi[0, 1] > worst.min()
    assert chi[0, 1] == pytest.approx(worst.min(), rel=1e-2)


def test_global_rectifier_is_the_largest_local_one():
    costs = _costs(5, 2, 4, 4)
    for codec in (onehot, domain_wall):
        local = codec.rectifier_weights(costs, Rectifier.LOCAL)
        global_ = codec.rectifier_weights(costs, Rectifier.GLOBAL)
        assert np.all(global_ == local.max())


@pytest.mark.parametrize("encoding", CODECS)
def test_invalid_pixels_are_repaired_to_their_best_label(encoding):
    costs = _costs(7, 1, 3, 4)
    codec = get_codec(encoding)
    labels = np.array([[1, 2, 3]])
    bits = codec.encode_labels(labels, 4).copy()
    per_pixel = codec.variables_per_pixel(4)
    # break the middle pixel: all ones for one-hot; wall 0,1,... for domain-wall
    bits[per_pixel : 2 * per_pixel] = 1 if encoding is Encoding.ONE_HOT else [0, 1, 0]
    decoded = codec.decode(costs, bits)
    assert decoded.repaired == 1
    local = costs.unary[0, 1] + costs.pair_h[0, 0][1, :] + costs.pair_h[0, 1][:, 3]
    assert decoded.labels[0, 1] == int(local.argmin())
    assert decoded.labels[0, 0] == 1 and decoded.labels[0, 2] == 3


def test_domain_wall_uses_one_binary_less_per_pixel():
    costs = _costs(1, 2, 5, 4)
    assert domain_wall.encode(costs).num_variables == 2 * 5 * 3
    assert onehot.encode(costs).num_variables == 2 * 5 * 4
