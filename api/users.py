"""Users and API keys in Redis, and the FastAPI dependencies that authenticate a request.

A key looks like ``qhsm_1a2b3c4d_<43 url-safe characters>``: a fixed tag, a short public key id
used to find the user, and 32 random bytes. Only the key's SHA-256 is stored (the key is random
and long, so a fast hash is the right tool; there is nothing to brute-force), and the stored and
presented digests are compared in constant time. The key itself is shown once, when it is made.

Keys (under ``{key_prefix}:``):

    user:{name}     hash  name, admin, key_id, key_hash, created_at, key_created_at, revoked
    users           set   user names
    apikey:{id}     str   the name of the user whose current key has this id

Budgets live in :mod:`workers.quota` (``QuotaLedger``); :class:`UserStore` sets a new user's
budget there so that a user never exists without one.
"""

from __future__ import annotations

import hashlib
import hmac
import math
import re
import secrets
from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated

import redis
from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from pydantic import BaseModel

from shared.config import Settings
from shared.settings import BudgetPeriod
from workers.quota import LOCAL_USER, QuotaLedger
from workers.redis_client import client_for, text

KEY_TAG = "qhsm"
KEY_ID_BYTES = 4
KEY_SECRET_BYTES = 32
USER_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.@-]{0,63}$")
_KEY = re.compile(rf"^{KEY_TAG}_([0-9a-f]{{{2 * KEY_ID_BYTES}}})_([A-Za-z0-9_-]{{20,}})$")
#: Scope key under which ``api.middleware.RequestGuard`` leaves the authenticated user.
USER_SCOPE_KEY = "qhsm.user"
#: ``create_user``'s budget argument meaning "the settings' default".
DEFAULT_BUDGET = "default"


class UserError(ValueError):
    """A user-management request that cannot be done (message says why)."""


class User(BaseModel):
    """A lab member as the service sees them (never carries the key or its hash)."""

    name: str
    admin: bool = False
    key_id: str | None = None
    created_at: datetime | None = None
    key_created_at: datetime | None = None
    revoked: bool = False


def new_key() -> tuple[str, str]:
    """A fresh (key id, key)."""
    key_id = secrets.token_hex(KEY_ID_BYTES)
    return key_id, f"{KEY_TAG}_{key_id}_{secrets.token_urlsafe(KEY_SECRET_BYTES)}"


def key_digest(key: str) -> str:
    return hashlib.sha256(key.encode()).hexdigest()


def _now() -> str:
    return datetime.now(UTC).isoformat()


class UserStore:
    """Create, list, rotate and revoke users and their keys; authenticate a presented key."""

    def __init__(
        self,
        client: redis.Redis,
        key_prefix: str,
        *,
        auth_enabled: bool = True,
        default_qpu_seconds: float = Settings.model_fields["default_qpu_seconds"].default,
        budget_period: BudgetPeriod = Settings.model_fields["budget_period"].default,
    ):
        self.redis = client
        self.prefix = key_prefix
        self.auth_enabled = auth_enabled
        self.default_qpu_seconds = default_qpu_seconds
        self.ledger = QuotaLedger(client, key_prefix, budget_period)

    @classmethod
    def from_settings(cls, settings: Settings, client: redis.Redis | None = None) -> UserStore:
        return cls(
            client or client_for(settings),
            settings.key_prefix,
            auth_enabled=settings.auth_enabled,
            default_qpu_seconds=settings.default_qpu_seconds,
            budget_period=settings.budget_period,
        )

    def key(self, *parts: object) -> str:
        return ":".join([self.prefix, *map(str, parts)])

    # management -------------------------------------------------------------------------------

    def create_user(
        self, name: str, *, admin: bool = False, qpu_seconds: float | str | None = DEFAULT_BUDGET
    ) -> tuple[User, str]:
        """A new user with a new key (returned once) and a QPU budget in seconds: the settings'
        default unless given; None means unlimited."""
        if not USER_NAME.match(name):
            raise UserError(
                f"invalid user name {name!r}: use 1-64 letters, digits, '_', '.', '@' or '-'"
            )
        if qpu_seconds == DEFAULT_BUDGET:
            qpu_seconds = self.default_qpu_seconds
        if qpu_seconds is not None and not 0 <= float(qpu_seconds) < math.inf:
            raise UserError(
                f"--qpu-seconds must be a finite number >= 0 (or unlimited), not {qpu_seconds!r}"
            )
        if not self.redis.sadd(self.key("users"), name):
            raise UserError(f"user {name!r} exists already (rotate-key gives them a new key)")
        key_id, key = new_key()
        stamp = _now()
        with self.redis.pipeline() as pipe:
            pipe.hset(
                self.key("user", name),
                mapping={
                    "name": name,
                    "admin": int(admin),
                    "key_id": key_id,
                    "key_hash": key_digest(key),
                    "created_at": stamp,
                    "key_created_at": stamp,
                    "revoked": 0,
                },
            )
            pipe.set(self.key("apikey", key_id), name)
            pipe.execute()
        self.ledger.set_limit(name, None if qpu_seconds is None else float(qpu_seconds))
        user = self.get(name)
        assert user is not None
        return user, key

    def _raw(self, name: str) -> dict[str, str]:
        raw = self.redis.hgetall(self.key("user", name))
        return {text(k): text(v) for k, v in raw.items()}

    @staticmethod
    def _user(fields: dict[str, str]) -> User:
        return User(
            name=fields["name"],
            admin=fields.get("admin") == "1",
            key_id=fields.get("key_id") or None,
            created_at=fields.get("created_at") or None,
            key_created_at=fields.get("key_created_at") or None,
            revoked=fields.get("revoked") == "1",
        )

    def get(self, name: str) -> User | None:
        fields = self._raw(name)
        return self._user(fields) if fields else None

    def require(self, name: str) -> User:
        user = self.get(name)
        if user is None:
            raise UserError(f"no user {name!r} (see `qhsm admin list-users`)")
        return user

    def list_users(self) -> list[User]:
        names = sorted(text(n) for n in self.redis.smembers(self.key("users")))
        return [user for user in map(self.get, names) if user is not None]

    def rotate_key(self, name: str) -> str:
        """A new key for ``name`` (the old one stops working at once; revoked users return)."""
        user = self.require(name)
        key_id, key = new_key()
        with self.redis.pipeline() as pipe:
            if user.key_id:
                pipe.delete(self.key("apikey", user.key_id))
            pipe.hset(
                self.key("user", name),
                mapping={
                    "key_id": key_id,
                    "key_hash": key_digest(key),
                    "key_created_at": _now(),
                    "revoked": 0,
                },
            )
            pipe.set(self.key("apikey", key_id), name)
            pipe.execute()
        return key

    def revoke(self, name: str) -> None:
        """Disable the user's key (their jobs and usage records stay)."""
        user = self.require(name)
        with self.redis.pipeline() as pipe:
            if user.key_id:
                pipe.delete(self.key("apikey", user.key_id))
            pipe.hset(self.key("user", name), mapping={"revoked": 1, "key_hash": ""})
            pipe.execute()

    # authentication ---------------------------------------------------------------------------

    def authenticate(self, key: str) -> User | None:
        """The user whose current key this is; None for malformed, unknown or revoked keys."""
        match = _KEY.match(key.strip())
        if match is None:
            return None
        name = self.redis.get(self.key("apikey", match.group(1)))
        if name is None:
            return None
        fields = self._raw(text(name))
        stored = fields.get("key_hash", "")
        presented = key_digest(key.strip())
        if not stored or fields.get("revoked") == "1":
            return None
        if not hmac.compare_digest(stored.encode(), presented.encode()):
            return None
        return self._user(fields)


