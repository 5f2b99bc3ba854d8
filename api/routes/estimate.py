"""/v1/estimate: what a job would be charged, without running it (same form as POST /v1/jobs)."""

from __future__ import annotations

from fastapi import APIRouter

from api import job_service
from api.deps import LeftView, ParamsForm, PrincipalDep, RightView, ServicesDep, UsersDep
from api.responses import UPLOAD_ERRORS
from api.schemas import Estimate

router = APIRouter(tags=["jobs"])


@router.post(
    "/estimate",
    response_model=Estimate,
    responses={
        **UPLOAD_ERRORS,
        422: {"description": "Invalid parameters, sizes, or solver"},
    },
)
def estimate(
    svc: ServicesDep,
    principal: PrincipalDep,
    users: UsersDep,
    left: LeftView,
    right: RightView,
    params: ParamsForm = None,
) -> Estimate:
    """The QPU (or hybrid) seconds a job with these images and params would be charged, per
    level, and whether it fits your remaining budget. Nothing is stored or queued. Bundle shapes
    that earlier jobs have embedded are estimated with their actual embedding."""
    quote = job_service.quote(params, left, right, principal.name, svc, users)
    memory = (quote.memory_mb, quote.memory_budget_mb)
    return Estimate.of(quote.estimate, quote.max_disparity, quote.remaining_seconds, memory)
