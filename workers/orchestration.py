"""The service's ``solve_level``: a Celery chord per pyramid level, driven by fan-in callbacks.

    start_job      (control)  load uploads, resolve the disparity range (and check the views),
                              plan the levels, prepare_level(0), write inputs, launch chord 0
    plan_level     (solver)   only for solvers that plan on their QPU graph (qpu, qpu-sim): the
                              widest segment that embeds and the shapes' embeddings, found where
                              the solver (and its token) is, kept with the level and the
                              embeddings; then fan_out_level (control) launches the chord
    solve_bundles  (solver)   load the level's inputs once per process, solve_bundles, labels back
    level_done     (control)  assemble, finish_level, report; prepare the next level and launch
                              its chord, or finish_maps() (+ metrics) and store the result

No task ever waits for another: each level's callback launches the next level. The level logic
is ``shared.pipeline``'s and the level inference's (``shared.inference``: planned, solved
and assembled by the strategy its table chooses); this module only moves data between them.
The tasks stay together because each hands the next its data; the job's state changes are
``JobRecord``'s pure methods (``workers/records.py``), applied by ``JobStore.apply``.
"""

from __future__ import annotations

import logging
import time
from collections import OrderedDict
from collections.abc import Callable
from functools import partial

import numpy as np
from celery import Celery, chain, chord

from shared import pyramid
from shared.activity import reporting
from shared.assembly import BundleResult
from shared.bundles import bundle_key
from shared.config import MatchConfig, Settings
from shared.disparity_range import resolve_max_disparity
from shared.finishing import finish_level, finish_maps, level_stages
from shared.inference import inference_for
from shared.level_inputs import LevelInputs
from shared.memory import VOLUME_CACHE_MB, check_fits, job_memory_mb, worker_budget_mb
from shared.metrics import evaluate
from shared.pipeline import confidence_map, match_views, prepare_level, report
from shared.provenance_map import counts as pixel_counts
from shared.pyramid import LevelPlan
from shared.solvers.qpu.problems import sent_problems, task_label
from workers import fair
from workers.app import FAN_OUT_LEVEL, LEVEL_DONE, PLAN_LEVEL, SOLVE_BUNDLES, task_time_limits
from workers.chunks import (
    RowRanges,
    decode_bundle,
    encode_bundle,
    is_planned,
    rows_per_task,
    task_chunks,
)
from workers.level_store import LevelInputsMissingError
from workers.queues import job_solver, solver_queue
from workers.quota import LOCAL_USER, QpuMeter, solve_metered
from workers.records import ChunkReport, JobRecord, JobState, LevelRecord, now
from workers.store import JobStore
from workers.telemetry import Telemetry

log = logging.getLogger(__name__)

#: Level inputs a worker process keeps (a few jobs' current levels).
LEVEL_CACHE_SIZE = 4
_level_cache: OrderedDict[tuple[str, int], tuple[LevelInputs, JobRecord]] = OrderedDict()


class JobGoneError(LookupError):
    """The job record has expired or never existed."""


def internal_error(job_id: str, what: str) -> str:
    return (
        f"internal error while {what}; the traceback is in the worker log (job {job_id}). "
        "Resubmit the job; report it if it happens again"
    )


# --- control queue ---------------------------------------------------------------------------


def start_job(celery: Celery, store: JobStore, job_id: str) -> None:
    """Begin a queued job: its first level's chord. A start whose worker died before it
    launched the first level (the job is running, at level 0) is carried out again when its
    message comes back."""
    record, _ = store.apply(job_id, JobRecord.started, now())
    if record is None or record.state is not JobState.RUNNING or record.level or record.levels:
        log.info("job %s: not queued any more (cancelled, gone or started); nothing to do", job_id)
        return
    left, right = job_views(store, record)
    if record.disparity_range is None:
        record = resolve_range(store, record, left, right)
        if record is None:
            return
    # this worker's own budget (its host's memory): MemoryBudgetError fails the job
    check_fits(record.memory_mb or 0, worker_budget_mb(store.settings))
    first = job_plans(record)[0]
    launch_level(celery, store, record, prepare_level(left, right, record.config, first))


