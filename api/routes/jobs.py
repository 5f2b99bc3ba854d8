"""/v1/jobs: submit a stereo pair, poll it, download the disparity, cancel it, list jobs."""

from __future__ import annotations

import contextlib
from typing import Annotated, Literal

import cv2
import numpy as np
from fastapi import APIRouter, File, Form, HTTPException, Query, Request, UploadFile
from fastapi import status as http
from fastapi.responses import JSONResponse, Response

from api.auth import Principal, can_see
from api.deps import PrincipalDep, Responses, Services, ServicesDep, UsersDep, load_solver
from api.schemas import JobCreated, JobPage, JobStatus, JobSummary, Links
from api.uploads import (
    MAX_LABEL,
    UploadError,
    decode_ground_truth,
    decode_pair,
    display_name,
    one_line,
    parse_config,
    read_upload,
)
from api.users import UserStore
from shared.bundle_plan import bundle_width_setting
from shared.config import MatchConfig
from shared.disparity_range import RangeEstimate, resolve_max_disparity
from shared.ground_truth import ScaleNotInferredError, infer_gt_scale
from shared.images import disparity_bytes, preview_png
from shared.pipeline import match_views
from shared.pyramid import plan
from shared.residual import job_residual
from shared.solvers import InvalidSolverParamsError, UnknownSolver, check_params
from shared.solvers.embedding_cache import EmbeddingCache
from shared.solvers.qpu_time import JobEstimate, is_metered, job_seconds
from shared.solvers.registry import queue_of
from workers import embedding_store
from workers.app import START_JOB, terminate_tasks
from workers.quota import LOCAL_USER, QuotaExceeded
from workers.records import ACTIVE, GroundTruth, JobRecord, JobState, new_job_id, now
from workers.store import ActiveJobsCapError

router = APIRouter(prefix="/v1/jobs", tags=["jobs"])

DISPARITY_MEDIA = {
    "pfm": "image/x-portable-floatmap",
    "png": "image/png",
    "npy": "application/x-npy",
}
#: A ground truth's scale: stored value per disparity pixel. Outside this range the scaled
#: errors lose all precision or overflow (an infinite RMSE).
GT_SCALE_RANGE = (1e-3, 1e6)
#: Widest ignored frame, pixels (above any image side the pixel limit allows evaluating).
MAX_GT_BORDER = 10_000
#: Largest listing offset (Redis indexes are 64-bit; far past any real job count).
MAX_OFFSET = 10**9
NOT_FOUND: Responses = {http.HTTP_404_NOT_FOUND: {"description": "No such job (or it expired)"}}
#: Errors of the upload form (POST /v1/jobs and /v1/estimate) for the OpenAPI docs.
UPLOAD_ERRORS: Responses = {
    400: {"description": "params is not JSON"},
    413: {"description": "File or image too large"},
    415: {"description": "Not a supported image format"},
}


#: Response header of colour-mapped images: the value (pixels) the top colour stands for.
SCALE_HEADER = "X-Scale-Max"


def display_max(record: JobRecord, disparity: np.ndarray) -> float:
    """The disparity the preview's top colour stands for: the job's range, else the map's max."""
    top = record.disparity_range["max_disparity"] if record.disparity_range else None
    if isinstance(top, int | float) and top > 0:
        return float(top)
    return max(float(np.max(disparity)), 1.0)


def keep_views(svc: Services, job_id: str, arrays: dict[str, np.ndarray]) -> None:
    """Keep the left view the web page shows beside the result (8-bit PNG); the ground truth
    is kept by :meth:`~workers.store.JobStore.create`, for the scoring and the error map."""
    view = np.rint(np.clip(arrays["left"], 0.0, 1.0) * 255).astype(np.uint8)
    svc.store.save_view(job_id, "left.png", cv2.imencode(".png", view)[1].tobytes())