# --- the local admin of `qhsm serve` ----------------------------------------------------------

#: The admin `qhsm serve` / `qhsm demo` create so a fresh install works without setup.
LOCAL_ADMIN = "local-admin"
LOCAL_KEY_FILE = "api-key"


def read_local_key(data_dir: Path) -> str | None:
    """The local admin key `qhsm serve` left in ``data_dir``, if any."""
    path = Path(data_dir) / LOCAL_KEY_FILE
    try:
        return path.read_text().strip() or None
    except OSError:
        return None


def ensure_local_admin(store: UserStore, data_dir: Path) -> tuple[str, bool]:
    """A working key of the local admin: the one in ``data_dir/api-key`` if it still
    authenticates, else a new one (creating the user on first start), written there with mode
    600. Returns (key, whether it is new)."""
    key = read_local_key(data_dir)
    if key and (user := store.authenticate(key)) is not None and user.name == LOCAL_ADMIN:
        return key, False
    if store.get(LOCAL_ADMIN) is None:
        _, key = store.create_user(LOCAL_ADMIN, admin=True, qpu_seconds=None)
    else:
        key = store.rotate_key(LOCAL_ADMIN)
    path = Path(data_dir) / LOCAL_KEY_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    path.touch(mode=0o600, exist_ok=True)
    path.chmod(0o600)
    path.write_text(key + "\n")
    return key, True


# --- FastAPI dependencies ----------------------------------------------------------------------

_bearer = HTTPBearer(auto_error=False, description="API key from `qhsm admin create-user`")


def user_store_of(app) -> UserStore:
    """The app's user store: ``app.state.users``, else built from the app's services."""
    store = getattr(app.state, "users", None)
    if store is None:
        services = app.state.services
        store = UserStore.from_settings(services.settings, services.store.redis)
        app.state.users = store
    return store


def user_store(request: Request) -> UserStore:
    return user_store_of(request.app)


def _unauthorized(detail: str, error: str | None = None) -> HTTPException:
    challenge = 'Bearer realm="qhsm"'
    if error:
        challenge += f', error="{error}"'
    return HTTPException(
        status.HTTP_401_UNAUTHORIZED, detail=detail, headers={"WWW-Authenticate": challenge}
    )


def authenticate_header(store: UserStore, authorization: str | None) -> User:
    """The caller from an ``Authorization`` header value; 401 when missing, wrong or revoked.

    Runs in :class:`api.middleware.RequestGuard`, before the request body is read.
    """
    if not store.auth_enabled:
        return User(name=LOCAL_USER, admin=True)
    scheme, _, credentials = (authorization or "").partition(" ")
    if scheme.lower() != "bearer" or not credentials.strip():
        raise _unauthorized(
            "missing API key: send `Authorization: Bearer KEY` (an admin creates keys with "
            "`qhsm admin create-user NAME`)"
        )
    user = store.authenticate(credentials.strip())
    if user is None:
        raise _unauthorized(
            "invalid or revoked API key; ask an admin for a new one (`qhsm admin rotate-key`)",
            "invalid_token",
        )
    return user


def current_user(
    request: Request,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
    store: Annotated[UserStore, Depends(user_store)],
) -> User:
    """The caller, as ``RequestGuard`` authenticated them (``credentials`` only declares the
    scheme in the OpenAPI document); checked here when the guard did not run."""
    user = request.scope.get(USER_SCOPE_KEY)
    if user is not None:
        return user
    header = None if credentials is None else f"{credentials.scheme} {credentials.credentials}"
    return authenticate_header(store, header)


def admin_user(user: Annotated[User, Depends(current_user)]) -> User:
    """The caller if they are an admin; 403 otherwise."""
    if not user.admin:
        raise HTTPException(status.HTTP_403_FORBIDDEN, detail="this needs an admin's API key")
    return user
