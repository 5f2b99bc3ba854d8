"""Schemathesis over the OpenAPI document with a valid key, an admin's and a member's:
whatever the schema allows (and, in negative mode, what it does not), no request may end in a
5xx. At most 20 examples per operation and phase with the admin's key, 10 with the member's
(from 60 and 20, to keep the suite under 10 minutes: about 15 s here); the timeout caps a slow
machine."""

from __future__ import annotations

import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.config import (
    GenerationConfig,
    ProjectConfig,
    ProjectsConfig,
    SchemathesisConfig,
)

schema = schemathesis.pytest.from_fixture("openapi_schema")


@pytest.fixture(scope="module")
def openapi_schema(api):
    generation = GenerationConfig(modes=list(schemathesis.GenerationMode), max_examples=20)
    config = SchemathesisConfig(
        projects=ProjectsConfig(default=ProjectConfig(generation=generation))
    )
    return schemathesis.openapi.from_asgi("/openapi.json", api.app, config=config)


@pytest.fixture(scope="module")
def member_headers(api_settings) -> dict[str, str]:
    """A lab member's key (not an admin): the routes they may not use must say so with a 4xx."""
    import uuid

    from api.users import UserStore

    _, key = UserStore.from_settings(api_settings).create_user(f"member-{uuid.uuid4().hex[:6]}")
    return {"Authorization": f"Bearer {key}"}


def call_without_server_error(case, headers: dict[str, str]) -> None:
    response = case.call(headers=headers)
    if case.path == "/readyz" and response.status_code == 503:
        # its documented answer here: no worker consumes the control queue in these tests
        assert response.json()["status"] == "unavailable" and response.json()["redis"] == "ok"
        return
    assert response.status_code < 500, f"{case.method} {case.formatted_path}: {response.text}"


@schema.parametrize()
@settings(max_examples=20, deadline=None, suppress_health_check=list(HealthCheck))
@pytest.mark.timeout(120)
def test_no_request_ends_in_a_server_error(case, admin_headers):
    call_without_server_error(case, admin_headers)


@schema.parametrize()
@settings(max_examples=10, deadline=None, suppress_health_check=list(HealthCheck))
@pytest.mark.timeout(120)
def test_no_request_of_a_member_ends_in_a_server_error(case, member_headers):
    call_without_server_error(case, member_headers)
