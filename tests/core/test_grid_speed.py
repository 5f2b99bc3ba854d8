"""The speed rewrites of issue 18 compute exactly what the plain formulations compute."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.data_terms import bin_minimum


@settings(max_examples=100, deadline=None)
@given(
    disparities=st.integers(1, 40),
    bin_width=st.integers(1, 17),
    seed=st.integers(0, 2**16),
)
def test_bin_minimum_is_reduceat(disparities: int, bin_width: int, seed: int) -> None:
    """Strided minima equal ``np.minimum.reduceat`` bit for bit, a narrower last bin included."""
    volume = np.random.default_rng(seed).random((disparities, 3, 4)).astype(np.float32)
    expected = np.minimum.reduceat(volume, np.arange(0, disparities, bin_width), axis=0)
    binned = bin_minimum(volume, bin_width)
    assert binned.dtype == volume.dtype
    assert binned.tobytes() == expected.tobytes()
