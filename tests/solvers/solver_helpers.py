"""Small stereo bundles and random QUBOs for the solver tests."""

from __future__ import annotations

import itertools

import dimod
import numpy as np

from shared import pyramid
from shared.config import LevelConfig, Regularizer
from shared.energy import Costs, level_costs, mrf_energy
from shared.solvers.exact import solve_chains
from shared.synthetic import make_scene


def stereo_costs(height: int = 1, width: int = 6, labels: int = 4, seed: int = 1) -> Costs:
    """Costs of a small block of a synthetic scene (the paper's full-resolution level)."""
    scene = make_scene(max(16, height + 8), max(24, width + 12), max_disparity=6, seed=seed)
    level = LevelConfig(candidates=labels)
    candidates = pyramid.initial_candidates(scene.left.shape, labels, 6)
    rows, cols = slice(4, 4 + height), slice(8, 8 + width)
    assert candidates[rows, cols].shape[:2] == (height, width)
    return level_costs(
        scene.left[rows, cols],
        scene.right[rows, cols],
        candidates[rows, cols],
        level,
        Regularizer.TRUNCATED,
    )


def optimum(costs: Costs) -> float:
    """Minimum MRF energy, which is also the QUBO minimum of either codec (the rectifier
    proofs): row DP for one row, enumeration of all labellings for taller tiny bundles."""
    height, width, labels = costs.unary.shape
    if height == 1:
        return mrf_energy(costs, solve_chains(costs))
    grids = itertools.product(range(labels), repeat=height * width)
    return min(mrf_energy(costs, np.reshape(grid, (height, width))) for grid in grids)


def random_bqm(num_variables: int, seed: int) -> dimod.BinaryQuadraticModel:
    """A dense random QUBO on variables 0..n-1 with mixed-sign biases."""
    rng = np.random.default_rng(seed)
    rows, cols = np.triu_indices(num_variables, k=1)
    keep = rng.random(rows.size) < 0.6
    return dimod.BinaryQuadraticModel.from_numpy_vectors(
        rng.normal(size=num_variables),
        (rows[keep], cols[keep], rng.normal(size=int(keep.sum()))),
        0.0,
        dimod.BINARY,
    )


def with_record(solver, name: str):
    """``solver``, built by hand, given the registry's record of ``name`` (its defaults and
    description), as :func:`shared.solvers.registry.build` gives it to the samplers it builds."""
    from shared.solvers import registry

    solver.spec = registry.spec(name)
    return solver
