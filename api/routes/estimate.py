"""/v1/estimate: what a job would be charged, without running it (same form as POST /v1/jobs)."""

from __future__ import annotations

import math
from typing import Annotated

from fastapi import APIRouter, Depends, File, Form, UploadFile

from api.auth import Principal, current_principal
from api.deps import Services, services
from api.routes.jobs import UPLOAD_ERRORS, check_solver_name, disparity_range_of, estimate_job
from api.schemas import Estimate
from api.uploads import decode_pair, parse_config, read_upload
from api.users import UserStore, user_store

router = APIRouter(prefix="/v1", tags=["jobs"])


@router.post(
    "/estimate",
    response_model=Estimate,
    responses={
        **UPLOAD_ERRORS,
        422: {"description": "Invalid parameters, sizes, or solver"},
    },
)
def estimate(
    svc: Annotated[Services, Depends(services)],
    principal: Annotated[Principal, Depends(current_principal)],
    users: Annotated[UserStore, Depends(user_store)],
    left: Annotated[UploadFile, File(description="Left view (PNG, PPM/PGM, JPEG, PFM, TIFF)")],
    right: Annotated[UploadFile, File(description="Right view, same size")],
    params: Annotated[
        str | None, Form(description='MatchConfig fields as JSON, e.g. {"solver": "qpu"}')
    ] = None,
) -> Estimate:
    """The QPU (or hybrid) seconds a job with these images and params would be charged, per
    level, and whether it fits your remaining budget. Nothing is stored or queued. Bundle shapes
    that earlier jobs have embedded are estimated with their actual embedding."""
    settings = svc.settings
    config = parse_config(params)
    check_solver_name(config)
    left_image, right_image = decode_pair(
        read_upload(left, "left", settings), read_upload(right, "right", settings), settings
    )
    top = disparity_range_of(left_image, right_image, config).max_disparity
    job = estimate_job(config, left_image, right_image, top, svc)
    remaining = users.ledger.status(principal.name).remaining if job.seconds > 0 else math.inf
    return Estimate(
        **job.as_dict(),
        max_disparity=top,
        remaining_seconds=None if math.isinf(remaining) else remaining,
        fits=job.seconds <= remaining,
    )