def resolve_range(
    store: JobStore, record: JobRecord, left: np.ndarray, right: np.ndarray
) -> JobRecord | None:
    """The job's disparity range (given, or estimated for ``auto``) and the check of its views,
    written to the running job's record: ``disparity_range``, the levels it makes, and the
    views' warning first among the job's warnings. Done here, in the job's first control task,
    rather than in the HTTP request that accepted it. None when the job is no longer running."""
    # the warning goes to the job's status, not the log
    estimate = resolve_max_disparity(left, right, record.config.max_disparity, warn=False)
    levels = len(pyramid.plan(record.config, estimate.max_disparity))
    pyramid_note = pyramid.range_warning(record.config, estimate.max_disparity)
    notes = (pyramid_note,) if pyramid_note else ()
    memory = job_memory_mb(record.config, record.height, record.width, estimate.max_disparity)

    def with_range(current: JobRecord) -> JobRecord | None:
        """The range (``JobRecord.with_range``) and the peak memory it makes."""
        changed = current.with_range(estimate, levels, notes)
        return None if changed is None else changed.model_copy(update={"memory_mb": memory})

    updated, _ = store.apply(record.id, with_range)
    if updated is None or updated.state is not JobState.RUNNING:
        return None
    return updated


def job_views(store: JobStore, record: JobRecord) -> tuple[np.ndarray, np.ndarray]:
    """The job's uploads as the views its data term reads."""
    return match_views(*store.load_views(record.id), record.config)


def job_plans(record: JobRecord) -> list[LevelPlan]:
    """The job's levels, from the disparity range resolved when it started (or, for a metered
    solver with ``max_disparity: auto``, when it was accepted)."""
    if record.disparity_range is None:
        raise ValueError(f"job {record.id}: no disparity range recorded")
    return pyramid.plan(record.config, record.disparity_range.max_disparity)


def launch_level(celery: Celery, store: JobStore, record: JobRecord, inputs: LevelInputs) -> None:
    """Write the level's inputs once, plan its bundles and fan them out on the solver's queue.

    Planning is geometry for most solvers (done here). Solvers that embed on a QPU graph need
    their sampler for it, and so the D-Wave token, which control workers never have: for
    them it is a task on the solver's own queue (:func:`plan_level`), followed by
    :func:`fan_out_level` here."""
    config = record.config
    inference = inference_for(config)
    started = time.time()
    remote = inference.plans_with_solver
    # the host's step (the residual design settles the level): its labels go with the inputs;
    # the strategy reports what it does as the level's phase (shared.activity)
    with reporting(partial(store.set_phase, record.id, inputs.plan.index)):
        done = inference.prepare(inputs, config)
        if done is not None:
            log.info("job %s: level %d %s", record.id, inputs.plan.index + 1, done)
        if not remote:
            inference.plan(inputs, config)  # sets inputs.prepared: the bundles' width
    store.save_level(record.id, inputs, started=started)
    if remote:
        if _advance(store, record.id, inputs.plan.index):
            send_plan(celery, store.settings, record.id, inputs.plan.index, config.solver)
        return
    _fan_out_planned(celery, store, record.id, inputs, launched_here=True)


def _advance(
    store: JobStore, job_id: str, index: int, total: int = 0, *, launched_here: bool = True
) -> bool:
    """Make level ``index`` the running job's current one with ``total`` bundles (0 while
    they are planned elsewhere); False (and the level's inputs dropped) when the job is no
    longer running. With ``launched_here`` false the level must be current and not fanned
    out yet (a repeated fan-out changes nothing)."""
    updated, moved = store.apply(job_id, JobRecord.at_level, index, total, launched_here)
    if updated is None or updated.state is not JobState.RUNNING:
        store.drop_level(job_id, index)
        return False
    return moved


