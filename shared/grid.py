"""The 2D grid MRF of a level and its dual decomposition into row and column chains.

A level's energy over the 4-connected grid of one view is

    E(x) = sum_p U[p, x_p] + sum_(p,q) w_pq min(T, s |C[p, x_p] - C[q, x_q]|)

over horizontal and vertical neighbours (C: the label, a disparity bin, that candidate x_p
stands for; w_pq the edge weight, lower across gray steps). Minimising it is NP-hard with a
truncated regulariser: the reason for annealers. Its chains are not: a row (or a column) alone is
solved exactly by min-sum dynamic programming in O(w K^2).

Dual decomposition (Komodakis et al., "MRF optimization via dual decomposition", 2007) splits the
grid into the row chains (horizontal edges) and the column chains (vertical edges), each pixel's
unary shared between its row copy (U/2 + lambda) and its column copy (U/2 - lambda). For every
lambda the two sets of chain optima sum to a **lower bound** on min E; subgradient ascent on
lambda where row and column labels disagree raises the bound (Polyak step
gamma (E_best - LB) / |g|^2, gamma halved when the bound stalls), and where they all agree the
labelling is optimal. Every :data:`PRIMAL_EVERY` iterations a primal labelling is built by chain
solves too: rows given the column solution's vertical neighbours, then columns given that. The
lowest energy seen is the result, reported with the bound and the gap.

TRW-S over the same chains is the other minimiser ``exact`` may use (:mod:`shared.grid_inference`).

Each chain is one QUBO bundle like a row of the ``rows`` inference; ``exact`` solves all chains of
an iteration at once with the compiled kernels of :mod:`shared.grid_kernels` (:func:`solve_chains`;
dual decomposition runs the column chains as the rows of a transposed copy, contiguous in memory,
keeps its multipliers in both layouts, and has the kernels write each solve's labels in the layout
the next step reads, with no transpose copies).
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import partial

import numpy as np

from shared.config import LevelConfig, Regularizer
from shared.kernels import (
    chains_general,
    chains_windows,
    disagreements,
    grid_energy,
    neighbour_costs,
    subgradient_step,
)
from shared.threads import both, spare_core

#: :meth:`GridMRF.edges`: candidates, first, windowed, weight_h, weight_v, slope, truncation.
EdgeArguments = tuple[np.ndarray, np.ndarray, bool, np.ndarray, np.ndarray, float, float]

#: What the grid kernels read for a window grid's candidates and a general grid's ``first``
#: (:meth:`GridMRF.edges`): placeholders, never indexed.
_NO_CANDIDATES = np.zeros((1, 1, 1), dtype=np.int32)
_NO_FIRST = np.zeros((1, 1), dtype=np.int32)

#: The primal heuristic runs every this many dual iterations.
PRIMAL_EVERY = 5
#: Iterations without a higher bound after which the step factor gamma is halved.
STALL_ITERATIONS = 2


@dataclass(frozen=True)
class GridMRF:
    """A view's grid MRF in compact form: the pairwise cost of edge (p, q) for candidates
    (l, m) is ``weight * min(truncation, slope * |C[p, l] - C[q, m]|)``.

    Shapes: unary (h, w, K) float32, candidates (h, w, K) int32, weight_h (h, w - 1) and
    weight_v (h - 1, w) float64 (0 where there is no edge). ``first`` (h, w) int32 is each
    pixel's first candidate when its candidates are consecutive labels (the bin pyramid's
    windows: the chains then take the O(K) kernel), else ``None``; with ``first`` the
    candidates may be None (not kept: :meth:`candidate_labels` builds them when asked).
    """

    unary: np.ndarray
    candidates: np.ndarray | None
    weight_h: np.ndarray
    weight_v: np.ndarray
    slope: float
    truncation: float
    first: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.candidates is None and self.first is None:
            raise ValueError("a grid without candidates needs first (its windows' starts)")

    @property
    def shape(self) -> tuple[int, int]:
        return self.unary.shape[0], self.unary.shape[1]

    def candidate_labels(
        self, rows: slice = slice(None), columns: slice = slice(None)
    ) -> np.ndarray:
        """The labels (rows, columns, K) int32 the pixels' candidates stand for:
        ``candidates``, or a window grid's built from ``first``."""
        if self.candidates is not None:
            return self.candidates[rows, columns]
        assert self.first is not None  # __post_init__
        return self.first[rows, columns, None] + np.arange(self.unary.shape[2], dtype=np.int32)

    def transposed(self, candidates: bool = True) -> GridMRF:
        """The same MRF with rows and columns swapped (columns become rows, contiguous).

        Parameters
        ----------
        candidates : bool, optional
            Copy the candidates too; without, a window MRF's transpose holds none (its chains
            and neighbour costs read ``first``; saves memory).

        Returns
        -------
        GridMRF
        """
        kept = self.candidates if candidates or self.first is None else None
        return GridMRF(
            unary=np.ascontiguousarray(self.unary.transpose(1, 0, 2)),
            candidates=None if kept is None else np.ascontiguousarray(kept.transpose(1, 0, 2)),
            weight_h=np.ascontiguousarray(self.weight_v.T),
            weight_v=np.ascontiguousarray(self.weight_h.T),
            slope=self.slope,
            truncation=self.truncation,
            first=None if self.first is None else np.ascontiguousarray(self.first.T),
        )

    def pair_cost(self, labels_here: np.ndarray, labels_there: np.ndarray) -> np.ndarray:
        """``min(T, s |a - b|)`` of label arrays (disparity bins), unweighted.

        Parameters
        ----------
        labels_here, labels_there : numpy.ndarray
            Labels (not candidate indices) that broadcast together.

        Returns
        -------
        numpy.ndarray
            The regulariser, float64.
        """
        penalty = np.abs(labels_here - labels_there).astype(np.float64)
        penalty *= self.slope
        return np.minimum(penalty, self.truncation, out=penalty)

    def energy(self, labels: np.ndarray) -> float:
        """E(x) of a labelling (h, w) of candidate indices.

        Parameters
        ----------
        labels : numpy.ndarray
            Candidate index of every pixel.

        Returns
        -------
        float
        """
        per_row = grid_energy(
            self.unary, *self.edges(), np.ascontiguousarray(labels, dtype=np.int32)
        )
        return float(per_row.sum())

    def picked(self, labels: np.ndarray) -> np.ndarray:
        """The label (bin) each pixel's candidate index stands for.

        Parameters
        ----------
        labels : numpy.ndarray
            Candidate index (h, w) of every pixel.

        Returns
        -------
        numpy.ndarray
            (h, w) int32.
        """
        if self.first is not None:  # a window: no gather over the (h, w, K) candidates
            return self.first + labels.astype(np.int32, copy=False)
        indices = labels[:, :, None].astype(np.intp)
        return np.take_along_axis(self.candidate_labels(), indices, axis=2)[:, :, 0]

    def tile(self, rows: slice, columns: slice, extra: np.ndarray | None = None) -> GridMRF:
        """The sub-grid of a tile (its own edges only), with ``extra`` added to its unary: e.g.
        :func:`boundary_unary`, the cost of its edges to the fixed pixels around it.

        Parameters
        ----------
        rows, columns : slice
            The tile within the grid (steps of 1, bounds given).
        extra : numpy.ndarray, optional
            (tile rows, tile columns, K) added to the unary.

        Returns
        -------
        GridMRF
            Contiguous copies (the chain kernels read them row by row).
        """
        unary = self.unary[rows, columns]
        if extra is not None:
            unary = unary + extra
        return GridMRF(
            unary=np.ascontiguousarray(unary, dtype=np.float32),
            candidates=(
                None
                if self.candidates is None
                else np.ascontiguousarray(self.candidates[rows, columns])
            ),
            weight_h=np.ascontiguousarray(self.weight_h[rows, columns.start : columns.stop - 1]),
            weight_v=np.ascontiguousarray(self.weight_v[rows.start : rows.stop - 1, columns]),
            slope=self.slope,
            truncation=self.truncation,
            first=None if self.first is None else np.ascontiguousarray(self.first[rows, columns]),
        )

    def edges(self) -> EdgeArguments:
        """The grid's edges as every grid kernel takes them, in one place: candidates, ``first``
        (a placeholder when the candidates are not consecutive windows), whether they are
        windows, the weights, slope and truncation."""
        first = self.first if self.first is not None else _NO_FIRST
        return (
            self.candidates if self.candidates is not None else _NO_CANDIDATES,
            first,
            self.first is not None,
            self.weight_h,
            self.weight_v,
            self.slope,
            self.truncation,
        )

    def neighbour_unary(
        self, labels: np.ndarray, vertical: bool = True, out: np.ndarray | None = None
    ) -> np.ndarray:
        """The edges' cost of every candidate given the labels of the pixels above and below
        (``vertical``) or left and right: what a row (column) chain adds to its unary when the
        other rows (columns) are fixed.

        Parameters
        ----------
        labels : numpy.ndarray
            Candidate index (h, w) of every pixel (the fixed neighbours).
        vertical : bool, optional
            Vertical neighbours (for row chains) or horizontal ones (for column chains).
        out : numpy.ndarray, optional
            (h, w, K) float32 to write (every element is written).

        Returns
        -------
        numpy.ndarray
            (h, w, K) float32: ``out`` when given.
        """
        if out is None:
            out = np.empty(self.unary.shape, dtype=np.float32)
        labels = np.ascontiguousarray(labels, dtype=np.int32)
        neighbour_costs(*self.edges(), labels, vertical, out)
        return out


