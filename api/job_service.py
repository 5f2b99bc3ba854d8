"""The job service: what admits a job (``POST /v1/jobs``), and the job lookups the routes
share, as plain functions of the app's :class:`Services` (estimates: :mod:`api.estimate_service`).

Admission, in this order (a request with several problems is told the first): the owner's
active-job cap (before the uploads are read), the ``params`` (a ``MatchConfig``), the solver and
its parameters, the views, the job's memory when its range is given, the ground truth; then the
record is written and ``qhsm.start_job`` sent. A metered solver's job is written ``pricing`` and
``qhsm.price_job`` sent to the pricing queue instead: the worker estimates its QPU time, checks
it against the owner's budget and queues it or fails it with the reason (``workers.pricing``);
the API never runs the matcher.

Nothing here speaks HTTP: a refusal is a domain error (:mod:`api.errors`), which ``create_app``
answers with its status and message.
"""

from __future__ import annotations

import contextlib
import logging
from dataclasses import dataclass

import cv2
import numpy as np

from api.auth import Principal, can_see
from api.deps import Services, load_solver
from api.errors import (
    AdmissionError,
    ExpiredError,
    JobNotFoundError,
    JobStateError,
    Refusal,
)
from api.uploads import (
    Upload,
    decode_ground_truth,
    decode_pair,
    display_name,
    one_line,
    parse_config,
    parse_tags,
    read_upload,
)
from api.users import UserStore
from shared.config import MatchConfig
from shared.ground_truth import FormatScale, infer_gt_scale, scale_of_format
from shared.memory import MemoryBudgetError, check_fits, job_memory_mb, worker_budget_mb
from shared.provenance import qhsm_version
from shared.pyramid import plan
from shared.solvers import Availability
from shared.solvers.meters.qpu_time import is_metered
from shared.solvers.resolved import ResolvedSolver
from workers.app import pricing_task_id, terminate_tasks
from workers.app import send_first_task as first_task
from workers.estimates import revoke
from workers.records import ACTIVE, Cameras, GroundTruth, JobRecord, JobState, new_job_id, now
from workers.store import ActiveJobsCapError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class JobForm:
    """A job as submitted: the form fields of ``POST /v1/jobs``, not read or checked yet."""

    left: Upload
    right: Upload
    params: str | None = None
    ground_truth: Upload | None = None
    gt_scale: float | None = None
    gt_border: int = GroundTruth.model_fields["border"].default
    label: str | None = None
    cameras: Cameras | None = None
    tags: str | None = None  # comma-separated


# --- admission checks -----------------------------------------------------------------------


def check_active_jobs(owner: str, svc: Services) -> None:
    """Refuse at once, before the uploads are read, when the user already has
    ``Settings.max_active_jobs_per_user`` jobs in flight (the cap is taken atomically when the
    job is written: :meth:`workers.store.JobStore.create`)."""
    cap = svc.settings.max_active_jobs_per_user
    if not cap:  # 0 or None: no limit
        return
    active = svc.store.active_jobs(owner)
    if active >= cap:
        raise ActiveJobsCapError(owner, active, cap)


def check_solver_name(config: MatchConfig) -> tuple[ResolvedSolver, Availability]:
    """The solver must be registered (``UnknownSolverError`` otherwise) and its bundle width
    usable; returns it resolved, and whether it runs here."""
    solver, availability = load_solver(config)
    try:
        solver.bundle_width_setting()
    except ValueError as error:
        raise AdmissionError(Refusal.INVALID, f"params: {error}") from None
    return solver, availability


def check_solver(config: MatchConfig, svc: Services) -> ResolvedSolver:
    """The solver must exist, and run here or have a worker consuming its queue; returns it
    resolved."""
    solver, availability = check_solver_name(config)
    if availability.ok:
        return solver
    consumers = svc.queues.consumers() or {}
    queue = solver.spec.queue_name
    if consumers.get(queue):
        return solver
    raise AdmissionError(
        Refusal.INVALID,
        f"solver {config.solver!r} is not available: {availability.reason}; and no worker "
        f"consumes its queue (start one where it can run: "
        f"celery -A workers worker -Q {queue})",
    )


def bounded_params(config: MatchConfig, solver: ResolvedSolver) -> MatchConfig:
    """The config with its solver parameters checked against the solver's schema
    (``InvalidSolverParamsError`` when one is outside it)."""
    return config.model_copy(update={"solver_params": solver.checked_params()})


