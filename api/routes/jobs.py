"""/v1/jobs: submit a stereo pair, poll it, download the disparity, cancel it, list jobs."""

from __future__ import annotations

import dataclasses
import io
import zipfile
from datetime import timedelta
from typing import Annotated, Any, Literal

import cv2
import numpy as np
from fastapi import APIRouter, File, Query, Request, UploadFile
from fastapi.responses import Response
from pydantic import Field

from api import job_service
from api.auth import can_see
from api.deps import Caller, CallerDep, PrincipalDep, Responses, ServicesDep, UploadViews
from api.errors import ExpiredError, JobNotFoundError, Refusal, ServiceError
from api.job_service import JobForm, find_job, finished_result
from api.responses import (
    NOT_FOUND,
    SCALE_HEADER,
    accepted,
    charged_seconds,
    display_max,
    links,
    summary_of,
    upload_route,
)
from api.schemas import JobCreated, JobPage, JobStatus
from api.uploads import GT_SCALE_RANGE, MAX_GT_BORDER, MAX_LABEL, MAX_TAGS, TAG, cameras_of
from api.users import UserStore
from shared import provenance_map
from shared.datasets.calibration import Calibration
from shared.depth import ply_bytes, point_cloud
from shared.images import DisparityFormatError, disparity_bytes, preview_png
from shared.solvers.meters.qpu_time import is_metered
from workers.arrays import npy
from workers.quota import LOCAL_USER
from workers.records import Cameras, GroundTruth, JobRecord, JobState

router = APIRouter(prefix="/jobs", tags=["jobs"])

DISPARITY_MEDIA = {
    "pfm": "image/x-portable-floatmap",
    "png": "image/png",
    "npy": "application/x-npy",
}
#: Largest listing offset (Redis indexes are 64-bit; far past any real job count).
MAX_OFFSET = 10**9
#: What else a job upload can be refused with (:func:`~api.responses.upload_route`).
REFUSED: Responses = {
    403: {"description": "QPU budget too small for the job's estimate"},
    429: {"description": "Too many of the user's jobs are queued or running"},
    422: {
        "description": "Invalid parameters (solver_params outside their range), sizes, or solver"
    },
}


def budget_warning(record: JobRecord, users: UserStore) -> list[str]:
    """A metered job's owner is told when their QPU budget runs low."""
    if not is_metered(record.config.solver):
        return []
    warning = users.ledger.status(record.owner or LOCAL_USER).warning
    return [warning] if warning else []


def status_of(record: JobRecord, caller: Caller) -> JobStatus:
    svc, _, users = caller
    chunks = svc.store.chunks(record.id)
    progress = svc.store.progress(record, chunks)
    return JobStatus(
        **{
            **JobStatus.fields_of(record, links(record), charged_seconds(record, users)),
            "progress": progress.model_dump(),
            "usage": svc.store.usage(chunks),
            "problem_ids": svc.store.problem_ids(chunks),
            "warnings": record.warnings + budget_warning(record, users),
            "expires_at": (
                record.finished_at + timedelta(seconds=svc.settings.result_ttl_seconds)
                if record.finished_at and not record.pinned
                else None
            ),
        }
    )


def _camera(name: str, description: str) -> Any:
    """:class:`Cameras`' field ``name`` as an optional form field: the core's bounds (one
    place for them), finite, described for the form."""
    bounds = {
        key: value
        for constraint in Cameras.model_fields[name].metadata
        for key, value in dataclasses.asdict(constraint).items()
    }
    return Field(None, allow_inf_nan=False, description=description, **bounds)