def boundary_unary(mrf: GridMRF, labels: np.ndarray, rows: slice, columns: slice) -> np.ndarray:
    """The cost of every candidate of a tile's pixels for their edges to the pixels just
    outside the tile, whose labels are fixed: what a tile QUBO adds to its unary.

    Parameters
    ----------
    mrf : GridMRF
        A grid holding the tile and its neighbouring pixels.
    labels : numpy.ndarray
        Candidate index (h, w) of every pixel of ``mrf`` (those outside the tile are read).
    rows, columns : slice
        The tile within ``mrf`` (steps of 1, bounds given).

    Returns
    -------
    numpy.ndarray
        (tile rows, tile columns, K) float64.
    """
    height, width = mrf.shape
    top, bottom, left, right = rows.start, rows.stop, columns.start, columns.stop
    picked = mrf.picked(labels)
    cands = mrf.candidate_labels(rows, columns)
    extra = np.zeros(cands.shape, dtype=np.float64)
    if top > 0:
        extra[0] += mrf.weight_v[top - 1, columns, None] * mrf.pair_cost(
            cands[0], picked[top - 1, columns, None]
        )
    if bottom < height:
        extra[-1] += mrf.weight_v[bottom - 1, columns, None] * mrf.pair_cost(
            cands[-1], picked[bottom, columns, None]
        )
    if left > 0:
        extra[:, 0] += mrf.weight_h[rows, left - 1, None] * mrf.pair_cost(
            cands[:, 0], picked[rows, left - 1, None]
        )
    if right < width:
        extra[:, -1] += mrf.weight_h[rows, right - 1, None] * mrf.pair_cost(
            cands[:, -1], picked[rows, right, None]
        )
    return extra


