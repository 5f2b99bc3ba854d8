"""Liveness (the process answers) and readiness (Redis answers)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends
from fastapi.responses import JSONResponse

from api.deps import Services, services
from api.schemas import Health

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health)
def healthz():
    return Health(status="ok")


@router.get("/readyz", response_model=Health, responses={503: {"model": Health}})
def readyz(svc: Annotated[Services, Depends(services)]):
    try:
        svc.store.ping()
    except Exception as error:
        body = Health(status="unavailable", redis=f"unreachable: {type(error).__name__}")
        return JSONResponse(body.model_dump(), status_code=503)
    return Health(status="ok", redis="ok")