def links(job_id: str) -> Links:
    base = f"/v1/jobs/{job_id}"
    return Links(self=base, disparity=f"{base}/disparity?format=pfm", preview=f"{base}/preview.png")


def charged_seconds(record: JobRecord, users: UserStore) -> float | None:
    """QPU (hybrid: charge) seconds the job's owner was charged for it; None when the job's
    solver is not metered."""
    if not is_metered(record.config.solver):
        return None
    return users.ledger.job_usage(record.owner or LOCAL_USER, record.id).seconds


def summary_of(record: JobRecord, users: UserStore) -> JobSummary:
    return JobSummary(
        **JobSummary.fields_of(record, links(record.id), charged_seconds(record, users))
    )


def status_of(record: JobRecord, svc: Services, users: UserStore) -> JobStatus:
    chunks = svc.store.chunks(record.id)
    progress = svc.store.progress(record, chunks)
    return JobStatus(
        **JobSummary.fields_of(record, links(record.id), charged_seconds(record, users)),
        progress=progress.model_dump(),
        levels=record.levels,
        usage=svc.store.usage(chunks),
        error=record.error,
        warnings=record.warnings,
        ground_truth=record.ground_truth,
        config=record.config,
        disparity_range=record.disparity_range,
    )


def find_job(job_id: str, svc: Services, principal: Principal) -> JobRecord:
    record = svc.store.get(job_id)
    if record is None or not can_see(principal, record):
        raise HTTPException(
            http.HTTP_404_NOT_FOUND,
            f"no job {job_id!r}: it never existed or its results expired "
            f"(results are kept {svc.settings.result_ttl_seconds} s)",
        )
    return record


def check_solver_name(config: MatchConfig):
    """422 unless the solver is registered; returns its availability here."""
    try:
        _, availability = load_solver(config.solver)
    except UnknownSolver as error:
        raise UploadError(http.HTTP_422_UNPROCESSABLE_CONTENT, f"params: {error}") from None
    try:
        bundle_width_setting(config)
    except ValueError as error:
        raise UploadError(http.HTTP_422_UNPROCESSABLE_CONTENT, f"params: {error}") from None
    return availability


def check_solver(config: MatchConfig, svc: Services) -> None:
    """The solver must exist, and run here or have a worker consuming its queue."""
    availability = check_solver_name(config)
    if availability.ok:
        return
    consumers = svc.queues.consumers() or {}
    queue = queue_of(config.solver)
    if consumers.get(queue):
        return
    raise UploadError(
        http.HTTP_422_UNPROCESSABLE_CONTENT,
        f"solver {config.solver!r} is not available: {availability.reason}; and no worker "
        f"consumes its queue (start one where it can run: "
        f"celery -A workers worker -Q {queue})",
    )


def bounded_params(config: MatchConfig) -> MatchConfig:
    """422 unless every solver parameter is inside the solver's schema (the registry's)."""
    try:
        params = check_params(config.solver, config.solver_params)
    except InvalidSolverParamsError as error:
        raise UploadError(http.HTTP_422_UNPROCESSABLE_CONTENT, f"params: {error}") from None
    return config.model_copy(update={"solver_params": params})


def too_many_jobs(name: str, active: int, cap: int) -> HTTPException:
    """The 429 of a user at the per-user cap of jobs in flight."""
    return HTTPException(
        http.HTTP_429_TOO_MANY_REQUESTS,
        f"user {name!r} already has {active} jobs queued or running, the limit per user "
        f"(QHSM_MAX_ACTIVE_JOBS_PER_USER={cap}); wait for one to finish or cancel one "
        "(DELETE /v1/jobs/{id}), then submit again",
    )


def check_active_jobs(principal: Principal, svc: Services) -> None:
    """429 at once, before the uploads are read, when the user already has
    ``Settings.max_active_jobs_per_user`` jobs in flight (the cap is taken atomically when the
    job is written: :meth:`workers.store.JobStore.create`)."""
    cap = svc.settings.max_active_jobs_per_user
    if not cap:  # 0 or None: no limit
        return
    active = svc.store.active_jobs(principal.name)
    if active >= cap:
        raise too_many_jobs(principal.name, active, cap)


