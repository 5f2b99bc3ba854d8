"""The one pipeline: coarse-to-fine MRF stereo, one row QUBO per bundle at every level.

    resolve max disparity    the given one, or estimated by a quick dense match (``auto``)
    plan                     the levels (:func:`shared.pyramid.plan`: image or bin pyramid)
    for each level k (coarse to fine):
        prepare_level        level images (both views stacked with the LR check), candidates
                             from level k-1, warm-start labels
        solve_level          injected: in process (CLI, tests) or a Celery fan-out (service)
        finish_level         labels -> level map, median filter per view
        level_stages         which stage decided each pixel (the finest level's are kept)
    finish                   full-resolution left disparity: left-right check and background
                             fill, sub-pixel fit, weighted median, bilateral (as configured);
                             the validity, confidence and provenance maps

``run_pipeline`` runs the loop synchronously. The service calls the same functions from its
fan-in callbacks, so the level logic lives only here.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass
from functools import partial

import numpy as np

from shared import coarse_grid, filters, hypotheses, kernels, provenance_map, pyramid
from shared.assembly import LevelSolution
from shared.config import DataTerm, Inference, MatchConfig, PyramidKind
from shared.data_terms import VolumeBlock, cost_volume
from shared.disparity_range import (
    RangeEstimate,
    ViewsRefusedError,
    ViewsWarning,
    resolve_max_disparity,
)
from shared.finishing import finish_level, finish_maps, level_stages
from shared.images import as_pair_of_same_kind, check_pair, to_gray
from shared.inference import reads_initial_labels, solve_level_in_process
from shared.level_inputs import LevelInputs
from shared.level_report import LevelReport
from shared.pyramid import LevelPlan
from shared.threads import beside, each_beside

SolveLevel = Callable[..., LevelSolution]
"""``(inputs, config[, progress=shared.inference.BundleProgress]) -> LevelSolution``: one level."""
Progress = Callable[[int, int, int, int], None]
"""``(level, levels, units done, units total)``: the 1-based level being solved, the run's
levels, and the level's :data:`shared.inference.BundleProgress`."""

#: In process, the views' aggregated cost volumes are computed once for all levels when together
#: they are at most this large; larger volumes are kept binned at the finest level width that
#: fits, for the levels that width divides, and recomputed per block of rows at the finer levels
#: (memory bound by rows). 512 MiB holds a 0.36 MP / 106 px pair's two views (305 MB): its CPU
#: time -16 to -27 %; a 4 MP / 64 px pair's at width 8 (2 levels of 5; peak RSS 1.56 GB, where
#: 640 MiB, width 4 for 3 levels, peaked at 2.08 GB).
VOLUME_CACHE_BYTES = 512 * 2**20
#: A cache that only coarse-grid levels read may be this large: it is released before the first
#: full-resolution level, whose dual state makes the run's peak, and the coarse levels pool it
#: a few bins at a time (:func:`shared.coarse_grid.pooled_costs`). A 4 MP / 256 px pair's bins
#: of 8 (1007 MiB) serve its four coarse levels, where bins of 32 served two and the bins of 16
#: and 8 were built again (three passes over every disparity).
COARSE_VOLUME_CACHE_BYTES = 1024 * 2**20


@dataclass
class MatchResult:
    """Full-resolution left-view disparity (float32, pixels) and per-level reports."""

    disparity: np.ndarray
    levels: list[LevelReport]
    seconds: float
    disparity_range: RangeEstimate
    #: Where the left-right check confirmed the pixel (None without ``lr_check``).
    validity: np.ndarray | None = None
    #: :func:`shared.filters.cost_confidence` of the final map, times the validity.
    confidence: np.ndarray | None = None
    #: What decided each pixel: :class:`shared.provenance_map.Stage` codes (uint8, h x w).
    provenance_map: np.ndarray | None = None

    def summary(self) -> dict:
        """The run without its map, JSON-friendly (the CLI's ``--json``, job results).

        Returns
        -------
        dict
            ``seconds``, ``disparity_range`` (:meth:`RangeEstimate.as_dict`, named as in the job
            status), one dict per level and ``provenance_counts`` (pixels per stage of the
            provenance map, :func:`shared.provenance_map.counts`; None without the map).
        """
        return {
            "seconds": self.seconds,
            "disparity_range": self.disparity_range.as_dict(),
            "levels": [asdict(level) for level in self.levels],
            "provenance_counts": None
            if self.provenance_map is None
            else provenance_map.counts(self.provenance_map),
        }