def ground_truth_protocol(
    left_image: np.ndarray,
    right_image: np.ndarray,
    values: np.ndarray,
    scale: float | None,
    border: int,
    stated: FormatScale | None = None,
) -> tuple[GroundTruth, str]:
    """How an uploaded ground truth is scored: the given scale (with a warning when the file's
    format, ``stated``, says otherwise), else the format's (PFM 1, 16-bit PNG 256), else one
    inferred from the views, with the note that says so (``ScaleNotInferredError`` when they
    do not tell)."""
    if scale is not None:
        return GroundTruth(scale=scale, border=border), stated.disagreement(scale) if stated else ""
    if stated is not None:
        note = f"ground-truth scale not given: {stated.scale:g}, from {stated.source}"
        # not inferred from the views (``inferred`` says that): the format states it
        return GroundTruth(scale=stated.scale, border=border), note
    estimate = infer_gt_scale(left_image, right_image, values)
    return GroundTruth(scale=estimate.scale, border=border, inferred=True), estimate.note


def check_memory(config: MatchConfig, shape: tuple[int, ...], top: int, svc: Services) -> int:
    """The job's estimated peak memory (MiB, :func:`shared.memory.job_memory_mb`), refused
    (413) when it is above a worker process's budget on this host (a worker elsewhere checks
    against its own when the job starts)."""
    memory = job_memory_mb(config, shape[0], shape[1], top)
    try:
        check_fits(memory, worker_budget_mb(svc.settings))
    except MemoryBudgetError as error:
        raise AdmissionError(Refusal.TOO_LARGE, str(error)) from None
    return memory


# --- submission -----------------------------------------------------------------------------


def submit(form: JobForm, owner: str, svc: Services, users: UserStore) -> JobRecord:
    """Admit a job and queue it: the record as written (``state`` queued; a metered solver's
    ``pricing``, queued by its pricing task within its owner's budget)."""
    check_active_jobs(owner, svc)
    record, arrays = admit(form, owner, svc, users)
    dispatch(record, arrays, svc)
    return record


def admit(
    form: JobForm, owner: str, svc: Services, users: UserStore, batch: str | None = None
) -> tuple[JobRecord, dict[str, np.ndarray]]:
    """Every admission check of one job but the active-job cap: its record (of ``batch``, when
    one) and decoded arrays, not written yet."""
    settings = svc.settings
    config = parse_config(form.params)
    tags = parse_tags(form.tags)
    config = bounded_params(config, check_solver(config, svc))
    left_image, right_image = decode_pair(
        read_upload(form.left, "left", settings),
        read_upload(form.right, "right", settings),
        settings,
    )
    # the range decides the levels, hence the job's size: given, or resolved by the job's
    # first task (a metered job's by its pricing task, which checks its budget against the
    # estimate before it is queued: workers.pricing)
    top = config.max_disparity
    memory = check_memory(config, left_image.shape, top, svc) if isinstance(top, int) else None
    arrays = {"left": left_image, "right": right_image}
    warnings: list[str] = []
    truth = None
    if form.ground_truth is not None:
        stored = read_upload(form.ground_truth, "ground_truth", settings)
        arrays["ground_truth"] = decode_ground_truth(stored, left_image.shape[:2])
        truth, note = ground_truth_protocol(
            left_image,
            right_image,
            arrays["ground_truth"],
            form.gt_scale,
            form.gt_border,
            scale_of_format(stored[:64]),
        )
        warnings += [note] if note else []
    record = JobRecord(
        id=new_job_id(),
        state=JobState.PRICING if is_metered(config.solver) else JobState.QUEUED,
        owner=owner,
        config=config,
        width=left_image.shape[1],
        height=left_image.shape[0],
        label=one_line(form.label) or None,
        tags=tags,
        files=[display_name(upload.filename) for upload in (form.left, form.right)],
        warnings=warnings,
        ground_truth=truth,
        created_at=now(),
        levels_total=len(plan(config, top)) if isinstance(top, int) else 0,
        version=qhsm_version(),
        cameras=form.cameras,
        dispatched=False,
        memory_mb=memory,
        batch=batch,
    )
    return record, arrays


