"""ASGI middleware around the routes: what must happen before a request body is read, and what
keeps an unexpected error a well-formed response.

``RequestGuard`` authenticates ``/v1`` requests, refuses a member on an admin-only route, and
checks ``Content-Length`` against the route's limit (uploads: the files' limit; any other
route: ``max_json_body_bytes``), from the headers alone, so an unauthenticated, unauthorised or
oversized request is refused without receiving a byte of its body (FastAPI reads and parses a
body before any dependency runs). ``ErrorBoundary`` turns an
unexpected exception into a JSON 500 and does not re-raise it: Starlette's own handler
re-raises after answering, and the server then drops the connection (the client sees a reset
when it reuses it).
"""

from __future__ import annotations

import inspect
import json
import logging
import uuid
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import redis
from fastapi import APIRouter, HTTPException, Request, params, status
from fastapi.dependencies.models import Dependant
from fastapi.responses import JSONResponse
from fastapi.routing import APIRoute
from starlette.concurrency import run_in_threadpool
from starlette.routing import Match
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from api.errors import full_storage, storage_full
from api.users import USER_SCOPE_KEY, admin_user, authenticate_header, user_store_of
from shared.config import Settings

log = logging.getLogger("qhsm.api")

#: Files of the largest request (left, right, ground truth), each up to ``max_upload_bytes``.
FILES_PER_REQUEST = 3
#: Room for the form's other fields (params, gt_scale, ...) and multipart boundaries.
FORM_OVERHEAD_BYTES = 2**20


def max_request_bytes(settings: Settings) -> int:
    """The largest request body accepted, derived from the per-file limit."""
    return FILES_PER_REQUEST * settings.max_upload_bytes + FORM_OVERHEAD_BYTES


class BodyTooLargeError(HTTPException):
    """A body without (or beyond) its ``Content-Length`` grew past the limit while read (an
    HTTPException, so FastAPI's form parsing passes it on as it is)."""

    def __init__(self, limit: int, uploads: bool = True):
        what = (
            f"{FILES_PER_REQUEST} files of QHSM_MAX_UPLOAD_BYTES plus the form"
            if uploads
            else "QHSM_MAX_JSON_BODY_BYTES, for a route without file uploads"
        )
        super().__init__(
            status.HTTP_413_CONTENT_TOO_LARGE,
            f"the request body is larger than the limit of {limit} bytes ({what}); "
            + ("send smaller files" if uploads else "send a smaller body"),
        )


@dataclass(frozen=True)
class RoutePolicy:
    """What the guard checks of a request before its body is read, from its route alone:
    whether only admins may call it, and its largest body."""

    admin: bool
    uploads: bool  # the route takes files (a multipart form): the upload limit, else JSON's

    def limit(self, settings: Settings) -> int:
        return max_request_bytes(settings) if self.uploads else settings.max_json_body_bytes


def _dependencies(dependant: Dependant) -> Iterator[Dependant]:
    for sub in dependant.dependencies:
        yield sub
        yield from _dependencies(sub)


def route_policy(route: APIRoute) -> RoutePolicy:
    """A route's :class:`RoutePolicy`: admin-only when ``admin_user`` is among its
    dependencies (its router's included), uploads when a body parameter is a form field."""
    dependants = [route.dependant, *_dependencies(route.dependant)]
    admin = any(d.call is admin_user for d in dependants)
    uploads = any(isinstance(f.field_info, params.Form) for d in dependants for f in d.body_params)
    return RoutePolicy(admin=admin, uploads=uploads)


async def send_json(
    send: Send, status_code: int, body: dict[str, Any], headers: dict[str, str] | None = None
) -> None:
    payload = json.dumps(body).encode()
    raw_headers = [
        (b"content-type", b"application/json"),
        (b"content-length", str(len(payload)).encode()),
    ]
    raw_headers += [(k.lower().encode(), v.encode()) for k, v in (headers or {}).items()]
    await send({"type": "http.response.start", "status": status_code, "headers": raw_headers})
    await send({"type": "http.response.body", "body": payload})


def _header(scope: Scope, name: bytes) -> str | None:
    for key, value in scope.get("headers", []):
        if key.lower() == name:
            return value.decode("latin-1")
    return None


