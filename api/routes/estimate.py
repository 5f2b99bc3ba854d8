"""/v1/estimate: what a job would be charged, without running it (same form as POST /v1/jobs),
computed on a pricing worker and polled at /v1/estimates/{id}."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, File
from fastapi.responses import JSONResponse

from api import estimate_service
from api.deps import CallerDep, Responses, UploadViews
from api.responses import accepted, upload_route
from api.schemas import EstimateStatus

router = APIRouter(tags=["jobs"])

NOT_FOUND: Responses = {404: {"description": "No such estimate (or not yours), or it expired"}}


#: What else an estimate upload can be refused with (:func:`~api.responses.upload_route`).
REFUSED: Responses = {
    422: {"description": "Invalid parameters, sizes, or solver"},
    429: {"description": "Too many of your estimates are waiting or computing"},
}


@upload_route(router, "/estimate", EstimateStatus, REFUSED)
def estimate(caller: CallerDep, upload: Annotated[UploadViews, File()]) -> JSONResponse:
    """The QPU (or hybrid) seconds a job with these images and params would be charged, per
    level, and whether it fits your remaining budget. Computed on a worker: the answer (202)
    is the estimate's status, done at once when an identical request was estimated recently;
    otherwise poll its ``Location`` (``GET /v1/estimates/{id}``) until it is ``done`` (its
    ``result``), ``failed`` (its ``error``) or ``cancelled``; an estimate nobody polls for
    ``QHSM_ESTIMATE_ABANDON_SECONDS`` is cancelled. Nothing is queued as a job. Bundle shapes
    that earlier jobs have embedded are estimated with their actual embedding."""
    svc, principal, users = caller
    record = estimate_service.request_estimate(
        upload.params, upload.left, upload.right, principal.name, svc
    )
    body = estimate_service.status_of(record, svc, users)
    return accepted(body, body.links["self"])


@router.get("/estimates/{estimate_id}", response_model=EstimateStatus, responses=NOT_FOUND)
def get_estimate(estimate_id: str, caller: CallerDep) -> EstimateStatus:
    """An estimate's state, and its result once done (or why there is none)."""
    record = estimate_service.find_estimate(estimate_id, caller.svc, caller.principal)
    return estimate_service.status_of(record, caller.svc, caller.users)


@router.delete("/estimates/{estimate_id}", response_model=EstimateStatus, responses=NOT_FOUND)
def cancel_estimate(estimate_id: str, caller: CallerDep) -> EstimateStatus:
    """Cancel an estimate you no longer wait for (its worker stops); one that has ended is
    answered as it is."""
    record = estimate_service.cancel_estimate(estimate_id, caller.svc, caller.principal)
    return estimate_service.status_of(record, caller.svc, caller.users)