def disparity_range_of(left_image, right_image, config: MatchConfig) -> RangeEstimate:
    """The job's disparity range: it decides the levels, hence the job's size."""
    return resolve_max_disparity(
        *match_views(left_image, right_image, config), config.max_disparity
    )


def range_at_submit(left_image, right_image, config: MatchConfig) -> RangeEstimate | None:
    """The range, resolved in the request only when the QPU budget check needs it: a metered
    solver with ``max_disparity: auto`` (the estimate of its QPU time depends on it, and the
    job is refused before it is queued when it does not fit). Every other job's range estimate
    and views check run in its first control task (``workers.orchestration.start_job``), off
    the HTTP request; their result appears in the job's status once it has started."""
    if is_metered(config.solver) and not isinstance(config.max_disparity, int):
        return disparity_range_of(left_image, right_image, config)
    return None


def ground_truth_protocol(
    left_image: np.ndarray,
    right_image: np.ndarray,
    values: np.ndarray,
    scale: float | None,
    border: int,
) -> tuple[GroundTruth, str]:
    """How an uploaded ground truth is scored: the given scale, else one inferred from the
    views, with the note that says so; 422 (asking for ``gt_scale``) when they do not tell."""
    if scale is not None:
        return GroundTruth(scale=scale, border=border), ""
    try:
        estimate = infer_gt_scale(left_image, right_image, values)
    except ScaleNotInferredError as error:
        raise UploadError(http.HTTP_422_UNPROCESSABLE_CONTENT, f"gt_scale: {error}") from None
    return GroundTruth(scale=estimate.scale, border=border, inferred=True), estimate.note


def estimate_job(
    config: MatchConfig, left_image, right_image, max_disparity: int, svc: Services
) -> JobEstimate:
    """The job's metered time, with the actual embeddings the workers have already found
    (shared through Redis) for bundle shapes they have met and what roof duality leaves of the
    bundles (surveyed on the pair); 422 for unusable solver_params."""
    cache = EmbeddingCache(embedding_store.for_settings(svc.settings, svc.store.redis))
    try:
        residual = job_residual(config, left_image, right_image, max_disparity, cache)
        return job_seconds(config, left_image.shape[:2], max_disparity, cache, residual)
    except (TypeError, ValueError, KeyError) as error:
        raise UploadError(
            http.HTTP_422_UNPROCESSABLE_CONTENT,
            f"params: cannot estimate the job's QPU time from solver_params ({error})",
        ) from None


def check_budget(
    config: MatchConfig,
    left_image,
    right_image,
    max_disparity: int,
    principal: Principal,
    users: UserStore,
    svc: Services,
) -> None:
    """403 when a metered job's estimate exceeds what is left of its owner's QPU budget."""
    if not is_metered(config.solver):
        return
    estimate = estimate_job(config, left_image, right_image, max_disparity, svc)
    try:
        users.ledger.check(
            principal.name, estimate.seconds, f"this job ({estimate.bundles} bundles)"
        )
    except QuotaExceeded as error:
        raise HTTPException(http.HTTP_403_FORBIDDEN, str(error)) from None