def _fan_out_planned(
    celery: Celery, store: JobStore, job_id: str, inputs: LevelInputs, *, launched_here: bool
) -> None:
    """The planned level's chord, once its bundle count is on the record."""
    record = store.get(job_id)
    if record is None:
        return
    config = record.config
    chunks = task_chunks(inputs, config, rows_per_task(store.settings, config.solver))
    total = sum(len(chunk) for chunk in chunks)
    if _advance(store, job_id, inputs.plan.index, total, launched_here=launched_here):
        if not chunks:  # the host settled every pixel: nothing to send, the fan-in at once
            celery.signature(
                LEVEL_DONE, args=([], job_id, inputs.plan.index), queue=store.settings.control_queue
            ).apply_async()
            return
        fan_out(celery, store, record, inputs.plan.index, chunks)


def send_plan(celery: Celery, settings: Settings, job_id: str, index: int, solver: str) -> None:
    """Plan the level on the solver's queue, then fan it out from the control queue."""
    chain(
        celery.signature(
            PLAN_LEVEL,
            args=(job_id, index),
            queue=solver_queue(solver),
            **task_time_limits(settings, solver),
        ),
        celery.signature(
            FAN_OUT_LEVEL, args=(job_id, index), queue=settings.control_queue, immutable=True
        ),
    ).apply_async()


def plan_level(store: JobStore, job_id: str, index: int) -> dict | None:
    """On the solver's queue: what the level's plan needs from the solver (its QPU graph: the
    widest segment that embeds, every bundle shape embedded once, kept in the embedding store),
    recorded with the level's inputs; None when the job is no longer running.

    Idempotent: a level planned already (a re-sent or redelivered task) is left as it is."""
    if store.state(job_id) is not JobState.RUNNING:
        return None
    record = store.get(job_id)
    if record is None:
        raise JobGoneError(job_id)
    inputs, _ = store.load_level(job_id, index)
    if not is_planned(inputs):
        with reporting(partial(store.set_phase, job_id, index)):  # e.g. the embedding search
            inference_for(record.config).plan(inputs, record.config)
        store.save_prepared(job_id, index, inputs.prepared)
    return inputs.prepared


def fan_out_level(celery: Celery, store: JobStore, job_id: str, index: int) -> None:
    """On the control queue, after :func:`plan_level`: launch the planned level's chord (once:
    a level whose bundle count is already on the record was launched)."""
    record = store.get(job_id)
    if record is None or record.state is not JobState.RUNNING or record.level != index + 1:
        return
    if record.bundles_total:
        log.info("job %s: level %d fanned out already; ignoring a repeat", job_id, index + 1)
        return
    inputs, _ = store.load_level(job_id, index)
    if is_planned(inputs):
        _fan_out_planned(celery, store, job_id, inputs, launched_here=False)


def fan_out(
    celery: Celery, store: JobStore, record: JobRecord, index: int, chunks: list[RowRanges]
) -> None:
    """A chord: the chunks on the job's owner's queue of the solver (``workers/fair.py``:
    users are served in turn), with the solver's time limits, then the level's fan-in on the
    control queue."""
    settings, solver = store.settings, record.config.solver
    queue = fair.route(store.redis, store.prefix, solver_queue(solver), record.owner)
    limits = task_time_limits(settings, solver)
    header = [
        celery.signature(SOLVE_BUNDLES, args=(record.id, index, chunk), queue=queue, **limits)
        for chunk in chunks
    ]
    callback = celery.signature(LEVEL_DONE, args=(record.id, index), queue=settings.control_queue)
    chord(header)(callback)


def level_done(celery: Celery, store: JobStore, results: list[dict], job_id: str, index: int):
    """Fan-in: assemble and filter the level, then launch the next one or finish the job.

    The level is assembled from the solved bundles in the store, not from ``results``: a chord
    the watchdog re-sent for lost chunks carries only those. Runs at most once per level."""
    record = _running_record(store, job_id, index)
    if record is None:
        return
    level = _level_inputs(store, job_id, index)
    if level is None:
        return
    inputs, started = level
    bundles = _solved_bundles(store, job_id, index, inputs, record.config)
    if bundles is None:
        return
    level_map, stages, level_report = _assemble_level(inputs, bundles, record.config, started)
    # None when the job ended, or the same level was assembled twice at once and the other won
    record, added = store.apply(job_id, JobRecord.with_level, index, level_report)
    if record is None or not added:
        return
    store.drop_level(job_id, index)
    _next_level_or_finish(celery, store, record, index, inputs, level_map, stages)


