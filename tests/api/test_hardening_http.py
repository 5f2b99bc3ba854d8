"""Issue 10's API breaks in the HTTP layer: the key and the size are checked before a body is
read, a 500 leaves the connection usable, polls are logged quietly."""

from __future__ import annotations

import asyncio
import http.client
import json
import logging
import socket
import time

import harness
import httpx
import pytest
from api_helpers import LEFT

from tests.fresh_thread import in_fresh_thread

MiB = 2**20


# --- 9. the key and the size are checked before the body is read ------------------------------


def call_asgi(
    app, headers: dict[str, str], body_bytes: int, method: str = "POST", path: str = "/v1/jobs"
) -> tuple[int, dict, int]:
    """``method path`` (POST /v1/jobs) with a body of ``body_bytes`` fed in 1 MiB pieces;
    returns the status, the JSON answer and how many body bytes the app asked for."""
    scope = {
        "type": "http",
        "asgi": {"version": "3.0"},
        "http_version": "1.1",
        "method": method,
        "scheme": "http",
        "path": path,
        "raw_path": path.encode(),
        "root_path": "",
        "query_string": b"",
        "headers": [(k.lower().encode(), v.encode()) for k, v in headers.items()],
        "client": ("127.0.0.1", 50000),
        "server": ("testserver", 80),
    }
    consumed = 0
    messages: list[dict] = []

    async def receive() -> dict:
        nonlocal consumed
        piece = min(MiB, body_bytes - consumed)
        consumed += piece
        return {"type": "http.request", "body": bytes(piece), "more_body": consumed < body_bytes}

    async def send(message: dict) -> None:
        messages.append(message)

    in_fresh_thread(lambda: asyncio.run(asyncio.wait_for(app(scope, receive, send), 60)))
    status = next(m["status"] for m in messages if m["type"] == "http.response.start")
    body = b"".join(m.get("body", b"") for m in messages if m["type"] == "http.response.body")
    return status, json.loads(body), consumed


BIG = 1_500_000_000
MULTIPART = {"content-type": "multipart/form-data; boundary=x", "content-length": str(BIG)}


@pytest.mark.parametrize("authorization", [None, "Bearer qhsm_0badc0de_" + "x" * 43, "Basic Zm9v"])
def test_an_unauthenticated_upload_is_401_without_reading_its_body(api, authorization):
    headers = dict(MULTIPART)
    if authorization:
        headers["authorization"] = authorization
    status, answer, consumed = call_asgi(api.app, headers, 64 * MiB)
    assert status == 401 and "API key" in answer["detail"]
    assert consumed == 0


def test_an_announced_body_above_the_limit_is_413_without_reading_it(api, admin_headers):
    headers = {**MULTIPART, "authorization": admin_headers["Authorization"]}
    status, answer, consumed = call_asgi(api.app, headers, 64 * MiB)
    assert status == 413 and "QHSM_MAX_UPLOAD_BYTES" in answer["detail"]
    assert consumed == 0


JSON_BIG = {"content-type": "application/json", "content-length": str(BIG)}


@pytest.mark.parametrize(
    ("method", "path"),
    [("POST", "/v1/users"), ("PUT", "/v1/users/ada/quota"), ("POST", "/v1/users/ada/key")],
)
def test_a_member_on_an_admin_route_is_403_without_reading_its_body(
    api, api_settings, method, path
):
    """A member's 150 MB JSON body on an admin-only route was parsed (+900 MB of API memory)
    before the 403 (issue 29): now refused from the headers."""
    from api.users import UserStore

    _, key = UserStore.from_settings(api_settings).create_user(
        f"member-{harness.unique_prefix()[-6:]}"
    )
    headers = {"content-type": "application/json", "authorization": f"Bearer {key}"}
    status, answer, consumed = call_asgi(api.app, headers, 8 * MiB, method, path)
    assert status == 403 and "admin" in answer["detail"]
    assert consumed == 0


def test_a_json_route_has_its_own_body_limit(api, admin_headers, make_client):
    headers = {**JSON_BIG, "authorization": admin_headers["Authorization"]}
    status, answer, consumed = call_asgi(api.app, headers, 64 * MiB, "POST", "/v1/users")
    assert status == 413 and "QHSM_MAX_JSON_BODY_BYTES" in answer["detail"]
    assert consumed == 0
    client = make_client(max_json_body_bytes=2048)
    body = json.dumps({"name": "padded", "pad": "x" * 4096})
    response = client.post("/v1/users", content=body, headers={"content-type": "application/json"})
    assert response.status_code == 413
    assert "limit of 2048 bytes (QHSM_MAX_JSON_BODY_BYTES" in response.json()["detail"]
    # uploads keep the files' limit, far above the JSON one
    upload = client.post("/v1/jobs", files={"left": ("l.png", LEFT), "right": ("r.png", LEFT)})
    assert upload.status_code == 202, upload.text


def test_a_chunked_body_is_cut_off_at_the_limit(make_client):
    client = make_client(max_upload_bytes=1000)  # limit: 3 x 1000 bytes + 1 MiB of form

    def pieces():
        for _ in range(8):
            yield bytes(MiB)

    response = client.post(
        "/v1/jobs", content=pieces(), headers={"content-type": "multipart/form-data; boundary=x"}
    )
    assert response.status_code == 413
    assert "request body is larger than the limit of 1051576 bytes" in response.json()["detail"]