class RequestGuard:
    """401 for a missing or wrong key on ``/v1`` and 413 for a too-large body, both decided from
    the headers before the body is received; a body longer than announced is cut off at the
    limit too."""

    def __init__(
        self, app: ASGIApp, settings: Settings, routers: Sequence[tuple[str, APIRouter]] = ()
    ):
        self.app = app
        self.settings = settings
        #: The routers' routes (under the prefix the app includes them with) and their
        #: policies, matched as the app will match them.
        self.routes = [
            (prefix, route, route_policy(route))
            for prefix, router in routers
            for route in router.routes
            if isinstance(route, APIRoute)
        ]

    def policy(self, scope: Scope) -> RoutePolicy:
        """The policy of the route that will answer (an unknown path: a JSON route's)."""
        path = scope["path"].removeprefix(scope.get("root_path", ""))
        for prefix, route, policy in self.routes:
            if prefix and not (path == prefix or path.startswith(prefix + "/")):
                continue
            inner = {**scope, "path": path[len(prefix) :], "root_path": ""}
            if route.matches(inner)[0] is Match.FULL:
                return policy
        return RoutePolicy(admin=False, uploads=False)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        path = scope["path"].removeprefix(scope.get("root_path", ""))
        policy = self.policy(scope)
        if path == "/v1" or path.startswith("/v1/") or policy.admin:
            store = user_store_of(scope["app"])
            try:
                user = await run_in_threadpool(
                    authenticate_header, store, _header(scope, b"authorization")
                )
                if policy.admin:  # refused before a byte of the body is read (issue 29)
                    admin_user(user)
            except HTTPException as refused:
                await self.refuse(scope, send, refused)
                return
            scope[USER_SCOPE_KEY] = user
        limit = policy.limit(self.settings)
        length = _header(scope, b"content-length")
        if length is not None and length.strip().isdigit() and int(length) > limit:
            await self.refuse(scope, send, BodyTooLargeError(limit, policy.uploads))
            return
        received = 0

        async def counting_receive() -> Message:
            """The body as it comes, cut off at the limit (the HTTPException raised here is
            answered by FastAPI's handler, or by :class:`ErrorBoundary`)."""
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    raise BodyTooLargeError(limit, policy.uploads)
            return message

        await self.app(scope, counting_receive, send)

    @staticmethod
    async def refuse(scope: Scope, send: Send, refused: HTTPException) -> None:
        """Answer without reading the body; with one coming, close the connection afterwards
        (else the server would have to drain the unread body to reuse it)."""
        headers = dict(refused.headers or {})
        has_body = _header(scope, b"transfer-encoding") or _header(scope, b"content-length")
        if has_body and has_body.strip() != "0":
            headers["connection"] = "close"
        await send_json(send, refused.status_code, {"detail": refused.detail}, headers)


def storage_full_response(request: Request, error: BaseException) -> JSONResponse:
    """507 with ``Retry-After``: nothing was kept of the request (uploads are removed)."""
    error = full_storage(error) or error
    where = "Redis cannot write" if isinstance(error, redis.RedisError) else "the disk is full"
    log.error("%s %s: storage full (%s): %s", request.method, request.url.path, where, error)
    return JSONResponse(
        {
            "detail": f"the service is out of storage ({where}); nothing of this request was "
            "kept. Try again later; if it persists, tell the operator to free disk space on "
            "the data directory and Redis"
        },
        status_code=507,
        headers={"Retry-After": "60"},
    )


def _registered_handler(app: Any, error: Exception) -> Any:
    """The app's exception handler for ``error``'s class (nearest in its MRO), if any: errors
    raised outside the routes (in :class:`RequestGuard`) get the answers the routes' get."""
    handlers = getattr(app, "exception_handlers", {})
    for kind in type(error).__mro__:
        if kind is Exception:
            return None
        if kind in handlers:
            return handlers[kind]
    return None


async def _handled(handler: Any, request: Request, error: Exception) -> Any:
    """The handler's response, or None when it declines ``error`` by raising it again (e.g.
    the OSError handler for anything but a full disk)."""
    try:
        response = handler(request, error)
        if inspect.isawaitable(response):
            response = await response
    except Exception:
        return None
    return response


class ErrorBoundary:
    """Any exception that escapes the routes: answered by the app's handler for its class when
    there is one, else logged with an incident id and answered as a JSON 500 that names the
    incident; never re-raised (so the connection stays usable). A handler declines an error by
    raising it again."""

    def __init__(self, app: ASGIApp):
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = False

        async def tracking_send(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, receive, tracking_send)
        except Exception as error:
            handler = None if started else _registered_handler(scope["app"], error)
            if handler is not None:  # e.g. a Redis outage raised while authenticating
                response = await _handled(handler, Request(scope, receive), error)
                if response is not None:
                    await response(scope, receive, send)
                    return
            if not started and storage_full(error):  # e.g. kombu's error around Redis's
                response = storage_full_response(Request(scope, receive), error)
                await response(scope, receive, send)
                return
            incident = uuid.uuid4().hex[:12]
            log.exception("incident %s: %s %s failed", incident, scope["method"], scope["path"])
            if started:  # half a response is out: only closing the connection can end it
                raise
            detail = f"internal error (incident {incident}); the details are in the server log"
            await send_json(send, status.HTTP_500_INTERNAL_SERVER_ERROR, {"detail": detail})
