"""The compiled census + gradient volume (shared/volume_kernels.py) is OpenCV's bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared import data_terms
from shared.data_terms import VolumeBlock, census_gradient_volume
from shared.synthetic import make_scene
from shared.volume_kernels import _bits


def both(left, right, block, out=None):
    """The volume by OpenCV and NumPy, then by the compiled kernels."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(data_terms, "FUSED_VOLUME_BYTES", 2**62)
        reference = census_gradient_volume(left, right, block)
        patch.setattr(data_terms, "FUSED_VOLUME_BYTES", 0)
        return reference, census_gradient_volume(left, right, block, out)


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**16),
    height=st.integers(6, 40),
    width=st.integers(8, 60),
    max_disparity=st.integers(0, 20),
    colour=st.booleans(),
    levels=st.sampled_from([2, 5, 256]),
    data=st.data(),
)
def test_the_compiled_volume_is_opencvs_bit_for_bit(
    seed, height, width, max_disparity, colour, levels, data
):
    """Random views (few grey levels too: many equal costs, zero gradients), any block of
    rows, colour or grey."""
    rng = np.random.default_rng(seed)
    shape = (height, width, 3) if colour else (height, width)
    left = (rng.integers(0, levels, shape) / (levels - 1)).astype(np.float32)
    right = (rng.integers(0, levels, shape) / (levels - 1)).astype(np.float32)
    start = data.draw(st.integers(0, height - 1))
    stop = data.draw(st.integers(start + 1, height))
    reference, fused = both(left, right, VolumeBlock(max_disparity, start, stop))
    assert fused.dtype == np.float32
    np.testing.assert_array_equal(fused, reference)


def test_the_compiled_volume_of_a_scene_fills_a_strided_buffer():
    """A scene, written into a block of a larger scratch buffer (as the blocks of a view are)."""
    scene = make_scene(160, 90, max_disparity=24, seed=5)
    block = VolumeBlock(24, 30, 70)
    scratch = np.full((25, 50, scene.left.shape[1]), np.nan, np.float32)
    reference, fused = both(scene.left, scene.right, block, scratch[:, : block.rows])
    assert np.shares_memory(fused, scratch)
    np.testing.assert_array_equal(fused, reference)


@pytest.mark.parametrize("code", [0, 1, 0b1011, 0xFFFFFF, 0xFFFFFFFF, 0x80000001])
def test_bits_counts_the_set_bits(code):
    assert _bits(np.uint32(code)) == bin(code).count("1")
