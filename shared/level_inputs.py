"""The inputs of one level: everything needed to build any bundle of it (the level's images, both
views stacked, and its candidate array), and the bundles it is cut into. Workers receive this;
:mod:`shared.inference` cuts it into bundles and solves them."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from shared.bundles import Bundle, bundle_rows, segment_columns
from shared.config import DataTerm, MatchConfig
from shared.data_terms import (
    VolumeBlock,
    bin_minimum,
    binned_cost_volume,
    gather,
    gather_window,
    squared_difference,
    volume_dtype,
    window_costs,
    window_minimum,
    window_minimum_runs,
)
from shared.energy import Costs, mrf_costs
from shared.grid import GridMRF, grid_mrf
from shared.images import to_gray
from shared.pyramid import LevelPlan, outside_coarse_bin
from shared.threads import each_beside

#: Rows of a cost volume built at once for a bundle of many rows (a grid's whole view): the
#: block's (D + 1) x rows x w float32 within this.
VOLUME_BLOCK_BYTES = 64 * 2**20

#: A bundle as given to :func:`shared.inference.solve_bundles`: a :class:`Bundle`, a row range
#: ``(row_start, row_stop)`` (whole rows) or ``(row_start, row_stop, col_start, col_stop)``.
BundleSpec = Bundle | Sequence[int]


@dataclass
class LevelInputs:
    """Everything needed to build any bundle of a level.

    ``left`` / ``right`` are the level's images (float32 in [0, 1], gray or BGR colour) and
    ``candidates`` (rows, w, K) int32 the labels each pixel may take (None on a window level,
    below: :meth:`candidate_labels` builds them when asked). With ``views`` = 2 the
    arrays hold two matching problems one below the other: rows [0, h) are the left view's,
    rows [h, 2h) the right view's as the mirrored pair (both images flipped, roles swapped).
    Bundles, tasks and progress therefore treat the right view as more rows of the same level;
    costs never mix the two. ``initial_labels`` (rows, w) is the coarser level's estimate as
    labels, for warm starts; ``None`` on the coarsest level. ``first`` (rows, w) int32 is each
    pixel's first candidate when its candidates are consecutive labels (a bin level's window:
    ``candidates == first[..., None] + arange(K)``), else ``None``: costs, the grid and the
    picked labels then read it, and the (rows, w, K) array is not kept (``candidates`` None:
    Aloe's finest three levels built theirs in 32 ms of the run's serial path, 2000 x 2000's
    are 192 MB each).
    """

    plan: LevelPlan
    left: np.ndarray
    right: np.ndarray
    candidates: np.ndarray | None
    initial_labels: np.ndarray | None = None
    views: int = 1
    #: Optional per-view cost volumes (in process only; workers build costs per block), binned
    #: at ``volume_bin_width`` (1: the full volumes; :meth:`binned_view_volumes`).
    volumes: list[np.ndarray] | None = None
    #: The bin width of ``volumes``: a level whose width is a multiple reads its bins from them
    #: (a bin's minimum is the minimum of its sub-bins' minima: the very values).
    volume_bin_width: int = 1
    #: Each pixel's first candidate when the candidates are consecutive windows (class doc).
    first: np.ndarray | None = None
    #: A coarse grid's bin costs (views, bins, view_height, w): the full-resolution ones
    #: averaged over each block (:mod:`shared.coarse_grid`); they replace the level's own.
    pooled: np.ndarray | None = None
    #: (rows, w) int32: the coarser level's bin of each pixel, on a level whose MRF has a
    #: ``coarse_prior`` (:meth:`view_unary` adds it), else None.
    coarse_bins: np.ndarray | None = None
    #: What planning the bundles did (``LevelInference.plan``): segment width, embeddings.
    prepared: dict = field(default_factory=dict)
    _binned: list[np.ndarray] | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        if self.candidates is None and self.first is None:
            raise ValueError("a level without candidates needs first (its windows' starts)")

    @property
    def count(self) -> int:
        """K: the candidates of every pixel."""
        return self.plan.candidates if self.candidates is None else self.candidates.shape[2]

    def candidate_labels(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """The labels (stop - start, w, K) int32 the candidates of rows [start, stop) stand
        for: ``candidates``, or a window level's built from ``first``."""
        if self.candidates is not None:
            return self.candidates[start:stop]
        assert self.first is not None  # __post_init__
        return self.first[start:stop, :, None] + np.arange(self.count, dtype=np.int32)

    @property
    def shape(self) -> tuple[int, int]:
        """(rows of all views, width)."""
        return self.left.shape[0], self.left.shape[1]

    @property
    def view_height(self) -> int:
        return self.left.shape[0] // self.views

    def view_parts(self, start: int, stop: int) -> list[tuple[int, int, int]]:
        """Rows [start, stop) split by view, as (view, first row, stop row) in view rows.

        Parameters
        ----------
        start, stop : int
            Rows of the stacked views.

        Returns
        -------
        list of tuple of int
            ``(view, first, stop)`` per view the range touches, rows counted within that view.
        """
        parts = []
        height = self.view_height
        for view in range(self.views):
            first, last = max(start, view * height), min(stop, (view + 1) * height)
            if first < last:
                parts.append((view, first - view * height, last - view * height))
        return parts

    def starting_labels(self, costs: Costs, start: int, stop: int) -> np.ndarray:
        """A warm start for rows [start, stop): the coarser level's estimate, or on the coarsest
        level the data term's winner-takes-all (``costs`` are those rows' costs).

        Parameters
        ----------
        costs : Costs
            The costs of rows [start, stop).
        start, stop : int
            Rows of the stacked views.

        Returns
        -------
        numpy.ndarray
            Candidate index (stop - start, w), int32.
        """
        if self.initial_labels is not None:
            return self.initial_labels[start:stop]
        return costs.unary.argmin(axis=2).astype(np.int32)

    def bundle_rows(self, bundle_height: int) -> list[tuple[int, int]]:
        """The level's bundles as row ranges: each view tiled on its own, so that no bundle
        spans the seam between the two views.

        Parameters
        ----------
        bundle_height : int
            Rows per bundle.

        Returns
        -------
        list of tuple of int
            ``(start, stop)`` in rows of the stacked views.
        """
        height = self.view_height
        return [
            (view * height + start, view * height + stop)
            for view in range(self.views)
            for start, stop in bundle_rows(height, bundle_height)
        ]

    def bundles(self, bundle_height: int, bundle_width: int | None, margin: int) -> list[Bundle]:
        """The level's bundles: :meth:`bundle_rows`, each cut into row segments of
        ``bundle_width`` pixels overlapping by ``margin`` (:func:`shared.bundles.segment_columns`;
        None: whole rows).

        Parameters
        ----------
        bundle_height : int
            Rows per bundle.
        bundle_width : int or None
            Columns per segment; ``None`` for whole rows.
        margin : int
            Least overlap of neighbouring segments, pixels.

        Returns
        -------
        list of Bundle
            Row by row, segments left to right.
        """
        columns = segment_columns(self.shape[1], bundle_width, margin)
        return [
            Bundle(start, stop, first, last)
            for start, stop in self.bundle_rows(bundle_height)
            for first, last in columns
        ]

    def planned_bundles(self, config: MatchConfig) -> list[Bundle]:
        """The bundles of ``bundle_height`` rows and ``bundle_width`` a strategy's ``plan`` chose
        for this level (kept in ``prepared``), without searching or embedding again.

        Parameters
        ----------
        config : MatchConfig
            The run's configuration (bundle height and margin).

        Returns
        -------
        list of Bundle
        """
        width = self.prepared.get("bundle_width")
        if width is not None and width >= self.shape[1]:
            width = None
        height = self.prepared.get("bundle_height", config.bundle_height)
        return self.bundles(height, width, config.bundle_margin)

    def as_bundle(self, spec: BundleSpec) -> Bundle:
        """A :class:`Bundle` from a bundle or a row range (whole rows).

        Parameters
        ----------
        spec : Bundle or sequence of int
            A bundle, ``[row_start, row_stop, col_start, col_stop]`` or ``[row_start, row_stop]``.

        Returns
        -------
        Bundle
        """
        if isinstance(spec, Bundle):
            return spec
        if len(spec) == 4:
            return Bundle(*spec)
        start, stop = spec
        return Bundle(start, stop, 0, self.shape[1])

    def view_images(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """(left, right) image of each view.

        Returns
        -------
        list of tuple of numpy.ndarray
            One ``(left, right)`` per view, each (view_height, w) or (view_height, w, 3).
        """
        height = self.view_height
        return [
            (self.left[v * height : (v + 1) * height], self.right[v * height : (v + 1) * height])
            for v in range(self.views)
        ]

    def picked(self, labels: np.ndarray) -> np.ndarray:
        """The label each pixel's candidate index stands for.

        Parameters
        ----------
        labels : numpy.ndarray
            Candidate index (rows, w) of every pixel (all views).

        Returns
        -------
        numpy.ndarray
            (rows, w) int32.
        """
        if self.first is not None:
            return self.first + labels.astype(np.int32, copy=False)
        return np.take_along_axis(self.candidate_labels(), labels[:, :, None], axis=2)[:, :, 0]

    def _rows(self, view: int, first: int, last: int) -> tuple[int, int]:
        """Rows [first, last) of one view as rows of the stacked views."""
        base = view * self.view_height
        return base + first, base + last

    def _window(self, view: int, first: int, last: int) -> np.ndarray | None:
        """``first`` of rows [first, last) of one view, or None."""
        if self.first is None:
            return None
        start, stop = self._rows(view, first, last)
        return self.first[start:stop]

    def _cached(self) -> bool:
        """Whether this level's bin costs come from ``pooled`` or the cached ``volumes``."""
        if self.pooled is not None:
            return True
        return self.volumes is not None and self.plan.bin_width % self.volume_bin_width == 0

    def _bin_costs(
        self,
        data_term: DataTerm,
        view: int,
        block: VolumeBlock,
        scratch: np.ndarray | None = None,
    ) -> np.ndarray:
        """The data term of every label (bins, block rows, w) on a block of one view; the full
        volume of the rows goes into ``scratch`` (:meth:`_scratch`) when given, so the result
        may be a view of it."""
        if not self._cached():
            left, right = self.view_images()[view]
            out = block.within(scratch)
            return binned_cost_volume(data_term, left, right, block, self.plan.bin_width, out)
        return self.binned_volumes()[view][:, block.start : block.stop]

    def _candidate_costs(
        self,
        data_term: DataTerm,
        view: int,
        first: int,
        last: int,
        dtype: type = np.float64,
        workers: int = 1,
    ) -> np.ndarray:
        """(last - first, w, K) costs of the candidates, built from the cost volume a block of
        :data:`VOLUME_BLOCK_BYTES` at a time (blocks dealt to ``workers`` threads) when no volume
        is cached: a view's volume holds every disparity of every pixel (4 GB at 2000 x 2000 x
        257). The same values either way: costs are row-local. ``dtype`` float32 for a grid (the
        volume's own precision: exact) halves the view's costs."""
        window = self._window(view, first, last)
        count = self.count
        candidates = (
            None if window is not None else self.candidate_labels(*self._rows(view, first, last))
        )

        def pick(per_label: np.ndarray, rows: slice) -> np.ndarray:
            if candidates is not None:
                return gather(per_label, candidates[rows], dtype)
            assert window is not None
            return gather_window(per_label, window[rows], count, dtype)

        if self._cached():
            direct = self._cached_windows(view, first, window, count, dtype)
            if direct is not None:
                return direct
            whole = VolumeBlock(self.plan.max_disparity, first, last)
            return pick(self._bin_costs(data_term, view, whole), slice(None))
        costs: np.ndarray = np.empty((last - first, self.shape[1], count), dtype=dtype)
        (left, right), width = self.view_images()[view], self.plan.bin_width

        def fill(blocks: list[VolumeBlock]) -> None:
            scratch = self._scratch(data_term, blocks)
            for block in blocks:
                rows = slice(block.start - first, block.stop - first)
                direct = None
                if window is not None:  # the kernels' window costs: no volume, no gather
                    direct = window_costs(data_term, left, right, block, width, window[rows], count)
                if direct is None:
                    direct = pick(self._bin_costs(data_term, view, block, scratch), rows)
                costs[rows] = direct

        blocks = self._volume_blocks(first, last)
        shares = [blocks[i :: max(1, workers)] for i in range(min(max(1, workers), len(blocks)))]
        each_beside(fill, [(share,) for share in shares])
        return costs

    def _cached_source(self, view: int) -> tuple[np.ndarray, int]:
        """The cached costs (planes, view_height, w) of one view this level's bins are the
        minima of, and the planes per bin: the pooled bins themselves, else the cached volume's
        planes this level's width spans."""
        if self.pooled is not None:
            return self.pooled[view], 1
        assert self.volumes is not None  # _cached()
        return self.volumes[view], self.plan.bin_width // self.volume_bin_width

    def _cached_windows(
        self, view: int, first: int, window: np.ndarray | None, count: int, dtype: type
    ) -> np.ndarray | None:
        """The windows' costs of rows [first, ...) of one view straight from the cached costs by
        the compiled kernel (:func:`shared.data_terms.window_minimum`), or None (no windows, or
        the kernel does not run: the caller bins and gathers)."""
        if window is None:
            return None
        source, ratio = self._cached_source(view)
        return window_minimum(source, first, window, count, ratio, dtype)

    def prepare_costs(self) -> None:
        """Build the cached volumes' bins that bundles' costs read (:meth:`binned_volumes`), once,
        before the inputs are shared between threads; nothing when each window's costs come
        straight from the cached volumes (:meth:`_cached_windows`: no binned copy of the
        volumes, 0.03-0.05 s of each of Aloe's views at widths 4 and 2)."""
        if self.first is not None and self._cached():
            sources = [self._cached_source(view)[0] for view in range(self.views)]
            if all(window_minimum_runs(source) for source in sources):
                return
        self.binned_volumes()

    def _scratch(self, data_term: DataTerm, blocks: list[VolumeBlock]) -> np.ndarray | None:
        """One block's full volume, for every block of ``blocks`` in turn (None for one block):
        a fresh array per block costs its page faults every time."""
        if len(blocks) < 2:
            return None
        shape = (self.plan.max_disparity + 1, blocks[0].rows, self.shape[1])
        return np.empty(shape, dtype=volume_dtype(data_term))

    def _volume_blocks(self, first: int, last: int) -> list[VolumeBlock]:
        """Rows [first, last) in blocks whose full cost volume fits :data:`VOLUME_BLOCK_BYTES`."""
        max_disparity = self.plan.max_disparity
        step = max(1, VOLUME_BLOCK_BYTES // (4 * (max_disparity + 1) * self.shape[1]))
        return [
            VolumeBlock(max_disparity, start, min(start + step, last))
            for start in range(first, last, step)
        ]

    def binned_view_volumes(self, data_term: DataTerm, bin_width: int) -> list[np.ndarray]:
        """Every view's cost volume binned at ``bin_width`` (bins, view_height, w), built a block
        of rows at a time: memory bound by the bins, not by the disparities (the cache of the
        coarse levels when the full volumes are too large to keep).

        Parameters
        ----------
        data_term : DataTerm
            The run's data term.
        bin_width : int
            Disparities per bin.

        Returns
        -------
        list of numpy.ndarray
            One (bins, view_height, w) array per view, of the data term's precision.
        """

        def binned(left: np.ndarray, right: np.ndarray) -> np.ndarray:
            view: np.ndarray | None = None
            blocks = self._volume_blocks(0, self.view_height)
            scratch = self._scratch(data_term, blocks)
            for block in blocks:
                out = block.within(scratch)
                costs = binned_cost_volume(data_term, left, right, block, bin_width, out)
                if view is None:
                    view = np.empty((len(costs), self.view_height, self.shape[1]), costs.dtype)
                view[:, block.start : block.stop] = costs
            assert view is not None  # a view has rows
            return view

        # the other views on the spare core (a block each at a time)
        return each_beside(binned, self.view_images())

    def level_bin_costs(self, data_term: DataTerm) -> list[np.ndarray]:
        """Every view's bin costs at this level's width (bins, view_height, w): from the cached
        volumes when they serve it, else built a block of rows at a time."""
        if self._cached():
            return self.binned_volumes()
        return self.binned_view_volumes(data_term, self.plan.bin_width)

    def binned_volumes(self) -> list[np.ndarray]:
        """The cached volumes' bin minima per view at this level's width, built once (call before
        sharing the inputs between threads).

        Returns
        -------
        list of numpy.ndarray
            (bins, view_height, w) per view; empty without cached volumes of a width dividing
            this level's.
        """
        if self.pooled is not None:
            return list(self.pooled)
        if self._binned is None and self.volumes is not None and self._cached():
            ratio = self.plan.bin_width // self.volume_bin_width
            self._binned = each_beside(bin_minimum, [(v, ratio) for v in self.volumes])
        return self._binned or []

    def view_unary(
        self,
        config: MatchConfig,
        view: int,
        first: int,
        last: int,
        dtype: type = np.float64,
        workers: int = 1,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The data term of rows [first, last) of one view at its candidates, with the level's
        coarse-to-fine prior (:meth:`_add_coarse_prior`).

        Parameters
        ----------
        config : MatchConfig
            The run's configuration (its data term).
        view : int
            0 (the left view's problem) or 1 (the mirrored pair's).
        first, last : int
            Rows within the view.
        dtype : type, optional
            Of the costs: float64 (the row matcher's arithmetic) or float32 (a grid's).
        workers : int, optional
            Threads that build the costs' blocks (:meth:`_candidate_costs`).

        Returns
        -------
        unary : numpy.ndarray
            (last - first, w, K) costs.
        guide : numpy.ndarray
            Gray rows (last - first, w) of the view's left image.
        """
        left, right = self.view_images()[view]
        guide = to_gray(left[first:last])
        if config.data_term is DataTerm.SQUARED and self.plan.bin_width == 1:
            # the paper's path: evaluated at the candidates only
            candidates = self.candidate_labels(*self._rows(view, first, last))
            unary = squared_difference(guide, to_gray(right[first:last]), candidates)
        else:
            unary = self._candidate_costs(config.data_term, view, first, last, dtype, workers)
            self._add_coarse_prior(unary, view, first, last)
        return unary, guide

    def _add_coarse_prior(self, unary: np.ndarray, view: int, first: int, last: int) -> None:
        """Add to ``unary`` (rows [first, last) of one view, a fresh array) the level's
        ``coarse_prior`` per bin each candidate lies outside its coarser bin
        (:func:`shared.pyramid.outside_coarse_bin`): on the coarse levels a wall's data term
        is flat, and over a large wall a small, consistent bias of it can outweigh the few
        edges that hold the wall at the coarser level's bin (docs/benchmarks.md, "The
        coarse-to-fine prior")."""
        weight = self.plan.mrf.coarse_prior
        if not weight or self.coarse_bins is None:
            return
        start, stop = self._rows(view, first, last)
        outside = outside_coarse_bin(
            self.candidate_labels(start, stop), self.coarse_bins[start:stop]
        )
        unary += outside.astype(unary.dtype) * unary.dtype.type(weight)

    def grid(self, config: MatchConfig, start: int, stop: int, workers: int = 1) -> GridMRF:
        """The grid MRF of rows [start, stop) of one view (``grid`` inference).

        Parameters
        ----------
        config : MatchConfig
            The run's configuration.
        start, stop : int
            Rows of the stacked views, within one view.
        workers : int, optional
            Threads that build its costs (the grids minimised one at a time: a core spare).

        Returns
        -------
        GridMRF

        Raises
        ------
        ValueError
            If the rows span both views.
        """
        parts = self.view_parts(start, stop)
        if len(parts) != 1:
            raise ValueError(f"rows [{start}, {stop}) span both views; a grid is one view's")
        unary, guide = self.view_unary(config, *parts[0], np.float32, workers)
        window = self._window(*parts[0])  # a window grid's candidates: first + arange(K)
        candidates = None if window is not None else self.candidate_labels(*self._rows(*parts[0]))
        return grid_mrf(unary, candidates, guide, self.plan.mrf, config.regularizer, window)

    def costs(self, config: MatchConfig, start: int = 0, stop: int | None = None) -> Costs:
        """Costs of rows [start, stop) (a block that spans both views has no edge between).

        Parameters
        ----------
        config : MatchConfig
            The run's configuration.
        start : int, optional
            First row of the stacked views.
        stop : int, optional
            Row after the last; default: all rows.

        Returns
        -------
        Costs
            Vertical edges only when ``config.bundle_height`` > 1.
        """
        stop = self.shape[0] if stop is None else stop
        blocks = []
        for view, first, last in self.view_parts(start, stop):
            unary, guide = self.view_unary(config, view, first, last)
            blocks.append(
                mrf_costs(
                    unary,
                    self.candidate_labels(*self._rows(view, first, last)),
                    guide,
                    self.plan.mrf,
                    config.regularizer,
                    vertical=config.bundle_height > 1,
                )
            )
        return Costs.stack(blocks)