def grid_mrf(
    unary: np.ndarray,
    candidates: np.ndarray | None,
    guide: np.ndarray,
    level: LevelConfig,
    regularizer: Regularizer,
    first: np.ndarray | None = None,
) -> GridMRF:
    """A view's grid MRF: edge weights from its gray ``guide``, per axis (m where the gray step
    between the two pixels exceeds the threshold, 1 elsewhere), as :func:`shared.energy.smoothness`.

    Parameters
    ----------
    unary : numpy.ndarray
        Data costs (h, w, K).
    candidates : numpy.ndarray or None
        Labels (h, w, K) the candidates stand for; None with ``first`` (windows).
    guide : numpy.ndarray
        Gray view (h, w) in [0, 1].
    level : LevelConfig
        Slope, truncation, edge threshold and factor.
    regularizer : Regularizer
        ``truncated``, ``linear`` (no truncation, no edge weights) or ``none``.
    first : numpy.ndarray, optional
        (h, w) each pixel's first candidate when the candidates are known to be consecutive
        windows (``LevelInputs.first``); otherwise :func:`consecutive` finds out.

    Returns
    -------
    GridMRF
    """
    step_h = np.abs(guide[:, 1:] - guide[:, :-1])
    step_v = np.abs(guide[1:] - guide[:-1])
    slope, truncation = level.slope, level.truncation
    if regularizer is Regularizer.TRUNCATED:
        weight_h = np.where(step_h > level.edge_threshold, level.edge_factor, 1.0)
        weight_v = np.where(step_v > level.edge_threshold, level.edge_factor, 1.0)
    else:
        weight_h, weight_v = np.ones(step_h.shape), np.ones(step_v.shape)
        truncation = math.inf
        slope = 0.0 if regularizer is Regularizer.NONE else slope
    if candidates is not None:
        candidates = np.ascontiguousarray(candidates, dtype=np.int32)
        if first is None and consecutive(candidates):
            first = candidates[:, :, 0]
    return GridMRF(
        unary=np.ascontiguousarray(unary, dtype=np.float32),
        candidates=candidates,
        first=None if first is None else np.ascontiguousarray(first, dtype=np.int32),
        weight_h=np.ascontiguousarray(weight_h, dtype=np.float64),
        weight_v=np.ascontiguousarray(weight_v, dtype=np.float64),
        slope=float(slope),
        truncation=float(truncation),
    )


