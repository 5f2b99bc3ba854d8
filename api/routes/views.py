"""Images the web page shows: thumbnails of the files a user picks (any accepted format, as PNG,
which every browser shows: PPM/PGM, PFM and TIFF are not), and beside a result the left view,
the error map against the ground truth, the difference from another job, and the colour bars of
the colour-mapped images (their scale in ``X-Scale-Max``)."""

from __future__ import annotations

from typing import Annotated, Literal

import cv2
import numpy as np
from fastapi import APIRouter, File, Query, UploadFile
from fastapi.responses import Response

from api.auth import Principal
from api.deps import PrincipalDep, Responses, Services, ServicesDep
from api.errors import ExpiredError, Refusal, ServiceError
from api.job_service import find_job, finished_result
from api.responses import NOT_FOUND, SCALE_HEADER, UPLOAD_ERRORS, display_max
from api.schemas import LegendEntry
from api.uploads import decode_view, read_upload
from shared import provenance_map
from shared.images import colorize
from shared.metrics import BAD_PIXEL_THRESHOLD, Truth

router = APIRouter(prefix="/jobs", tags=["jobs"])
thumbnails = APIRouter(tags=["web"])

#: Errors at or above this many pixels get the top colour of the error map.
ERROR_MAP_MAX = 4 * BAD_PIXEL_THRESHOLD
#: Colour (BGR) of the pixels the error map does not evaluate.
NOT_EVALUATED = (128, 128, 128)
PNG: Responses = {200: {"content": {"image/png": {}}}}
#: Longest side of a thumbnail, pixels.
THUMBNAIL_SIDE = 320
#: Response header of the difference map: share of the pixels (%) that differ by more than the
#: bad-pixel threshold.
DIFFERING_HEADER = "X-Differing-Percent"


@thumbnails.get("/provenance-legend", response_model=list[LegendEntry])
def get_provenance_legend():
    """The provenance map's codes: each one's name, colour and what decided its pixels."""
    return provenance_map.legend()


def png(image: np.ndarray, top: float | None = None) -> Response:
    headers = {SCALE_HEADER: f"{top:g}"} if top is not None else None
    return Response(
        cv2.imencode(".png", image)[1].tobytes(), media_type="image/png", headers=headers
    )


@router.get("/{job_id}/left.png", response_class=Response, responses={**NOT_FOUND, **PNG})
def get_left(job_id: str, svc: ServicesDep, principal: PrincipalDep):
    """The left view as the job received it (8-bit)."""
    find_job(job_id, svc, principal)
    data = svc.store.load_view(job_id, "left.png")
    if data is None:
        raise ExpiredError(job_id, "left view")
    return Response(data, media_type="image/png")


def errors_of(job_id: str, svc: Services, principal: Principal) -> np.ndarray:
    """|disparity - ground truth| in pixels, NaN where not evaluated."""
    record, disparity = finished_result(job_id, svc, principal)
    if record.ground_truth is None:
        raise ServiceError(
            Refusal.NOT_FOUND,
            f"job {job_id} was submitted without a ground truth, so it has no error map",
        )
    truth = svc.store.load_ground_truth(job_id)
    if truth is None:
        raise ExpiredError(job_id, "ground truth")
    scored = Truth(truth, record.ground_truth.scale, record.ground_truth.border)
    return scored.error_map(disparity)


@router.get(
    "/{job_id}/error.png",
    response_class=Response,
    responses={**NOT_FOUND, 409: {"description": "Not finished"}, **PNG},
)
def get_error_map(job_id: str, svc: ServicesDep, principal: PrincipalDep):
    """|disparity - ground truth| colour-mapped from 0 to ``X-Scale-Max`` px; grey: not
    evaluated (unknown ground truth or the border)."""
    errors = errors_of(job_id, svc, principal)
    image = colorize(np.nan_to_num(errors, nan=0.0), ERROR_MAP_MAX)
    image[np.isnan(errors)] = NOT_EVALUATED
    return png(image, ERROR_MAP_MAX)


@router.get(
    "/{job_id}/colorbar.png",
    response_class=Response,
    responses={**NOT_FOUND, 409: {"description": "Not finished"}, **PNG},
)
def get_colorbar(
    job_id: str,
    svc: ServicesDep,
    principal: PrincipalDep,
    kind: Annotated[Literal["disparity", "error"], Query(alias="map")] = "disparity",
):
    """The colour bar of the job's disparity preview or error map, left (0) to right
    (``X-Scale-Max`` pixels)."""
    record, disparity = finished_result(job_id, svc, principal)
    top = display_max(record, disparity) if kind == "disparity" else ERROR_MAP_MAX
    ramp = np.tile(np.linspace(0.0, top, 256, dtype=np.float32), (12, 1))
    return png(colorize(ramp, top), top)


@router.get(
    "/{job_id}/difference.png",
    response_class=Response,
    responses={
        **NOT_FOUND,
        409: {"description": "One of the jobs is not finished"},
        422: {"description": "The jobs' maps differ in size"},
        **PNG,
    },
)
def get_difference(
    job_id: str,
    svc: ServicesDep,
    principal: PrincipalDep,
    other: Annotated[str, Query(alias="with", description="The other job's id")],
):
    """|disparity - the other job's disparity| colour-mapped from 0 to ``X-Scale-Max`` px, as
    the error map; ``X-Differing-Percent``: pixels that differ by more than 1 px."""
    _, first = finished_result(job_id, svc, principal)
    _, second = finished_result(other, svc, principal)
    if first.shape != second.shape:
        raise ServiceError(
            Refusal.INVALID,
            f"job {job_id} is {first.shape[1]}x{first.shape[0]} and job {other} is "
            f"{second.shape[1]}x{second.shape[0]}: only maps of one size can be compared",
        )
    difference = np.abs(first.astype(np.float32) - second.astype(np.float32))
    response = png(colorize(difference, ERROR_MAP_MAX), ERROR_MAP_MAX)
    differing = 100.0 * float(np.mean(difference > BAD_PIXEL_THRESHOLD))
    response.headers[DIFFERING_HEADER] = f"{differing:.2f}"
    return response


@thumbnails.post("/thumbnail", response_class=Response, responses={**UPLOAD_ERRORS, **PNG})
def make_thumbnail(
    svc: ServicesDep,
    image: Annotated[UploadFile, File(description="A view in any accepted format")],
):
    """A PNG of at most 320 px a side of an image in any format a job accepts (PNG, PPM/PGM,
    JPEG, PFM, TIFF, BMP), for the submit form's previews; nothing is stored."""
    view = decode_view(read_upload(image, "image", svc.settings), "image", svc.settings)
    height, width = view.shape[:2]
    factor = THUMBNAIL_SIDE / max(height, width)
    if factor < 1:
        size = (max(1, round(width * factor)), max(1, round(height * factor)))
        view = cv2.resize(view, size, interpolation=cv2.INTER_AREA)
    return png(np.rint(np.clip(view, 0.0, 1.0) * 255).astype(np.uint8))
