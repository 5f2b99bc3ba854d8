"""What several routes answer alike: the OpenAPI error responses they share, the colour scale
of the images they draw and a job's summary with its links (job lists, batches). Routes import
this module, never each other."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from fastapi import APIRouter
from fastapi import status as http
from fastapi.responses import JSONResponse
from pydantic import BaseModel

from api.deps import Responses
from api.schemas import JobSummary, Links
from api.users import UserStore
from shared.solvers.meters.qpu_time import is_metered
from workers.quota import LOCAL_USER
from workers.records import JobRecord, JobState

NOT_FOUND: Responses = {http.HTTP_404_NOT_FOUND: {"description": "No such job (or it expired)"}}
#: Errors of the upload form (POST /v1/jobs, /v1/estimate and /v1/batches) for the OpenAPI docs.
UPLOAD_ERRORS: Responses = {
    400: {"description": "params is not JSON"},
    413: {"description": "File or image too large"},
    415: {"description": "Not a supported image format"},
}


def upload_route(
    router: APIRouter, path: str, model: type, errors: Responses
) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """``POST path`` taking uploaded views as work for a worker: answered 202 with ``model``,
    documented with the upload form's errors (:data:`UPLOAD_ERRORS`) and the route's own."""
    return router.post(
        path,
        status_code=http.HTTP_202_ACCEPTED,
        response_model=model,
        responses={**UPLOAD_ERRORS, **errors},
    )


def accepted(body: BaseModel, location: str) -> JSONResponse:
    """An upload route's answer: 202 with ``body``, and in ``Location`` where to poll it."""
    return JSONResponse(
        body.model_dump(mode="json"),
        status_code=http.HTTP_202_ACCEPTED,
        headers={"Location": location},
    )


#: Response header of colour-mapped images: the value (pixels) the top colour stands for.
SCALE_HEADER = "X-Scale-Max"


def display_max(record: JobRecord, disparity: np.ndarray) -> float:
    """The disparity the preview's top colour stands for: the job's range, else the map's max."""
    top = record.disparity_range.max_disparity if record.disparity_range else None
    if isinstance(top, int | float) and top > 0:
        return float(top)
    return max(float(np.max(disparity)), 1.0)


def links(record: JobRecord) -> Links:
    """Where the job and its results are; the maps and depth only where the job has them."""
    base = f"/v1/jobs/{record.id}"
    extra = {}
    if "validity" in record.maps:
        extra["validity"] = f"{base}/validity.png"
    if "confidence" in record.maps:
        extra["confidence"] = f"{base}/confidence?format=pfm"
    if "provenance" in record.maps:
        extra["provenance"] = f"{base}/provenance?format=png"
    if record.cameras is not None and record.state is JobState.SUCCEEDED:
        extra |= {"depth": f"{base}/depth?format=pfm", "points": f"{base}/points.ply"}
    return Links(
        self=base, disparity=f"{base}/disparity?format=pfm", preview=f"{base}/preview.png", **extra
    )


def charged_seconds(record: JobRecord, users: UserStore) -> float | None:
    """QPU (hybrid: charge) seconds the job's owner was charged for it; None when the job's
    solver is not metered."""
    if not is_metered(record.config.solver):
        return None
    return users.ledger.job_usage(record.owner or LOCAL_USER, record.id).seconds


def summary_of(record: JobRecord, users: UserStore) -> JobSummary:
    return JobSummary(**JobSummary.fields_of(record, links(record), charged_seconds(record, users)))
