"""/v1/users: what ``qhsm admin`` does, over HTTP for admins (the web page's admin panel).

Keys are returned once, in the answer of the request that made them; only their hashes are kept.
"""

from __future__ import annotations

from datetime import datetime

from fastapi import APIRouter, Depends, HTTPException
from fastapi import status as http
from pydantic import BaseModel, Field

from api.deps import AdminDep, PrincipalDep, UsersDep
from api.users import DEFAULT_BUDGET, User, UserError, UserStore, admin_user
from shared.settings import BudgetPeriod

router = APIRouter(prefix="/users", tags=["users"], dependencies=[Depends(admin_user)])
me_router = APIRouter(tags=["users"])


class UserInfo(User):
    limit_seconds: float | None = Field(description="QPU budget per period; null: unlimited")
    used_seconds: float = Field(description="Charged in the current period")
    reserved_seconds: float
    period: BudgetPeriod = Field(description="What the budget covers now")
    own_period: BudgetPeriod | None = Field(
        None, description="The user's own period; null: the deployment's (QHSM_BUDGET_PERIOD)"
    )
    resets_at: datetime | None = Field(None, description="End of the current period; null: never")


class NewUser(BaseModel):
    name: str = Field(description="1-64 letters, digits, '_', '.', '@' or '-'")
    admin: bool = False
    qpu_seconds: float | None = Field(
        None,
        ge=0,
        allow_inf_nan=False,
        description="QPU budget, seconds (finite); null: unlimited; omitted: the default",
    )


class Quota(BaseModel):
    qpu_seconds: float | None = Field(
        ge=0, allow_inf_nan=False, description="QPU budget, seconds (finite); null: unlimited"
    )
    period: BudgetPeriod | None = Field(
        None,
        description="The user's own budget period (lifetime, monthly, weekly); null: the "
        "deployment's (QHSM_BUDGET_PERIOD); omitted: unchanged",
    )


class IssuedKey(BaseModel):
    user: UserInfo
    key: str = Field(description="The API key: shown this once, only its hash is stored")


def info(store: UserStore, user: User) -> UserInfo:
    budget = store.ledger.status(user.name).as_dict()
    return UserInfo(
        **user.model_dump(),
        limit_seconds=budget["limit_seconds"],
        used_seconds=budget["used_seconds"],
        reserved_seconds=budget["reserved_seconds"],
        period=budget["period"],
        own_period=store.ledger.own_period(user.name),
        resets_at=budget["resets_at"],
    )


def existing(store: UserStore, name: str) -> User:
    try:
        return store.require(name)
    except UserError as error:
        raise HTTPException(http.HTTP_404_NOT_FOUND, str(error)) from None


@me_router.get("/me", response_model=User)
def me(caller: PrincipalDep):
    """Who the key belongs to and whether they are an admin (the web page's sign-in check)."""
    return caller


@router.get("", response_model=list[UserInfo])
def list_users(store: UsersDep):
    """Every user with their key id, state and QPU budget (admins only)."""
    return [info(store, user) for user in store.list_users()]


@router.post("", response_model=IssuedKey, status_code=http.HTTP_201_CREATED)
def create_user(body: NewUser, store: UsersDep):
    """Add a user; the answer holds their API key, shown once."""
    budget = body.qpu_seconds if "qpu_seconds" in body.model_fields_set else DEFAULT_BUDGET
    if store.get(body.name) is not None:
        raise HTTPException(
            http.HTTP_409_CONFLICT, f"user {body.name!r} exists already; rotate their key instead"
        )
    try:
        user, key = store.create_user(body.name, admin=body.admin, qpu_seconds=budget)
    except UserError as error:
        raise HTTPException(http.HTTP_422_UNPROCESSABLE_CONTENT, str(error)) from None
    return IssuedKey(user=info(store, user), key=key)


@router.post("/{name}/key", response_model=IssuedKey)
def rotate_key(name: str, store: UsersDep):
    """A new key for the user (the old one stops working at once); shown once."""
    existing(store, name)
    key = store.rotate_key(name)
    return IssuedKey(user=info(store, existing(store, name)), key=key)


@router.delete("/{name}/key", response_model=UserInfo)
def revoke_key(name: str, store: UsersDep, caller: AdminDep):
    """Disable the user's key; their jobs and usage stay. Rotating gives them a new one."""
    existing(store, name)
    if name == caller.name:
        raise HTTPException(
            http.HTTP_409_CONFLICT, "that is your own key: another admin must revoke it"
        )
    store.revoke(name)
    return info(store, existing(store, name))


@router.put("/{name}/quota", response_model=UserInfo)
def set_quota(name: str, body: Quota, store: UsersDep):
    """Set the user's QPU budget per period in seconds (null: unlimited) and, when given, their
    own budget period (null: the deployment's)."""
    user = existing(store, name)
    store.ledger.set_limit(name, body.qpu_seconds)
    if "period" in body.model_fields_set:
        store.ledger.set_period(name, body.period)
    return info(store, user)
