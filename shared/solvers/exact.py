"""``exact``: the global MAP of single-row bundles by min-sum dynamic programming (Viterbi).

It reads the MRF costs directly, not the QUBO: a row is a chain, so the optimum over K^w
labellings costs O(w K^2), and all rows of a block are solved at once (vectorised over rows and
labels; the only Python loop runs over columns). For a generic BQM it falls back to dimod's
brute-force ``ExactSolver``, which is only feasible for tiny problems.
"""

from __future__ import annotations

from typing import Any

import dimod
import numpy as np

from shared.energy import Costs
from shared.solvers.base import SolverError
from shared.solvers.sampler import Sampler

#: dimod.ExactSolver enumerates 2^n states; beyond this it is hopeless.
BRUTE_FORCE_LIMIT = 24


def solve_chains(costs: Costs) -> np.ndarray:
    """Optimal labels (h, w) of every row of ``costs``, each row an independent chain.

    Vertical edges are ignored, so this is the exact MAP only for single-row bundles; callers
    must not use it for taller bundles (see :meth:`ExactSolver.check_bundle_height`).

    Parameters
    ----------
    costs : Costs
        ``unary`` (h, w, K) and ``pair_h`` (h, w - 1, K, K); ``pair_v`` is not read.

    Returns
    -------
    numpy.ndarray
        int32 label indices of shape (h, w), the minimum-cost labelling of each row.
    """
    unary, pair = costs.unary, costs.pair_h
    height, width, labels = unary.shape
    # column-major copies: each step reads one contiguous column of every row
    pair_columns = np.ascontiguousarray(np.moveaxis(pair, 1, 0))  # (w - 1, h, K, K)
    unary_columns = np.ascontiguousarray(np.moveaxis(unary, 1, 0))  # (w, h, K)
    back = np.empty((max(width - 1, 0), height, labels), dtype=np.int16)
    message = unary_columns[0].copy()
    total = np.empty((height, labels, labels))
    for col in range(1, width):
        np.add(message[:, :, None], pair_columns[col - 1], out=total)  # (h, K_prev, K)
        back[col - 1] = total.argmin(axis=1)
        message = total.min(axis=1)
        message += unary_columns[col]
    result = np.empty((height, width), dtype=np.int32)
    result[:, -1] = message.argmin(axis=1)
    rows = np.arange(height)
    for col in range(width - 1, 0, -1):
        result[:, col - 1] = back[col - 1, rows, result[:, col]]
    return result


class ExactSolver(Sampler):
    """Row-chain DP for the pipeline (a row solver); as a ``dimod.Sampler``, dimod's brute
    force for small generic BQMs."""

    name = "exact"
    parameters: dict[str, list] = {}  # noqa: RUF012 (dimod's interface)
    properties: dict[str, Any] = {}  # noqa: RUF012

    @staticmethod
    def check_bundle_height(bundle_height: int) -> None:
        """Refuse bundles taller than one row, for which the row DP is not exact.

        Parameters
        ----------
        bundle_height : int
            The configured rows per bundle.

        Raises
        ------
        SolverError
            Unless ``bundle_height`` is 1.
        """
        if bundle_height != 1:
            raise SolverError(
                f"the exact solver is exact only for single-row bundles (bundle height 1), "
                f"got bundle height {bundle_height}: use --bundle-height 1, or a QUBO solver "
                "such as sa or gurobi for taller bundles"
            )

    def solve_rows(self, costs: Costs, bundle_height: int) -> np.ndarray:
        """Exact labels of every row of ``costs`` (single-row bundles only).

        Parameters
        ----------
        costs : Costs
            MRF costs of the rows (unary (h, w, K), horizontal pair costs).
        bundle_height : int
            Must be 1.

        Returns
        -------
        numpy.ndarray
            Optimal labels, (h, w) int32 (:func:`solve_chains`).

        Raises
        ------
        SolverError
            For a bundle height other than 1.
        """
        self.check_bundle_height(bundle_height)
        return solve_chains(costs)

    def run(self, bqm, params: dict[str, Any], *, seed, initial_states) -> dimod.SampleSet:
        """Brute-force minimum of a small generic BQM (dimod's ``ExactSolver``).

        Parameters
        ----------
        bqm : dimod.BinaryQuadraticModel
            At most :data:`BRUTE_FORCE_LIMIT` variables.
        params : dict
            Ignored (``exact`` takes none).
        seed : int or None
            Ignored: enumeration is deterministic.
        initial_states : samples-like or None
            Ignored.

        Returns
        -------
        dimod.SampleSet
            The lowest-energy state(s).

        Raises
        ------
        SolverError
            When the BQM is too large to enumerate.
        """
        if bqm.num_variables > BRUTE_FORCE_LIMIT:
            raise SolverError(
                f"exact solves a generic BQM by enumeration only up to {BRUTE_FORCE_LIMIT} "
                f"variables (this one has {bqm.num_variables}); stereo rows go through the "
                "row DP instead"
            )
        return dimod.ExactSolver().sample(bqm).lowest()
