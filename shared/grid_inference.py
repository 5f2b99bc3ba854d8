"""The minimisers of a view's grid MRF that ``exact`` chooses between (``grid_inference``):
the subgradient dual decomposition (:func:`shared.grid.dual_decomposition`) or TRW-S.

TRW-S (Kolmogorov, "Convergent tree-reweighted message passing for energy minimization", 2006;
:func:`trws`) works on the same decomposition into row and column chains: instead of subgradient
steps on the split it passes the chains' min-sum messages in raster order and back (each pixel
in two chains, rho = 1/2), which raises the same kind of bound monotonically and reaches a small
gap in a few passes; its labels are then polished by the chain primal step.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from shared.config import GridInference, MatchConfig
from shared.grid import DualResult, GridMRF, chain_primal, dual_decomposition
from shared.kernels import trws_pass

#: A minimiser of one view's grid: (mrf, iterations, gap) -> its result.
Minimiser = Callable[[GridMRF, int, float], DualResult]


def trws(mrf: GridMRF, iterations: int, gap: float = 0.0) -> DualResult:
    """Minimise the grid MRF by TRW-S over its row and column chains (module doc), then polish
    the best labelling by the chain primal step (rows given columns, columns given rows).

    Parameters
    ----------
    mrf : GridMRF
        One view's grid.
    iterations : int
        Most iterations (each a forward and a backward pass, about two dual-decomposition
        iterations of chain messages).
    gap : float, optional
        Stop once (E - LB) / |E| is at most this.

    Returns
    -------
    DualResult
        The lowest-energy labelling seen, its energy, the best lower bound and the gap;
        ``disagreeing`` is 0 when the labelling is proven optimal, else the pixels whose labels
        the last two passes chose differently.
    """
    height, width, _ = mrf.unary.shape
    # the message each pixel receives from its left, right, upper and lower neighbour
    left, right, up, down = (np.zeros(mrf.unary.shape, dtype=np.float32) for _ in range(4))
    passes = [np.zeros((height, width), dtype=np.int32) for _ in range(2)]
    best_labels, best_energy = passes[0], math.inf
    bound, done = -math.inf, 0
    for iteration in range(1, iterations + 1):
        done = iteration
        for forward, labels in ((True, passes[0]), (False, passes[1])):
            pass_bound = trws_pass(mrf.unary, *mrf.edges(), left, right, up, down, forward, labels)
            bound = max(bound, float(pass_bound))
            energy = mrf.energy(labels)
            if energy < best_energy:
                best_labels, best_energy = labels.copy(), energy
        if best_energy - bound <= gap * abs(best_energy):
            break
    disagreeing = int(np.count_nonzero(passes[0] != passes[1]))
    del left, right, up, down, passes
    polished = chain_primal(mrf, mrf.transposed(candidates=False), best_labels)
    energy = mrf.energy(polished)
    if energy < best_energy:
        best_labels, best_energy = polished, energy
    bound = min(bound, best_energy)
    return DualResult(
        labels=best_labels,
        energy=float(best_energy),
        lower_bound=float(bound),
        iterations=done,
        disagreeing=0 if best_energy <= bound else max(disagreeing, 1),
    )


def minimiser(config: MatchConfig) -> Minimiser:
    """``exact``'s minimiser of a whole view's grid, ``grid_inference``: :func:`trws` or
    :func:`dual_decomposition` (the residual design's host labels are the same)."""
    return trws if config.grid_inference is GridInference.TRWS else dual_decomposition
