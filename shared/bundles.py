"""Bundles: blocks of consecutive epipolar lines (rows), one QUBO each.

Inside a bundle every pixel links to its 4-neighbours in the bundle; edges between bundles are
dropped, so bundles are independent problems that can be solved anywhere in any order.
"""

from __future__ import annotations

import numpy as np


def bundle_rows(height: int, bundle_height: int) -> list[tuple[int, int]]:
    """Row ranges [start, stop) that tile ``height`` rows; the last bundle may be shorter."""
    if bundle_height < 1:
        raise ValueError("bundle_height must be at least 1")
    starts = range(0, height, bundle_height)
    return [(start, min(start + bundle_height, height)) for start in starts]


def bundle_seed(seed: int, level: int, row_start: int) -> int:
    """A solver seed per bundle that depends only on (seed, level, first row).

    In-process runs and distributed runs therefore give identical results for the same seed,
    whatever the grouping of bundles into tasks or their order.

    Seeds are below 2**31: dwave-samplers rejects larger ones despite its message.
    """
    return int(np.random.SeedSequence([seed, level, row_start]).generate_state(1)[0] >> 1)
