"""The API alone (no workers) against a real Redis, under a unique key prefix."""

from __future__ import annotations

import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import pytest
import uvicorn
from fastapi import FastAPI

sys.path.insert(0, str(Path(__file__).parents[1] / "service"))  # harness + test plugin
sys.path.insert(0, str(Path(__file__).parent))  # api_helpers

import harness
from fastapi.testclient import TestClient

from api.app import create_app
from shared.config import Settings


@pytest.fixture(scope="session")
def api_settings(tmp_path_factory, redis_url):
    folder = tmp_path_factory.mktemp("api")
    settings = Settings(
        redis_url=redis_url,
        key_prefix=harness.unique_prefix(),
        data_dir=folder / "data",
        inspect_timeout=0.3,
        max_active_jobs_per_user=None,  # no worker runs here: accepted jobs stay queued
    )
    yield settings
    harness.drop_prefix(redis_url, settings.key_prefix)


@pytest.fixture(scope="session")
def admin_headers(api_settings) -> dict[str, str]:
    return {"Authorization": f"Bearer {harness.admin_key(api_settings)}"}


@pytest.fixture(scope="session")
def api(api_settings, admin_headers):
    with TestClient(
        create_app(api_settings), raise_server_exceptions=False, headers=admin_headers
    ) as client:
        yield client


@pytest.fixture(scope="session")
def make_client(api_settings, admin_headers):
    """A client of an app with some settings changed (limits, Redis URL)."""

    def build(**changes) -> TestClient:
        return TestClient(
            create_app(api_settings.model_copy(update=changes)),
            raise_server_exceptions=False,
            headers=admin_headers,
        )

    return build


@dataclass
class LiveApi:
    """The app behind a real uvicorn server (connections, logging and bodies as in production)."""

    app: FastAPI
    host: str
    port: int

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}"


@pytest.fixture(scope="session")
def live_api(api_settings):
    """A uvicorn server in a thread; ``log_config=None`` leaves logging to pytest (caplog)."""
    from workers.embedded_redis import free_port

    app = create_app(api_settings)
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_config=None))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started:
        assert thread.is_alive() and time.monotonic() < deadline, "uvicorn did not start"
        time.sleep(0.02)
    yield LiveApi(app, "127.0.0.1", port)
    server.should_exit = True
    thread.join(10)