def test_a_real_server_answers_401_to_a_huge_unauthenticated_upload_at_once(live_api):
    """The answer comes at once, and the server then closes the connection instead of
    draining the 1.5 GB it was promised."""
    head = "".join(f"{name}: {value}\r\n" for name, value in MULTIPART.items())
    started = time.monotonic()
    with socket.create_connection((live_api.host, live_api.port), timeout=5) as sock:
        sock.sendall(f"POST /v1/jobs HTTP/1.1\r\nhost: x\r\n{head}\r\n--x\r\n".encode())
        answer = b""
        while chunk := sock.recv(65536):  # b"": the server closed the connection
            answer += chunk
    assert answer.startswith(b"HTTP/1.1 401 ")
    assert b"connection: close" in answer.lower()
    assert time.monotonic() - started < 5


# --- 11. a 500 keeps the connection usable ----------------------------------------------------


def test_after_a_500_the_connection_is_still_usable(live_api, admin_headers, monkeypatch):
    def broken(*args, **kwargs):
        raise RuntimeError("simulated bug")

    monkeypatch.setattr(live_api.app.state.services.store, "list_jobs", broken)
    connection = http.client.HTTPConnection(live_api.host, live_api.port, timeout=10)
    for _ in range(3):
        connection.request("GET", "/v1/jobs", headers=admin_headers)
        response = connection.getresponse()
        answer = json.loads(response.read())
        assert response.status == 500 and "incident" in answer["detail"]
        assert "simulated bug" not in answer["detail"]  # details stay in the log
        connection.request("GET", "/healthz")
        follow_up = connection.getresponse()
        assert follow_up.status == 200 and json.loads(follow_up.read())["status"] == "ok"
    connection.close()


def test_errors_raised_before_the_routes_get_the_apps_handlers(api_settings, admin_headers):
    """Authentication runs ahead of FastAPI's exception handling; the app's handler for an error
    (here a Redis outage: 503) still answers it, and anything without one is a JSON 500."""
    import redis
    from fastapi.testclient import TestClient

    from api.app import create_app
    from workers.embedded_redis import free_port

    app = create_app(
        api_settings.model_copy(update={"redis_url": f"redis://127.0.0.1:{free_port()}/0"})
    )
    with TestClient(app, raise_server_exceptions=False, headers=admin_headers) as client:
        response = client.get("/v1/jobs")
        assert response.status_code == 503 and "Redis" in response.json()["detail"]

        app.exception_handlers.pop(redis.ConnectionError)
        crashed = client.get("/v1/jobs")
    assert crashed.status_code == 500 and "incident" in crashed.json()["detail"]


# --- 16. polls are logged at debug level ------------------------------------------------------


def access_records(caplog) -> list[logging.LogRecord]:
    time.sleep(0.2)  # uvicorn logs after the response is sent
    return [r for r in caplog.records if r.name == "uvicorn.access"]


def test_polls_are_logged_at_debug_and_other_requests_at_info(
    live_api, admin_headers, caplog, monkeypatch
):
    # an earlier test's in-process `qhsm demo` may have applied uvicorn's logging config, which
    # stops the access log at uvicorn's own handlers; caplog listens at the root
    for name in ("uvicorn", "uvicorn.access"):
        monkeypatch.setattr(logging.getLogger(name), "propagate", True)
    with httpx.Client(base_url=live_api.url, headers=admin_headers) as client:
        job_id = client.post(
            "/v1/jobs", files={"left": ("l.png", LEFT), "right": ("r.png", LEFT)}
        ).json()["id"]
        caplog.set_level(logging.INFO, logger="uvicorn.access")
        caplog.clear()
        for _ in range(3):
            assert client.get(f"/v1/jobs/{job_id}").status_code == 200
        assert client.get("/healthz").status_code == 200
        assert client.get("/v1/jobs").status_code == 200
        records = access_records(caplog)
        assert [r.getMessage().split('"')[1] for r in records] == ["GET /v1/jobs HTTP/1.1"]
        assert records[0].levelno == logging.INFO

        caplog.set_level(logging.DEBUG, logger="uvicorn.access")
        caplog.clear()
        assert client.get(f"/v1/jobs/{job_id}").status_code == 200
        assert client.get("/v1/jobs/0123456789abcdef0123456789abcdef").status_code == 404
        levels = {r.getMessage().split('"')[1]: r.levelno for r in access_records(caplog)}
    assert levels == {
        f"GET /v1/jobs/{job_id} HTTP/1.1": logging.DEBUG,
        "GET /v1/jobs/0123456789abcdef0123456789abcdef HTTP/1.1": logging.INFO,  # errors stay
    }


def test_a_key_in_the_query_string_is_redacted_in_every_log(live_api, caplog, monkeypatch):
    """The key is refused (only the Authorization header counts) and never written to a log:
    uvicorn's access log or any other (issue 29)."""
    for name in ("uvicorn", "uvicorn.access"):
        monkeypatch.setattr(logging.getLogger(name), "propagate", True)
    secret = "qhsm_0123abcd_" + "S" * 43
    caplog.set_level(logging.DEBUG)
    with httpx.Client(base_url=live_api.url) as client:
        refused = client.get(f"/v1/jobs?api_key={secret}&limit=2")
        assert refused.status_code == 401
        assert client.get(f"/healthz?token={secret}").status_code == 200
    logging.getLogger("qhsm.api").warning("asked for %s", f"/v1/x?key={secret}")
    records = access_records(caplog)
    assert any("api_key=[redacted]&limit=2" in r.getMessage() for r in records), records
    assert all(secret not in r.getMessage() for r in caplog.records)