class JobUpload(UploadViews):
    """The form of POST /v1/jobs: the views and params, then the job's own fields."""

    ground_truth: UploadFile | None = Field(
        None, description="Left disparity ground truth (PNG/PGM/PFM/npy)"
    )
    gt_scale: float | None = Field(
        None,
        ge=GT_SCALE_RANGE[0],
        le=GT_SCALE_RANGE[1],
        allow_inf_nan=False,
        description="Stored value per disparity pixel (e.g. 1, 4, 16, 256); not given: "
        "inferred from the views, with a warning (422 when they do not tell)",
    )
    gt_border: int = Field(
        GroundTruth.model_fields["border"].default,
        ge=0,
        le=MAX_GT_BORDER,
        description="Ignored frame, pixels",
    )
    label: str | None = Field(
        None, max_length=MAX_LABEL, description="Your name for the job, shown in job lists"
    )
    focal: float | None = _camera("focal", "Focal length, px (with baseline: depth)")
    baseline: float | None = _camera(
        "baseline", "Camera baseline (with focal: depth and a point cloud in its unit)"
    )
    doffs: float | None = _camera("doffs", "cx(right) - cx(left), px (Middlebury's doffs)")
    calib: UploadFile | None = Field(
        None, description="Calibration file (Middlebury calib.txt or KITTI's): depth and PLY"
    )
    tags: str | None = Field(
        None,
        max_length=MAX_TAGS * 41,
        description=f"Comma-separated tags (at most {MAX_TAGS}: letters, digits, '.', '_', "
        "'-'); GET /v1/jobs?tag= lists the jobs with one",
    )

    def form(self) -> JobForm:
        """The job as submitted (its cameras read: a calibration file refused here is a 422)."""
        cameras = cameras_of(self.focal, self.baseline, self.doffs, self.calib)
        return JobForm(
            self.left, self.right, self.params, self.ground_truth, self.gt_scale,
            self.gt_border, self.label, cameras, self.tags,
        )  # fmt: skip


@upload_route(router, "", JobCreated, REFUSED)
def create_job(caller: CallerDep, upload: Annotated[JobUpload, File()]):
    """Queue a matching job; poll the ``Location`` it answers with."""
    record = job_service.submit(upload.form(), caller.principal.name, caller.svc, caller.users)
    body = JobCreated(
        id=record.id, state=record.state, links=links(record), warnings=record.warnings
    )
    return accepted(body, body.links.self)


@router.get("", response_model=JobPage)
def list_jobs(
    request: Request,
    caller: CallerDep,
    offset: Annotated[int, Query(ge=0, le=MAX_OFFSET)] = 0,
    limit: Annotated[int, Query(ge=1, le=100)] = 20,
    tag: Annotated[
        str | None, Query(pattern=TAG.pattern, description="Only the jobs with this tag")
    ] = None,
):
    """Your jobs, newest first (admins: everyone's); ``?tag=`` only those with the tag."""
    svc, principal, users = caller
    owner = None if principal.admin else principal.name
    records, total = svc.store.list_jobs(offset, limit, owner=owner, tag=tag)
    items = [summary_of(r, users) for r in records if can_see(principal, r)]
    following = offset + limit
    more = f"&tag={tag}" if tag else ""
    next_url = f"/v1/jobs?offset={following}&limit={limit}{more}" if following < total else None
    return JobPage(items=items, total=total, offset=offset, limit=limit, next=next_url)


@router.get("/{job_id}", response_model=JobStatus, responses=NOT_FOUND)
def get_job(job_id: str, caller: CallerDep):
    """State, progress, per-level timing, solver usage, metrics, warnings and errors of a
    job."""
    return status_of(find_job(job_id, caller.svc, caller.principal), caller)


@router.delete(
    "/{job_id}",
    response_model=JobStatus,
    responses={**NOT_FOUND, 409: {"description": "The job already finished"}},
)
def cancel_job(job_id: str, caller: CallerDep):
    """Cancel a queued or running job: its running solver tasks are terminated and bundles
    not solved yet are not solved."""
    return status_of(job_service.cancel(job_id, caller.svc, caller.principal), caller)


