"""The speed rewrites of issue 18 compute exactly what the plain formulations compute."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.data_terms import bin_minimum, gather, gather_window


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


@settings(max_examples=60, deadline=None)
@given(
    labels=st.integers(4, 12),
    count=st.integers(1, 4),
    rows=st.sampled_from([slice(None), slice(2, 5), slice(None, None, 2), slice(None, None, -1)]),
    seed=st.integers(0, 2**16),
)
def test_gathers_are_take_along_axis(labels: int, count: int, rows: slice, seed: int) -> None:
    """The flat-index gathers pick what ``take_along_axis`` over the label axis picks, from a
    block of rows of a view's volume (strided, reversed) too; a window from its first label."""
    rng = np.random.default_rng(seed)
    per_label = rng.random((labels, 6, 5)).astype(np.float32)[:, rows]
    first = rng.integers(0, labels - count + 1, per_label.shape[1:]).astype(np.int32)
    candidates = first[:, :, None] + np.arange(count, dtype=np.int32)
    expected = np.take_along_axis(np.moveaxis(per_label, 0, -1), candidates, axis=2)
    shuffled = rng.permuted(candidates, axis=2)  # any labels, not only windows
    assert gather_window(per_label, first, count, np.float32).tobytes() == expected.tobytes()
    assert gather(per_label, candidates).tobytes() == expected.astype(np.float64).tobytes()
    assert (
        gather(per_label, shuffled, np.float32).tobytes()
        == np.take_along_axis(np.moveaxis(per_label, 0, -1), shuffled, axis=2).tobytes()
    )