@router.post(
    "",
    status_code=http.HTTP_202_ACCEPTED,
    response_model=JobCreated,
    responses={
        **UPLOAD_ERRORS,
        403: {"description": "QPU budget too small for the job's estimate"},
        429: {"description": "Too many of the user's jobs are queued or running"},
        422: {
            "description": "Invalid parameters (solver_params outside their range), sizes, or "
            "solver"
        },
    },
)
def create_job(
    svc: ServicesDep,
    principal: PrincipalDep,
    users: UsersDep,
    left: Annotated[UploadFile, File(description="Left view (PNG, PPM/PGM, JPEG, PFM, TIFF)")],
    right: Annotated[UploadFile, File(description="Right view, same size")],
    params: Annotated[
        str | None, Form(description='MatchConfig fields as JSON, e.g. {"solver": "sa"}')
    ] = None,
    ground_truth: Annotated[
        UploadFile | None, File(description="Left disparity ground truth (PNG/PGM/PFM/npy)")
    ] = None,
    gt_scale: Annotated[
        float | None,
        Form(
            ge=GT_SCALE_RANGE[0],
            le=GT_SCALE_RANGE[1],
            allow_inf_nan=False,
            description="Stored value per disparity pixel (e.g. 1, 4, 16, 256); not given: "
            "inferred from the views, with a warning (422 when they do not tell)",
        ),
    ] = None,
    gt_border: Annotated[
        int, Form(ge=0, le=MAX_GT_BORDER, description="Ignored frame, pixels")
    ] = GroundTruth.model_fields["border"].default,
    label: Annotated[
        str | None,
        Form(max_length=MAX_LABEL, description="Your name for the job, shown in job lists"),
    ] = None,
):
    """Queue a matching job; poll the ``Location`` it answers with."""
    settings = svc.settings
    check_active_jobs(principal, svc)
    config = parse_config(params)
    check_solver(config, svc)
    config = bounded_params(config)
    left_image, right_image = decode_pair(
        read_upload(left, "left", settings), read_upload(right, "right", settings), settings
    )
    # the range decides the levels, hence the job's size: given, resolved here for a metered
    # solver's budget, or else resolved once by the job's first control task
    disparity_range = range_at_submit(left_image, right_image, config)
    top = disparity_range.max_disparity if disparity_range else config.max_disparity
    if isinstance(top, int):
        check_budget(config, left_image, right_image, top, principal, users, svc)
    arrays = {"left": left_image, "right": right_image}
    warnings = [disparity_range.warning] if disparity_range and disparity_range.warning else []
    truth = None
    if ground_truth is not None:
        arrays["ground_truth"] = decode_ground_truth(
            read_upload(ground_truth, "ground_truth", settings), left_image.shape[:2]
        )
        truth, note = ground_truth_protocol(
            left_image, right_image, arrays["ground_truth"], gt_scale, gt_border
        )
        warnings += [note] if note else []
    record = JobRecord(
        id=new_job_id(),
        owner=principal.name,
        config=config,
        width=left_image.shape[1],
        height=left_image.shape[0],
        label=one_line(label) or None,
        files=[display_name(upload.filename) for upload in (left, right)],
        warnings=warnings,
        ground_truth=truth,
        created_at=now(),
        disparity_range=disparity_range.as_dict() if disparity_range else None,
        levels_total=len(plan(config, top)) if isinstance(top, int) else 0,
    )
    try:
        svc.store.create(record, arrays, cap=settings.max_active_jobs_per_user)
    except ActiveJobsCapError as full:
        raise too_many_jobs(principal.name, full.active, full.cap) from None
    try:
        keep_views(svc, record.id, arrays)
        svc.celery.send_task(START_JOB, args=(record.id,), queue=settings.control_queue)
    except BaseException:  # a full disk or Redis gone: the job was never queued
        with contextlib.suppress(Exception):
            svc.store.discard(record.id)
        raise
    body = JobCreated(
        id=record.id, state=record.state, links=links(record.id), warnings=record.warnings
    )
    return JSONResponse(
        body.model_dump(mode="json"),
        status_code=http.HTTP_202_ACCEPTED,
        headers={"Location": body.links.self},
    )