def solve_chains(
    mrf: GridMRF,
    along_columns: bool = False,
    extra: np.ndarray | None = None,
    sign: float = 1.0,
    base: np.ndarray | None = None,
    scale: float = 1.0,
    transpose: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """The exact optimum of every row (or column) of a grid MRF as an independent chain, with
    unary ``scale * base + sign * extra`` (default: the MRF's own).

    Parameters
    ----------
    mrf : GridMRF
        The grid (candidates, edge weights, regulariser; its unary unless ``base`` is given).
    along_columns : bool, optional
        Chains along the columns (vertical edges) instead of the rows (horizontal edges).
    extra : numpy.ndarray, optional
        (h, w, K) float32 added to the unary (times ``sign``).
    sign : float, optional
        +1 or -1 (the two copies of dual decomposition).
    base : numpy.ndarray, optional
        (h, w, K) float32 unary in place of the MRF's.
    scale : float, optional
        Factor of ``base`` (0.5: dual decomposition's half copies, without storing them).
    transpose : bool, optional
        Return the labels transposed, (w, h) and contiguous, written so by the kernels: a
        transposed copy's chains give the original grid's labels without a transpose copy.

    Returns
    -------
    labels : numpy.ndarray
        (h, w) int32 optimal candidate indices of every chain ((w, h) when ``transpose``).
    energies : numpy.ndarray
        Each chain's optimal energy (h or w values), float64.
    """
    base = mrf.unary if base is None else base
    labels = np.zeros(mrf.shape[::-1] if transpose else mrf.shape, dtype=np.int32)
    if extra is None:
        extra, sign = base, 0.0
    # columns: the same kernels on transposed views (numba compiles them for strided arrays)
    turn = (lambda a: a.transpose(1, 0, 2)) if along_columns else (lambda a: a)
    flip = (lambda a: a.T) if along_columns else (lambda a: a)
    weight = mrf.weight_v if along_columns else mrf.weight_h
    common = (turn(base), float(scale), turn(extra), float(sign))
    if mrf.first is not None:
        edges = (flip(mrf.first), flip(weight), mrf.slope, mrf.truncation)
        energies = chains_windows(*common, *edges, flip(labels), transpose)
    else:
        edges = (turn(mrf.candidates), flip(weight), mrf.slope, mrf.truncation)
        energies = chains_general(*common, *edges, flip(labels), transpose)
    return labels, energies


def consecutive(candidates: np.ndarray) -> bool:
    """Whether every pixel's candidates are consecutive labels (first, first + 1, ...).

    Parameters
    ----------
    candidates : numpy.ndarray
        (..., K) labels.

    Returns
    -------
    bool
    """
    return bool(np.all(np.diff(candidates, axis=-1) == 1))


@dataclass
class DualResult:
    """What dual decomposition found on one grid."""

    labels: np.ndarray
    energy: float
    lower_bound: float
    iterations: int
    #: Pixels whose row and column labels disagreed in the last iteration (0: optimal).
    disagreeing: int
    #: (h, w) bool: those pixels (the row and column copies disagree), the only ones the
    #: decomposition leaves unsettled (:mod:`shared.settle` sends tiles around them).
    unsettled: np.ndarray | None = None

    @property
    def gap(self) -> float:
        """(E - LB) / |E|: how far the labelling can be from the optimum, relatively."""
        return (self.energy - self.lower_bound) / max(abs(self.energy), 1e-12)


def dual_decomposition(mrf: GridMRF, iterations: int, gap: float = 0.0) -> DualResult:
    """Minimise the grid MRF by dual decomposition into row and column chains (module doc).

    Parameters
    ----------
    mrf : GridMRF
        One view's grid.
    iterations : int
        Most subgradient iterations (fewer when row and column labels agree).
    gap : float, optional
        Stop once (E - LB) / |E| is at most this: the labelling is then certified that close
        to the optimum, and more iterations change the map less than the data term's noise.

    Returns
    -------
    DualResult
        The lowest-energy labelling seen, its energy, the best lower bound and the gap.
    """
    # the column chains run on a transposed copy (contiguous columns: 2-3x faster than strided)
    turned = mrf.transposed(candidates=False)  # its energy is never taken: no candidates
    # each copy's unary is half the MRF's (scaled inside the kernels: x 0.5 is exact, and two
    # fewer (h, w, K) arrays per view)
    # written now, not np.zeros' untouched pages: the chains read the multipliers before the
    # first step writes them, and a page read first maps the kernel's zero page, whose copy on
    # the first write flushes the other cores' TLBs (an IPI per page: 3-6 % of a run's CPU)
    multipliers = np.full(mrf.unary.shape, 0, dtype=mrf.unary.dtype)
    multipliers_turned = np.full(turned.unary.shape, 0, dtype=turned.unary.dtype)
    best_labels, best_energy = np.zeros(mrf.shape, dtype=np.int32), math.inf
    bound, gamma, stalled = -math.inf, 1.0, 0
    disagreeing, done = -1, 0
    row_labels = np.zeros(mrf.shape, dtype=np.int32)
    column_labels = np.zeros(mrf.shape, dtype=np.int32)
    # the primal steps' neighbour costs (fresh arrays: 2.3 of Art x3's 5.3 GiB of page faults)
    scratch = np.empty(mrf.unary.size, dtype=np.float32)

    def consider(labels: np.ndarray, energy: float | None = None) -> None:
        nonlocal best_labels, best_energy
        energy = mrf.energy(labels) if energy is None else energy
        if energy < best_energy:
            best_labels, best_energy = labels, energy

    # a core no other grid holds (threads.spare_core) takes the column chains and their energy
    with ThreadPoolExecutor(1, thread_name_prefix="qhsm-dual") as spare:
        for done in range(1, iterations + 1):
            helper = spare if spare_core() else None
            (row_labels, row_energies), (column_labels, column_energies) = both(
                partial(solve_chains, mrf, False, multipliers, 1.0, scale=0.5),
                partial(
                    solve_chains, turned, False, multipliers_turned, -1.0, scale=0.5, transpose=True
                ),
                helper,
            )
            current = float(row_energies.sum() + column_energies.sum())
            row_energy, column_energy = both(
                partial(mrf.energy, row_labels), partial(mrf.energy, column_labels), helper
            )
            consider(row_labels, row_energy)  # in this order, as one after the other
            consider(column_labels, column_energy)
            if done % PRIMAL_EVERY == 0:
                consider(chain_primal(mrf, turned, column_labels, scratch))
            disagreeing = disagreements(row_labels, column_labels)
            if current > bound:
                bound, stalled = current, 0
            else:
                stalled += 1
                if stalled >= STALL_ITERATIONS:
                    gamma, stalled = gamma / 2.0, 0
            if disagreeing == 0 or best_energy - bound <= gap * abs(best_energy):
                break
            step = np.float32(gamma * max(best_energy - current, 0.0) / (2 * disagreeing))
            subgradient_step(multipliers, multipliers_turned, row_labels, column_labels, step)
    return DualResult(
        labels=best_labels,
        energy=float(best_energy),
        lower_bound=float(min(bound, best_energy)),
        iterations=done,
        disagreeing=disagreeing,
        unsettled=row_labels != column_labels,
    )


def chain_primal(
    mrf: GridMRF, turned: GridMRF, column_labels: np.ndarray, scratch: np.ndarray | None = None
) -> np.ndarray:
    """A labelling by chains: rows given the column solution's vertical neighbours, then columns
    (as rows of the transposed grid ``turned``) given those rows' horizontal neighbours; both
    neighbour costs in ``scratch`` (float32, the unary's size) when given."""
    scratch = np.empty(mrf.unary.size, dtype=np.float32) if scratch is None else scratch
    # labels written in the layout the next step reads; the columns' costs overwrite the rows'
    extra = mrf.neighbour_unary(column_labels, out=scratch.reshape(mrf.unary.shape))
    rows, _ = solve_chains(mrf, False, extra, transpose=True)
    extra = turned.neighbour_unary(rows, out=scratch.reshape(turned.unary.shape))
    refined, _ = solve_chains(turned, False, extra, transpose=True)
    return refined


def chain_sweeps(mrf: GridMRF, turned: GridMRF, labels: np.ndarray, sweeps: int = 1) -> np.ndarray:
    """Lower a labelling's energy by exact chain solves: the even rows given all other labels,
    then the odd rows, then the columns likewise (as the rows of ``turned``, the transpose of
    ``mrf`` with its candidates). No two even rows share an edge, so their chains together are
    the exact minimum of E over those rows: E never rises. Why: it measures how far a labelling
    (dual decomposition's) is from the optimum its bound allows (benchmarks/primal_gap.py).

    Parameters
    ----------
    mrf : GridMRF
        The grid.
    turned : GridMRF
        ``mrf.transposed()``.
    labels : numpy.ndarray
        (h, w) candidate indices to start from (not modified).
    sweeps : int, optional
        Rounds of the four half-grids.

    Returns
    -------
    numpy.ndarray
        (h, w) int32 candidate indices, E at most that of ``labels``.
    """
    labels = np.array(labels, dtype=np.int32)
    for _ in range(sweeps):
        labels = _alternate_chains(mrf, labels)
        labels = _alternate_chains(turned, np.ascontiguousarray(labels.T)).T.copy()
    return labels


def _alternate_chains(mrf: GridMRF, labels: np.ndarray) -> np.ndarray:
    """``labels`` with its even rows, then its odd rows, each set to their chains' optimum given
    the rows above and below (modified in place and returned)."""
    for parity in (0, 1):
        rows = slice(parity, None, 2)
        extra = mrf.neighbour_unary(labels)[rows]
        half = GridMRF(
            unary=np.ascontiguousarray(mrf.unary[rows]),
            candidates=(
                None if mrf.first is not None else np.ascontiguousarray(mrf.candidate_labels(rows))
            ),
            weight_h=np.ascontiguousarray(mrf.weight_h[rows]),
            weight_v=np.zeros((0, mrf.shape[1])),  # row chains read no vertical edge
            slope=mrf.slope,
            truncation=mrf.truncation,
            first=None if mrf.first is None else np.ascontiguousarray(mrf.first[rows]),
        )
        labels[rows], _ = solve_chains(half, extra=np.ascontiguousarray(extra))
    return labels
