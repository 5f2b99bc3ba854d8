"""The API alone (no workers) against a real Redis, under a unique key prefix."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parents[1] / "service"))  # harness + test plugin

import harness
from fastapi.testclient import TestClient

from api.app import create_app
from shared.config import Settings


@pytest.fixture(scope="session")
def api_settings(tmp_path_factory):
    folder = tmp_path_factory.mktemp("api")
    url, server = harness.find_redis(folder / "redis")
    settings = Settings(
        redis_url=url,
        key_prefix=harness.unique_prefix(),
        data_dir=folder / "data",
        plugins="qhsm_test_plugin",
        inspect_timeout=0.3,
    )
    yield settings
    harness.drop_prefix(url, settings.key_prefix)
    if server is not None:
        server.stop()


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