def _running_record(store: JobStore, job_id: str, index: int) -> JobRecord | None:
    """The running job's record; None when it ended or is gone (its level inputs are dropped)
    or this level was already assembled (a redelivered fan-in)."""
    record = store.get(job_id)
    if record is None or record.state is not JobState.RUNNING:
        store.drop_level(job_id, index)
        return None
    if len(record.levels) > index:  # redelivered after a worker died having done this
        log.info("job %s: level %d already assembled; ignoring a repeated fan-in", job_id, index)
        return None
    return record


def _level_inputs(store: JobStore, job_id: str, index: int) -> tuple[LevelInputs, float] | None:
    """The level's inputs and when it started; None when they are gone: a concurrent fan-in
    finished the level, or they expired in the queue (the job is failed saying so)."""
    try:
        return store.load_level(job_id, index)
    except LevelInputsMissingError:
        record = store.get(job_id)
        if record is None or record.state is not JobState.RUNNING or len(record.levels) > index:
            return None  # a concurrent fan-in of the same level finished it
        # tasks that fail the job or see it end return no bundles, and the state check above
        # returns; a running job without its level inputs lost them (expired)
        store.fail(
            job_id,
            f"some bundles of level {index + 1} were not solved because the level's inputs "
            "expired while they waited in the queue; resubmit the job, or raise "
            "QHSM_TASK_VISIBILITY_TIMEOUT if the queue is often this long",
        )
        return None


def _solved_bundles(
    store: JobStore, job_id: str, index: int, inputs: LevelInputs, config: MatchConfig
) -> list[BundleResult] | None:
    """Every planned bundle of the level, decoded from the store, in plan order; None while
    some are missing."""
    width = inputs.shape[1]
    solved = store.solved_bundles(job_id, index)
    expected = [bundle_key(b.as_list()) for b in inference_for(config).planned(inputs, config)]
    missing = [key for key in expected if key not in solved]
    if missing:  # lost with a worker or a Redis outage: the watchdog re-sends them
        log.warning("job %s: level %d misses %d bundles", job_id, index, len(missing))
        return None
    return [decode_bundle(solved[key], width) for key in expected]


def _assemble_level(
    inputs: LevelInputs, bundles: list[BundleResult], config: MatchConfig, started: float
) -> tuple[np.ndarray, np.ndarray, LevelRecord]:
    """The level's filtered disparity map (``finish_level``), its provenance codes
    (``level_stages``) and its report for the record."""
    solution = inference_for(config).assemble(inputs, bundles, config)
    level_map = finish_level(inputs, solution, config)
    level_report = LevelRecord.of(report(inputs, solution, time.time() - started))
    return level_map, level_stages(inputs, solution, level_map), level_report


def _next_level_or_finish(
    celery: Celery,
    store: JobStore,
    record: JobRecord,
    index: int,
    inputs: LevelInputs,
    level_map: np.ndarray,
    stages: np.ndarray,
) -> None:
    """Launch the next level's chord from this level's map, or finish the job after the last
    (``stages``: the level's provenance codes; the finest level's make the provenance map)."""
    config = record.config
    left, right = job_views(store, record)
    plans = job_plans(record)
    if index + 1 < len(plans):
        next_inputs = prepare_level(left, right, config, plans[index + 1], level_map)
        launch_level(celery, store, record, next_inputs)
        return
    result, validity, provenance = finish_maps(
        level_map, left, right, config, plans[-1], inputs.views, stages=stages
    )
    confidence = None
    if (plans[-1].max_disparity + 1) * result.size * 4 <= VOLUME_CACHE_MB * 2**20:
        # within the volume the job's memory estimate allows for (shared.memory): larger
        # jobs keep the validity map only
        confidence = confidence_map(result, validity, left, right, config, plans[-1], None)
    maps = {
        name: array
        for name, array in (
            ("validity", validity),
            ("confidence", confidence),
            ("provenance", provenance),
        )
        if array is not None
    }
    metrics, warning = _evaluate_result(store, record, result)
    store.save_result(record.id, result, maps)
    counts = None if provenance is None else pixel_counts(provenance)
    done = store.apply(record.id, JobRecord.succeeded, now(), metrics, warning, list(maps), counts)
    if done.changed and counts is not None:
        Telemetry(store.redis, store.settings.key_prefix).pixels_decided(config.solver, counts)