def keep_views(svc: Services, job_id: str, arrays: dict[str, np.ndarray]) -> None:
    """Keep the left view the web page shows beside the result (8-bit PNG); the ground truth
    is kept by :meth:`~workers.store.JobStore.create`, for the scoring and the error map."""
    view = np.rint(np.clip(arrays["left"], 0.0, 1.0) * 255).astype(np.uint8)
    svc.store.save_view(job_id, "left.png", cv2.imencode(".png", view)[1].tobytes())


def dispatch(record: JobRecord, arrays: dict[str, np.ndarray], svc: Services) -> None:
    """Write the job (under its owner's active-job cap: ``ActiveJobsCapError``) and send its
    first task: ``qhsm.start_job`` to the control queue, or a pricing job's ``qhsm.price_job``
    to the pricing queue; a job that could not be queued is removed again.

    Idempotent for the client: once the task is sent nothing raises (the submit answers 202
    and the job runs once); before, the error is answered (507 on a full disk) and the job never
    runs, even when its removal fails too: its record says its start was not sent
    (``dispatched`` False) and the watchdog fails it instead of starting it."""
    write(record, arrays, svc)
    try:
        send_first_task(record, svc)
    except BaseException:  # a full disk or Redis gone: the job was never queued
        with contextlib.suppress(Exception):
            svc.store.discard(record.id)
        raise
    started(record, svc)


def write(record: JobRecord, arrays: dict[str, np.ndarray], svc: Services) -> None:
    """Write the job and its views (under its owner's active-job cap: ``ActiveJobsCapError``),
    not started yet; removed again when that fails."""
    svc.store.create(record, arrays, cap=svc.settings.max_active_jobs_per_user)
    try:
        keep_views(svc, record.id, arrays)
    except BaseException:
        with contextlib.suppress(Exception):
            svc.store.discard(record.id)
        raise


def started(record: JobRecord, svc: Services) -> None:
    """Say in the record that the job's start was sent (its worker runs it regardless)."""
    try:
        svc.store.mark_dispatched(record.id)
    except Exception as error:  # the start is sent: its worker runs the job regardless
        log.warning("job %s: started, but its record could not say so: %s", record.id, error)


def send_first_task(record: JobRecord, svc: Services) -> None:
    """Send a written job's first task (:func:`workers.app.send_first_task`)."""
    first_task(svc.celery, svc.settings, record.id, pricing=record.state is JobState.PRICING)


# --- lookups --------------------------------------------------------------------------------


def find_job(job_id: str, svc: Services, principal: Principal) -> JobRecord:
    """The job, if the caller may see it (``JobNotFoundError`` otherwise: whether someone
    else's job exists is not told)."""
    record = svc.store.get(job_id)
    if record is None or not can_see(principal, record):
        raise JobNotFoundError(job_id, svc.settings.result_ttl_seconds)
    return record


def finished_result(
    job_id: str, svc: Services, principal: Principal
) -> tuple[JobRecord, np.ndarray]:
    """A succeeded job and its disparity (``JobStateError`` before, ``ExpiredError`` after
    its result expired)."""
    record = find_job(job_id, svc, principal)
    if record.state is not JobState.SUCCEEDED:
        hint = (
            f"poll GET /v1/jobs/{job_id} until its state is succeeded"
            if record.state in ACTIVE
            else "it has no result"
        )
        raise JobStateError(f"job {job_id} is {record.state.value}: {hint}")
    disparity = svc.store.load_result(job_id)
    if disparity is None:
        raise ExpiredError(job_id, "result")
    return record, disparity


def cancel(job_id: str, svc: Services, principal: Principal) -> JobRecord:
    """Cancel a pricing, queued or running job and stop its running tasks; a job cancelled
    already is returned as it is, a finished one refused (``JobStateError``)."""
    before = find_job(job_id, svc, principal)
    applied = svc.store.apply(job_id, JobRecord.cancelled, now())
    record = applied.record
    if record is None or not applied.changed:
        record = find_job(job_id, svc, principal)
        if record.state is not JobState.CANCELLED:
            raise JobStateError(
                f"job {job_id} already {record.state.value}; there is nothing to cancel"
            )
    if before.state is JobState.PRICING:  # its pricing task, queued or running
        revoke(svc.celery, [pricing_task_id(job_id)])
    stop_tasks(record, svc)
    return record


def stop_tasks(record: JobRecord, svc: Services) -> None:
    """Revoke the cancelled job's running solver tasks and kill the processes running them."""
    terminate_tasks(svc.celery, svc.store.running_tasks(record.id), record.config.solver)