def match_views(
    left: np.ndarray, right: np.ndarray, config: MatchConfig
) -> tuple[np.ndarray, np.ndarray]:
    """The views the data term reads: gray for the squared difference (the paper converts before
    downsampling), colour otherwise when both views have it.

    Parameters
    ----------
    left, right : numpy.ndarray
        A rectified pair, float32 in [0, 1], (h, w) gray or (h, w, 3) BGR.
    config : MatchConfig
        The run's configuration (its data term).

    Returns
    -------
    tuple of numpy.ndarray
        ``(left, right)`` as the data term reads them.

    Raises
    ------
    ImageError
        If the views differ in size.
    """
    check_pair(left, right)
    if config.data_term is DataTerm.SQUARED:
        return to_gray(left), to_gray(right)
    return as_pair_of_same_kind(left, right)


def plan_run(
    left: np.ndarray, right: np.ndarray, config: MatchConfig
) -> tuple[RangeEstimate, list[LevelPlan]]:
    """The run's disparity range (given or estimated) and its levels, from the match views.

    Parameters
    ----------
    left, right : numpy.ndarray
        The pair's :func:`match_views`.
    config : MatchConfig
        The run's configuration.

    Returns
    -------
    estimate : RangeEstimate
        The maximum disparity and how it was found.
    plans : list of LevelPlan
        The levels, coarsest first.
    """
    estimate = resolve_max_disparity(left, right, config.max_disparity)
    warning = pyramid.range_warning(config, estimate.max_disparity)
    if warning:
        warnings.warn(warning, pyramid.RangeWarning, stacklevel=2)
    return estimate, pyramid.plan(config, estimate.max_disparity)


def _plan_beside(
    left: np.ndarray, right: np.ndarray, config: MatchConfig
) -> tuple[Callable[[], RangeEstimate], list[LevelPlan]]:
    """:func:`plan_run`, with the views' check left running in a thread when the range is
    given (the plans do not depend on it; it costs about as much as the first level's volumes
    and inputs, which it overlaps: the run waits for it only before the first solve): a getter
    of the estimate, which issues the check's :class:`~shared.disparity_range.ViewsWarning`
    when it has one, and the plans."""
    if not isinstance(config.max_disparity, int):
        estimate, plans = plan_run(left, right, config)
        return lambda: estimate, plans
    pending = beside(resolve_max_disparity, left, right, config.max_disparity, warn=False)
    warning = pyramid.range_warning(config, config.max_disparity)
    if warning:
        warnings.warn(warning, pyramid.RangeWarning, stacklevel=3)

    def checked() -> RangeEstimate:
        estimate = pending()
        if estimate.warning:
            warnings.warn(estimate.warning, ViewsWarning, stacklevel=3)
        return estimate

    return checked, pyramid.plan(config, config.max_disparity)


def level_views(
    left: np.ndarray, right: np.ndarray, config: MatchConfig, plan: LevelPlan
) -> tuple[np.ndarray, np.ndarray, int]:
    """The level's images and view count: with the left-right check the mirrored pair (both
    images flipped, roles swapped) is stacked below the pair, so its left view is the right one.

    Parameters
    ----------
    left, right : numpy.ndarray
        The pair's :func:`match_views`.
    config : MatchConfig
        The run's configuration (its left-right check).
    plan : LevelPlan
        The level (its downsampling factor).

    Returns
    -------
    left, right : numpy.ndarray
        The level's images, ``views`` pairs stacked top to bottom.
    views : int
        1, or 2 with the left-right check.
    """
    left_k = pyramid.downsample(left, plan.downsample)
    right_k = pyramid.downsample(right, plan.downsample)
    if not config.lr_check:
        return left_k, right_k, 1
    return (
        np.concatenate([left_k, right_k[:, ::-1]]),
        np.concatenate([right_k, left_k[:, ::-1]]),
        2,
    )