def _evaluate_result(
    store: JobStore, record: JobRecord, result: np.ndarray
) -> tuple[dict | None, str | None]:
    """The job's metrics against its ground truth (None without one), and a warning saying why
    a ground truth that does not fit was not evaluated."""
    if record.ground_truth is None:
        return None, None
    try:
        scores = evaluate(
            result,
            store.load_upload(record.id, "ground_truth"),
            scale=record.ground_truth.scale,
            border=record.ground_truth.border,
        )
        return scores.as_dict(), None
    except ValueError as error:
        return None, f"ground truth not evaluated: {error}"


# --- solver queues ---------------------------------------------------------------------------


def level_for(store: JobStore, job_id: str, index: int) -> tuple[LevelInputs, JobRecord]:
    """The level's inputs and the job's record (its config and owner), read from Redis once
    per worker process and level."""
    key = (job_id, index)
    if key in _level_cache:
        _level_cache.move_to_end(key)
        return _level_cache[key]
    record = store.get(job_id)
    if record is None:
        raise JobGoneError(job_id)
    inputs, _ = store.load_level(job_id, index)
    _level_cache[key] = (inputs, record)
    while len(_level_cache) > LEVEL_CACHE_SIZE:
        _level_cache.popitem(last=False)
    return inputs, record


def solve_chunk(
    store: JobStore,
    job_id: str,
    index: int,
    row_ranges: RowRanges,
    worker: str,
    meter: Callable[[], QpuMeter] | None = None,
) -> dict | None:
    """Solve some bundles of a level; None when the job is no longer running (not solved).

    Metered solvers go through ``meter()`` (lab-wide slot, budget reservation, settlement per
    bundle); a job whose owner's budget runs out raises ``QuotaExceededError`` (a SolverError)."""
    if store.state(job_id) is not JobState.RUNNING:
        return None
    solved = store.solved_rows(job_id, index)
    if all(bundle_key(spec) in solved for spec in row_ranges):  # a re-sent duplicate: done
        return {"bundles": len(row_ranges), "duplicate": True}
    inputs, record = level_for(store, job_id, index)
    config = record.config
    # every D-Wave problem labelled with the task, its id kept (shared.solvers.qpu.problems)
    solver = job_solver(config)  # once for the task: the inference and the meter take it
    with sent_problems(task_label(job_id, index, bundle_key(row_ranges[0]))) as problems:
        if solver.spec.metered and meter is not None:
            results = solve_metered(
                meter(),
                record.owner or LOCAL_USER,
                job_id,
                inputs,
                solver,
                [inputs.as_bundle(tuple(spec)) for spec in row_ranges],
                still_running=lambda: store.state(job_id) is JobState.RUNNING,
                level_estimate=record.level_estimate(index),
            )
            if results is None:
                return None
        else:
            bundles = [tuple(spec) for spec in row_ranges]
            results = inference_for(solver).solve(inputs, config, bundles)
    timing: dict[str, float] = {}
    for result in results:
        for key, value in result.timing.items():
            timing[key] = timing.get(key, 0.0) + float(value)
    chunk = ChunkReport(
        level=index,
        bundles=len(results),
        wall_time=float(sum(result.wall_time for result in results)),
        timing=timing,
        worker=worker,
        problem_ids=problems.ids,
    )
    store.save_bundles(job_id, index, [encode_bundle(result) for result in results])
    store.record_chunk(job_id, bundle_key(row_ranges[0]), chunk)
    return {"bundles": len(results)}  # how many; the labels are in the store for the fan-in


def retry_delay(settings: Settings, retries: int) -> float:
    """Exponential backoff after a transient solver error."""
    return min(settings.retry_backoff * 2**retries, settings.retry_backoff_max)