@router.get(
    "/{job_id}/disparity",
    responses={
        **NOT_FOUND,
        409: {"description": "Not finished"},
        422: {"description": "PNG asked for a map above 255.996 px"},
        200: {"content": {}},
    },
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
    try:
        data = disparity_bytes(disparity, format)
    except DisparityFormatError as error:
        raise ServiceError(Refusal.INVALID, str(error)) from None
    return Response(
        data,
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


def finished_map(job_id: str, name: str, caller: Caller) -> tuple[JobRecord, np.ndarray]:
    """A succeeded job's map saved beside its result (404 when the job has none)."""
    svc, principal, _ = caller
    record, _ = finished_result(job_id, svc, principal)
    if name not in record.maps:
        raise ServiceError(
            Refusal.NOT_FOUND,
            f"job {job_id} has no {name} map (the run had no left-right check or its cost "
            "volume was too large)",
        )
    values = svc.store.load_map(job_id, name)
    if values is None:
        raise ExpiredError(job_id, f"{name} map")
    return record, values


def validity_png(valid: np.ndarray) -> bytes:
    """The validity map as `qhsm match` writes it: 8-bit PNG, 255 confirmed, 0 filled."""
    return cv2.imencode(".png", np.where(valid, 255, 0).astype(np.uint8))[1].tobytes()


def attachment(data: bytes, media: str, filename: str) -> Response:
    return Response(
        data,
        media_type=media,
        headers={"Content-Disposition": f'attachment; filename="{filename}"'},
    )


#: How a float map (confidence, depth) is served: PFM or npy.
FloatFormat = Literal["pfm", "npy"]


def float_map(values: np.ndarray, job_id: str, name: str, format: FloatFormat) -> Response:
    """A float map as the attachment ``<job>.<name>.<format>``."""
    return attachment(
        disparity_bytes(values, format), DISPARITY_MEDIA[format], f"{job_id}.{name}.{format}"
    )


MAP_RESPONSES: dict = {
    **NOT_FOUND,
    409: {"description": "Not finished"},
    410: {"description": "Expired"},
    200: {"content": {}},
}


@router.get("/{job_id}/validity.png", responses=MAP_RESPONSES, response_class=Response)
def get_validity(job_id: str, caller: CallerDep):
    """Where the left-right check confirmed the disparity (255) before holes were filled (0)."""
    _, valid = finished_map(job_id, "validity", caller)
    image = np.where(valid, 255, 0).astype(np.uint8)
    return attachment(cv2.imencode(".png", image)[1].tobytes(), "image/png", f"{job_id}.valid.png")


@router.get("/{job_id}/confidence", responses=MAP_RESPONSES, response_class=Response)
def get_confidence(job_id: str, caller: CallerDep, format: FloatFormat = "pfm"):
    """Confidence of each disparity in [0, 1] (the cost margin; 0 where the check failed)."""
    _, confidence = finished_map(job_id, "confidence", caller)
    return float_map(confidence, job_id, "confidence", format)


@router.get("/{job_id}/provenance", responses=MAP_RESPONSES, response_class=Response)
def get_provenance(job_id: str, caller: CallerDep, format: Literal["png", "npy"] = "png"):
    """Which stage decided each pixel: a colour PNG, or the uint8 codes as npy (the legend:
    ``GET /v1/provenance-legend``; the pixels per stage are the status' ``provenance_counts``)."""
    _, stages = finished_map(job_id, "provenance", caller)
    data = provenance_map.png(stages) if format == "png" else npy(stages)
    media = "image/png" if format == "png" else DISPARITY_MEDIA["npy"]
    return attachment(data, media, f"{job_id}.provenance.{format}")


def job_calibration(record: JobRecord) -> Calibration:
    if record.cameras is None:
        raise ServiceError(
            Refusal.NOT_FOUND,
            f"job {record.id} was submitted without cameras: submit with focal and baseline "
            "for its depth and point cloud",
        )
    return record.cameras.calibration(record.width, record.height)


@router.get("/{job_id}/depth", responses=MAP_RESPONSES, response_class=Response)
def get_depth(job_id: str, caller: CallerDep, format: FloatFormat = "pfm"):
    """Depth Z = focal x baseline / (d + doffs) in the baseline's unit; NaN: no depth."""
    record, disparity = finished_result(job_id, caller.svc, caller.principal)
    return float_map(job_calibration(record).depth(disparity), job_id, "depth", format)


@router.get("/{job_id}/points.ply", responses=MAP_RESPONSES, response_class=Response)
def get_points(job_id: str, svc: ServicesDep, principal: PrincipalDep):
    """The pixels with a depth (and a confirmed disparity, where the job has the validity map)
    as a coloured binary PLY (Open3D, MeshLab, CloudCompare read it)."""
    record, disparity = finished_result(job_id, svc, principal)
    calibration = job_calibration(record)
    left = svc.store.load_view(job_id, "left.png")
    decoded = None if left is None else cv2.imdecode(np.frombuffer(left, np.uint8), -1)
    image = None if decoded is None else decoded.astype(np.float32) / 255.0
    valid = svc.store.load_map(job_id, "validity") if "validity" in record.maps else None
    points, colours = point_cloud(disparity, calibration, image, valid)
    return attachment(ply_bytes(points, colours), "application/octet-stream", f"{job_id}.ply")


def pin(job_id: str, pinned: bool, caller: Caller) -> JobRecord:
    svc, principal, _ = caller
    find_job(job_id, svc, principal)
    record = svc.store.pin(job_id, pinned)
    if record is None:  # expired between the two reads
        raise JobNotFoundError(job_id, svc.settings.result_ttl_seconds)
    return record


@router.post("/{job_id}/pin", response_model=JobStatus, responses=NOT_FOUND)
def pin_job(job_id: str, caller: CallerDep):
    """Keep the job (record, result, maps, views) past the retention until it is unpinned."""
    return status_of(pin(job_id, True, caller), caller)


@router.delete("/{job_id}/pin", response_model=JobStatus, responses=NOT_FOUND)
def unpin_job(job_id: str, caller: CallerDep):
    """Let the job expire again: ``QHSM_RESULT_TTL_SECONDS`` after it finished (at once when
    that has passed)."""
    return status_of(pin(job_id, False, caller), caller)


@router.get(
    "/{job_id}/export",
    responses={**NOT_FOUND, 200: {"content": {"application/zip": {}}}},
    response_class=Response,
)
def export_job(job_id: str, caller: CallerDep):
    """The job in one zip: ``job.json`` (its status: config, version, levels, usage, metrics,
    charge) and the files it still has: ``disparity.pfm``, ``validity.png``,
    ``confidence.pfm``, ``provenance.png``, ``left.png``."""
    svc, principal, _ = caller
    record = find_job(job_id, svc, principal)
    files = {"job.json": status_of(record, caller).model_dump_json(indent=2).encode()}
    disparity = svc.store.load_result(job_id) if record.state is JobState.SUCCEEDED else None
    if disparity is not None:
        files["disparity.pfm"] = disparity_bytes(disparity, "pfm")
        if (
            "validity" in record.maps
            and (valid := svc.store.load_map(job_id, "validity")) is not None
        ):
            files["validity.png"] = validity_png(valid)
        if (
            "confidence" in record.maps
            and (confidence := svc.store.load_map(job_id, "confidence")) is not None
        ):
            files["confidence.pfm"] = disparity_bytes(confidence, "pfm")
        if (
            "provenance" in record.maps
            and (stages := svc.store.load_map(job_id, "provenance")) is not None
        ):
            files["provenance.png"] = provenance_map.png(stages)
    if (left := svc.store.load_view(job_id, "left.png")) is not None:
        files["left.png"] = left
    stream = io.BytesIO()
    with zipfile.ZipFile(stream, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data in files.items():
            archive.writestr(f"{job_id}/{name}", data)
    return attachment(stream.getvalue(), "application/zip", f"{job_id}.zip")
