"""/v1/usage: QPU (and hybrid) time charged per user and job, with each user's budget."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, HTTPException, Query
from fastapi import status as http
from fastapi.responses import Response

from api.deps import PrincipalDep, UsersDep
from api.schemas import Usage, UserUsage
from workers.quota.ledger import usage_csv

router = APIRouter(tags=["usage"])


@router.get(
    "/usage",
    response_model=Usage,
    responses={200: {"content": {"text/csv": {}}}, 403: {"description": "Another user's"}},
)
def usage(
    caller: PrincipalDep,
    store: UsersDep,
    user: Annotated[str | None, Query(description="Admins: only this user")] = None,
    format: Annotated[
        Literal["json", "csv"], Query(description="csv: one row per user and job")
    ] = "json",
) -> Usage | Response:
    """Your QPU usage per job (with the dates it was charged) and in total, and what is left
    of your budget (with a ``warning`` when less than 10 % is). Admins see every user (or one,
    with ``?user=NAME``) and how many QPU problems are in flight lab-wide. ``?format=csv``: the
    ledger as CSV (user, job, qpu_seconds, problems, first/last_charged_at)."""
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
    ledger = [store.ledger.usage(name) for name in names]
    if format == "csv":
        return Response(
            usage_csv(ledger),
            media_type="text/csv",
            headers={"Content-Disposition": 'attachment; filename="qpu-usage.csv"'},
        )
    entries = [UserUsage.of(usage) for usage in ledger]
    in_flight = None
    if caller.admin:
        from workers.quota import QpuSemaphore

        in_flight = QpuSemaphore(store.redis, store.prefix, limit=1).in_flight()
    return Usage(
        users=entries,
        total_used_seconds=sum(entry.total_used_seconds for entry in entries),
        qpu_in_flight=in_flight,
    )