@router.get("", response_model=JobPage)
def list_jobs(
    request: Request,
    svc: ServicesDep,
    principal: PrincipalDep,
    users: UsersDep,
    offset: Annotated[int, Query(ge=0, le=MAX_OFFSET)] = 0,
    limit: Annotated[int, Query(ge=1, le=100)] = 20,
):
    """Your jobs, newest first (admins: everyone's)."""
    owner = None if principal.admin else principal.name
    records, total = svc.store.list_jobs(offset, limit, owner=owner)
    items = [summary_of(r, users) for r in records if can_see(principal, r)]
    following = offset + limit
    next_url = f"/v1/jobs?offset={following}&limit={limit}" if following < total else None
    return JobPage(items=items, total=total, offset=offset, limit=limit, next=next_url)


@router.get("/{job_id}", response_model=JobStatus, responses=NOT_FOUND)
def get_job(job_id: str, svc: ServicesDep, principal: PrincipalDep, users: UsersDep):
    """State, progress, per-level timing, solver usage, metrics, warnings and errors of a
    job."""
    return status_of(find_job(job_id, svc, principal), svc, users)


@router.delete(
    "/{job_id}",
    response_model=JobStatus,
    responses={**NOT_FOUND, 409: {"description": "The job already finished"}},
)
def cancel_job(job_id: str, svc: ServicesDep, principal: PrincipalDep, users: UsersDep):
    """Cancel a queued or running job: its running solver tasks are terminated and bundles
    not solved yet are not solved."""
    record = find_job(job_id, svc, principal)
    moved = svc.store.transition(job_id, JobState.CANCELLED, ACTIVE)
    if moved is None:
        record = find_job(job_id, svc, principal)
        if record.state is not JobState.CANCELLED:
            raise HTTPException(
                http.HTTP_409_CONFLICT,
                f"job {job_id} already {record.state.value}; there is nothing to cancel",
            )
    else:
        record = moved
    stop_tasks(record, svc)
    return status_of(record, svc, users)


def stop_tasks(record: JobRecord, svc: Services) -> None:
    """Revoke the cancelled job's running solver tasks and kill the processes running them."""
    terminate_tasks(svc.celery, svc.store.running_tasks(record.id), record.config.solver)


def finished_result(job_id: str, svc: Services, principal: Principal):
    record = find_job(job_id, svc, principal)
    if record.state is not JobState.SUCCEEDED:
        hint = (
            f"poll GET /v1/jobs/{job_id} until its state is succeeded"
            if record.state in ACTIVE
            else "it has no result"
        )
        raise HTTPException(http.HTTP_409_CONFLICT, f"job {job_id} is {record.state.value}: {hint}")
    disparity = svc.store.load_result(job_id)
    if disparity is None:
        raise HTTPException(http.HTTP_410_GONE, f"the result of job {job_id} has expired")
    return record, disparity


@router.get(
    "/{job_id}/disparity",
    responses={**NOT_FOUND, 409: {"description": "Not finished"}, 200: {"content": {}}},
    response_class=Response,
)
def get_disparity(
    job_id: str,
    svc: ServicesDep,
    principal: PrincipalDep,
    format: Literal["pfm", "png", "npy"] = "pfm",
):
    """Left-view disparity at full resolution: PFM (float32), 16-bit PNG (x256) or .npy."""
    _, disparity = finished_result(job_id, svc, principal)
    return Response(
        disparity_bytes(disparity, format),
        media_type=DISPARITY_MEDIA[format],
        headers={"Content-Disposition": f'attachment; filename="{job_id}.{format}"'},
    )


@router.get(
    "/{job_id}/preview.png",
    responses={**NOT_FOUND, 409: {"description": "Not finished"}, 200: {"content": {}}},
    response_class=Response,
)
def get_preview(job_id: str, svc: ServicesDep, principal: PrincipalDep):
    """Colour-mapped disparity (near = warm) for a quick look; 0 to ``X-Scale-Max`` pixels."""
    record, disparity = finished_result(job_id, svc, principal)
    top = display_max(record, disparity)
    return Response(
        preview_png(disparity, top), media_type="image/png", headers={SCALE_HEADER: f"{top:g}"}
    )
