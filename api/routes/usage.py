"""/v1/usage: QPU (and hybrid) time charged per user and job, with each user's budget."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, HTTPException, Query
from fastapi import status as http

from api.deps import PrincipalDep, UsersDep
from api.schemas import Usage, UserUsage

router = APIRouter(tags=["usage"])


@router.get("/usage", response_model=Usage)
def usage(
    caller: PrincipalDep,
    store: UsersDep,
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
    entries = [UserUsage.of(store.ledger.usage(name)) for name in names]
    in_flight = None
    if caller.admin:
        from workers.quota import QpuSemaphore

        in_flight = QpuSemaphore(store.redis, store.prefix, limit=1).in_flight()
    return Usage(
        users=entries,
        total_used_seconds=sum(entry.used_seconds for entry in entries),
        qpu_in_flight=in_flight,
    )
