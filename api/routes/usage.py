"""/v1/usage: QPU (and hybrid) time charged per user and job, with each user's budget."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Query
from fastapi import status as http
from pydantic import BaseModel, Field

from api.users import User, UserStore, current_user, user_store

router = APIRouter(prefix="/v1", tags=["usage"])


class JobUsage(BaseModel):
    id: str
    qpu_seconds: float = Field(description="QPU access time (hybrid: charge time) charged")
    problems: int = Field(description="QPU / hybrid problems sent")


class UserUsage(BaseModel):
    user: str
    limit_seconds: float | None = Field(description="Total budget; null: unlimited")
    used_seconds: float
    reserved_seconds: float = Field(description="Held by bundles being solved right now")
    remaining_seconds: float | None
    jobs: list[JobUsage]


class Usage(BaseModel):
    users: list[UserUsage] = Field(description="Your own entry; admins: everyone's")
    total_used_seconds: float
    qpu_in_flight: int | None = Field(None, description="Lab-wide problems in flight (admins)")


@router.get("/usage", response_model=Usage)
def usage(
    caller: Annotated[User, Depends(current_user)],
    store: Annotated[UserStore, Depends(user_store)],
    user: Annotated[str | None, Query(description="Admins: only this user")] = None,
) -> Usage:
    """Your QPU usage per job and in total, and what is left of your budget. Admins see every
    user (or one, with ``?user=NAME``) and how many QPU problems are in flight lab-wide."""
    if not caller.admin:
        if user not in (None, caller.name):
            raise HTTPException(http.HTTP_403_FORBIDDEN, "only admins may see others' usage")
        names = [caller.name]
    elif user is not None:
        if store.get(user) is None and user not in store.ledger.users():
            raise HTTPException(http.HTTP_404_NOT_FOUND, f"no user {user!r}")
        names = [user]
    else:
        names = sorted({u.name for u in store.list_users()} | set(store.ledger.users()))
    entries = [UserUsage.model_validate(store.ledger.usage(name).as_dict()) for name in names]
    in_flight = None
    if caller.admin:
        from workers.quota import QpuSemaphore

        in_flight = QpuSemaphore(store.redis, store.prefix, limit=1).in_flight()
    return Usage(
        users=entries,
        total_used_seconds=sum(entry.used_seconds for entry in entries),
        qpu_in_flight=in_flight,
    )