def prepare_level(
    left: np.ndarray,
    right: np.ndarray,
    config: MatchConfig,
    plan: LevelPlan,
    previous: np.ndarray | None = None,
    coarser: LevelInputs | None = None,
    fine: LevelInputs | None = None,
) -> LevelInputs:
    """Inputs of one level from the :func:`match_views` of the pair; ``previous`` is the coarser
    level's finished map (:func:`finish_level`).

    Parameters
    ----------
    left, right : numpy.ndarray
        The pair's :func:`match_views` at full resolution.
    config : MatchConfig
        The run's configuration.
    plan : LevelPlan
        The level to prepare.
    previous : numpy.ndarray, optional
        The coarser level's finished map; ``None`` at the coarsest level.
    coarser : LevelInputs, optional
        The coarser level's inputs: their images are this level's when both have the same
        downsampling (every level of a bin pyramid: the stacked views are built once).
    fine : LevelInputs, optional
        The full-resolution views (:func:`shared.coarse_grid.fine_inputs`) with the run's
        cached volumes: a coarse-grid level's costs are pooled from them (built here if None),
        and a full-resolution level's stacked views are theirs.

    Returns
    -------
    LevelInputs
        Images, candidates and warm-start labels (``None`` at the coarsest level, and for an
        inference that reads none: :func:`shared.inference.reads_initial_labels`) of the level.
    """
    if coarser is not None and coarser.plan.downsample == plan.downsample:
        left_k, right_k, views = coarser.left, coarser.right, coarser.views
    elif fine is not None and fine.plan.downsample == plan.downsample:
        # the first full-resolution level: the run's stacked views, not a second copy of them
        left_k, right_k, views = fine.left, fine.right, fine.views
    else:
        left_k, right_k, views = level_views(left, right, config, plan)
    shape = left_k.shape[:2]
    pooled = None
    if config.pyramid is PyramidKind.BINS and plan.downsample > 1:
        if fine is None:
            fine = fine_views(left, right, config, plan)
        view_shape = (shape[0] // views, shape[1])
        pooled = coarse_grid.pooled_costs(fine, plan, config.data_term, view_shape)
    if previous is not None and config.pyramid is PyramidKind.BINS:
        previous = pyramid.upsample_labels(previous, views, (shape[0] // views, shape[1]))
    first: np.ndarray | None = None
    initial: np.ndarray | None = None
    candidates: np.ndarray | None
    if previous is None:
        candidates = pyramid.initial_candidates(shape, plan.candidates, plan.max_label)
        values = candidates[0, 0]  # the same at every pixel; consecutive when bins <= K
        if np.all(np.diff(values) == 1):
            first = np.full(shape, values[0], dtype=np.int32)
            candidates = None  # the window: first + arange(K)
    else:
        warm = reads_initial_labels(config)  # a grid or a row chain solved whole reads none
        if config.pyramid is PyramidKind.IMAGE:
            candidates = pyramid.refined_candidates(
                previous, shape, plan.candidates, plan.max_label
            )
            if warm:
                target = pyramid.upsample_disparity(previous, shape)
                initial = np.abs(candidates - target[:, :, None]).argmin(axis=2)
                initial = initial.astype(np.int32)
        else:
            first = pyramid.window_starts(previous, plan.candidates, plan.max_label)
            candidates = None  # the windows: first + arange(K), not kept
            if warm:  # the lower child of the coarser bin, among consecutive candidates
                initial = pyramid.nearest_in_window(2.0 * previous, first, plan.candidates)
    inputs = LevelInputs(
        plan=plan,
        left=left_k,
        right=right_k,
        candidates=candidates,
        initial_labels=initial,
        views=views,
        first=first,
        pooled=pooled,
    )
    if previous is not None and config.pyramid is PyramidKind.BINS and plan.mrf.coarse_prior:
        inputs.coarse_bins = pyramid.prior_bins(previous, views)
    if (
        previous is not None
        and config.pyramid is PyramidKind.BINS
        and plan.index <= config.second_bins
    ):
        coarse = None
        if fine is not None and plan.downsample > 1:  # the coarser bins pooled as this level's
            wider = plan.model_copy(update={"bin_width": 2 * plan.bin_width})
            coarse = list(coarse_grid.pooled_costs(fine, wider, config.data_term, view_shape))
        inputs.candidates = hypotheses.with_second_bins(
            inputs, previous, config.data_term, config.second_bins_radius, coarse
        )
        inputs.first = None  # no longer one window
    return inputs


def fine_views(
    left: np.ndarray, right: np.ndarray, config: MatchConfig, plan: LevelPlan
) -> LevelInputs:
    """The full-resolution views as :func:`shared.coarse_grid.fine_inputs` (the run's volumes
    and a coarse grid's pooled costs are built from them)."""
    fine = plan.model_copy(update={"downsample": 1})
    return coarse_grid.fine_inputs(*level_views(left, right, config, fine), fine)


def report(inputs: LevelInputs, solution: LevelSolution, seconds: float) -> LevelReport:
    """One level's :class:`LevelReport` from its inputs and solution.

    Parameters
    ----------
    inputs : LevelInputs
        The level's inputs.
    solution : LevelSolution
        Its solution.
    seconds : float
        Wall time of the level.

    Returns
    -------
    LevelReport
    """
    height, width = inputs.view_height, inputs.shape[1]
    return LevelReport(
        index=inputs.plan.index,
        downsample=inputs.plan.downsample,
        bin_width=inputs.plan.bin_width,
        views=inputs.views,
        height=height,
        width=width,
        candidates=inputs.plan.candidates,
        bundles=solution.bundles,
        energy=solution.energy,
        lower_bound=solution.lower_bound,
        gap=None
        if solution.lower_bound is None
        else (solution.energy - solution.lower_bound) / max(abs(solution.energy), 1e-12),
        repaired=solution.repaired,
        seconds=seconds,
        solver_seconds=solution.solver_seconds,
        timing=solution.timing,
        info=solution.info,
        residual=solution.residual,
        termination=solution.termination,
        provenance_counts=None
        if solution.stages is None
        else provenance_map.counts(solution.stages),
    )


def run_pipeline(
    left: np.ndarray,
    right: np.ndarray,
    config: MatchConfig,
    solve_level: SolveLevel = solve_level_in_process,
    progress: Progress | None = None,
    force: bool = True,
) -> MatchResult:
    """Match a rectified pair (float32 in [0, 1], gray or BGR); returns the left view's
    disparity in full-resolution pixels.

    Parameters
    ----------
    left, right : numpy.ndarray
        A rectified pair, float32 in [0, 1], (h, w) gray or (h, w, 3) BGR.
    config : MatchConfig
        The run's configuration.
    solve_level : callable, optional
        ``(LevelInputs, MatchConfig) -> LevelSolution``; default: in process. With
        ``progress`` it is also given ``progress=``, the level's
        :data:`shared.inference.BundleProgress`.
    progress : callable, optional
        A :data:`Progress`: called as bundles of a level are solved (as often as
        ``solve_level`` reports) and once more when the level is done.
    force : bool, optional
        Run even when the views fail their check (swapped, not rectified, identical); False:
        :class:`ViewsRefusedError` before any level (``qhsm match`` without ``--force``).

    Returns
    -------
    MatchResult
        The disparity, per-level reports, wall time and the disparity range used.
    """
    started = time.perf_counter()
    if config.inference is Inference.GRID:
        kernels.preload()  # numba's start beside the views' check and the volumes
    left, right = match_views(left, right, config)
    checked, plans = _plan_beside(left, right, config)
    estimate: RangeEstimate | None = None
    reports: list[LevelReport] = []
    level_map: np.ndarray | None = None
    stages: np.ndarray | None = None
    volumes: list[np.ndarray] | None = None
    volume_bin_width = 1
    inputs: LevelInputs | None = None
    fine: LevelInputs | None = None
    for plan in plans:
        level_started = time.perf_counter()
        if plan.index == 0:  # the full-resolution views and their volumes, before any level
            fine = fine_views(left, right, config, plan)
            volumes, volume_bin_width = _cached_volumes(fine, config, plans)
        elif plan.bin_width < volume_bin_width:
            volumes = None  # finer than the cached bins: no later level reads them
        assert fine is not None  # set at index 0
        fine.volumes, fine.volume_bin_width = volumes, volume_bin_width
        coarser = inputs if inputs is not None else fine
        coarser.volumes = volumes  # released by the coarser level too (it lives till prepared)
        inputs = prepare_level(left, right, config, plan, level_map, coarser, fine)
        if inputs.pooled is not None and not _read_after(plans, plan.index, volume_bin_width):
            # a coarse level pooled the cache for the last time: released before its solve
            volumes = fine.volumes = coarser.volumes = None
        inputs.volumes, inputs.volume_bin_width = volumes, volume_bin_width
        if plan.index == 0:  # the views' check, done beside the volumes and these inputs
            estimate = checked()
            if estimate.warning and not force:
                raise ViewsRefusedError(estimate.warning)
        if progress is None:
            solution = solve_level(inputs, config)
        else:
            solution = solve_level(
                inputs, config, progress=partial(progress, plan.index + 1, len(plans))
            )
        level_map = finish_level(inputs, solution, config)
        stages = level_stages(inputs, solution, level_map)  # the finest level's are kept
        reports.append(report(inputs, solution, time.perf_counter() - level_started))
        if progress is not None:
            progress(plan.index + 1, len(plans), solution.bundles, solution.bundles)
    # plan() gives at least one level, the first index 0
    assert level_map is not None and inputs is not None and estimate is not None
    left_volume = volumes[0] if volumes and volume_bin_width == 1 else None
    # the confidence's least costs do not depend on the map: taken beside the finish, whose
    # weighted median runs on one core
    at_hand = left_volume is not None and left_volume.shape[1:] == left.shape[:2]
    least = beside(filters.least_costs, left_volume) if at_hand else lambda: None
    disparity, validity, provenance = finish_maps(
        level_map, left, right, config, plans[-1], inputs.views, left_volume, stages
    )
    confidence = confidence_map(
        disparity, validity, left, right, config, plans[-1], left_volume, least()
    )
    return MatchResult(
        disparity=disparity,
        levels=reports,
        seconds=time.perf_counter() - started,
        disparity_range=estimate,
        validity=validity,
        confidence=confidence,
        provenance_map=provenance,
    )


def confidence_map(
    disparity: np.ndarray,
    validity: np.ndarray | None,
    left: np.ndarray,
    right: np.ndarray,
    config: MatchConfig,
    last: LevelPlan,
    left_volume: np.ndarray | None,
    least: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray | None:
    """The final map's :func:`shared.filters.cost_confidence` under the run's data term, 0
    where the left-right check failed; None when the full cost volume would exceed
    :data:`VOLUME_CACHE_BYTES` and is not already at hand. ``least``: the :func:`least_costs
    <shared.filters.least_costs>` of ``left_volume``, when taken beforehand."""
    height, width = disparity.shape
    if left_volume is None or left_volume.shape[1:] != (height, width):
        if (last.max_disparity + 1) * height * width * 4 > VOLUME_CACHE_BYTES:
            return None
        block = VolumeBlock(last.max_disparity, 0, height)
        left_volume, least = cost_volume(config.data_term, left, right, block), None
    confidence = filters.cost_confidence(left_volume, disparity, least)
    return confidence if validity is None else np.where(validity, confidence, 0.0)


def _read_after(plans: list[LevelPlan], index: int, bin_width: int) -> bool:
    """Whether a level after ``index``, or the finish (the full volume's sub-pixel fit and
    confidence, ``bin_width`` 1), reads a cache binned at ``bin_width``."""
    later = plans[index + 1 :]
    return bin_width == 1 or any(plan.bin_width % bin_width == 0 for plan in later)


def _cached_volumes(
    inputs: LevelInputs, config: MatchConfig, plans: list[LevelPlan]
) -> tuple[list[np.ndarray] | None, int]:
    """Every view's cost volume, built once for the levels of the bin pyramid that read it, and
    its bin width: the full volumes (width 1) when they fit :data:`VOLUME_CACHE_BYTES`, else the
    volumes binned at the finest level width that fits, which every coarser level reads too
    (finer levels build their costs per block); :data:`COARSE_VOLUME_CACHE_BYTES` when only
    coarse-grid levels read it. ``(None, 1)`` when the pyramid does not share a volume between
    levels or no width below the coarsest fits."""
    if config.pyramid is not PyramidKind.BINS or config.data_term is DataTerm.SQUARED:
        return None, 1
    height, width = inputs.view_height, inputs.shape[1]
    max_disparity = inputs.plan.max_disparity
    for bin_width in sorted({plan.bin_width for plan in plans} | {1}):
        if bin_width > 1 and bin_width >= plans[0].bin_width:
            break  # the coarsest level alone gains nothing
        bins = max_disparity // bin_width + 1
        readers = [plan for plan in plans if plan.bin_width % bin_width == 0]
        coarse = bin_width > 1 and all(plan.downsample > 1 for plan in readers)
        budget = COARSE_VOLUME_CACHE_BYTES if coarse else VOLUME_CACHE_BYTES
        if bins * height * width * 4 * inputs.views > budget:
            continue
        if bin_width == 1:  # the full volumes (the sub-pixel fit and the confidence read them)
            whole = VolumeBlock(max_disparity, 0, height)
            views = [(config.data_term, left, right, whole) for left, right in inputs.view_images()]
            return each_beside(cost_volume, views), 1  # the other views on the spare core
        return inputs.binned_view_volumes(config.data_term, bin_width), bin_width
    return None, 1
