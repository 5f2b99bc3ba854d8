"""Fixtures shared by every test package: synthetic scenes and the optional Middlebury data."""

from __future__ import annotations

import numpy as np
import pytest

from shared.datasets import default_middlebury_dir, load_scene
from shared.energy import Costs
from shared.synthetic import SyntheticScene, make_scene


@pytest.fixture(scope="session")
def scene() -> SyntheticScene:
    """A 96x128 scene with a slanted background and two layers (disparities up to 16)."""
    return make_scene(96, 128, max_disparity=16, seed=0)


@pytest.fixture(scope="session")
def middlebury_dir():
    folder = default_middlebury_dir()
    if not folder.is_dir():
        pytest.skip(f"Middlebury data not found at {folder} (set QHSM_MIDDLEBURY_DIR to use it)")
    return folder


@pytest.fixture(scope="session")
def tsukuba(middlebury_dir):
    return load_scene(middlebury_dir / "tsukuba")


def _random_costs(rng: np.random.Generator, height: int, width: int, labels: int) -> Costs:
    return Costs(
        candidates=np.broadcast_to(np.arange(labels, dtype=np.int32), (height, width, labels)),
        unary=rng.random((height, width, labels)),
        pair_h=rng.random((height, max(width - 1, 0), labels, labels)),
        pair_v=rng.random((max(height - 1, 0), width, labels, labels)),
    )


@pytest.fixture(scope="session")
def random_costs():
    """Factory: non-negative random MRF costs (the regime the rectifier proofs cover)."""
    return _random_costs
