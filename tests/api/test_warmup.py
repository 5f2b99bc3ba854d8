"""The API builds at start what its first request used to build (issue 29: the process's first
``POST /v1/estimate`` answers as fast as the rest; api/warmup.py says what was measured)."""

from __future__ import annotations

import gc
import json
import logging
import sys

import fastapi.routing
import pytest
from api_helpers import LEFT, RIGHT
from celery.app import backends
from fastapi.testclient import TestClient

from api.app import create_app
from shared.solvers import registry


def refuse(what: str):
    def built(*args, **kwargs):
        raise AssertionError(f"{what} was built by a request, not at start")

    return built


#: Packages whose modules the first estimate used to import (Celery's result backend, the
#: solver's adapter).
LAZY = ("celery", "kombu", "shared", "api", "workers", "dwave", "dimod")


def test_the_first_estimate_builds_nothing_the_start_built(api_settings, admin_headers):
    """After start, a route's models and a solver's sampler are never built again (each is
    made to fail, and the first estimate is still answered), nothing is imported, and what
    start-up built is out of the collector's way (frozen: no full collection in a request)."""
    gc.unfreeze()
    with TestClient(create_app(api_settings), headers=admin_headers) as client:
        assert gc.get_freeze_count() > 0
        before = set(sys.modules)
        with pytest.MonkeyPatch.context() as patch:
            # FastAPI (0.16x) builds a route's dependency models the first time a request
            # walks past it; a FastAPI that stops doing so fails here (then drop the warm-up)
            patch.setattr(
                fastapi.routing._EffectiveRouteContext, "from_api_route", refuse("a route")
            )
            patch.setattr(registry, "build", refuse("a solver's sampler"))
            files = {"left": ("l.png", LEFT), "right": ("r.png", RIGHT)}
            params = {"params": json.dumps({"solver": "qpu-sim", "max_disparity": 6})}
            answer = client.post("/v1/estimate", files=files, data=params)
            assert answer.status_code == 202, answer.text
            assert client.get("/healthz").status_code == 200
        imported = sorted(name for name in set(sys.modules) - before if name.startswith(LAZY))
        assert imported == [], imported
        client.delete(answer.json()["links"]["self"])


def test_a_part_that_cannot_be_built_at_start_is_left_to_its_first_use(
    api_settings, admin_headers, monkeypatch, caplog
):
    """A broken optional part (here the result backend) never stops the API starting; the
    request that needs it reports it as before."""
    monkeypatch.setattr(backends, "by_url", refuse("Celery's result backend"))
    app = create_app(api_settings)
    with caplog.at_level(logging.WARNING, logger="qhsm.api"), TestClient(app) as client:
        assert client.get("/healthz").status_code == 200
    assert "warm-up of celery failed (loaded on first use)" in caplog.text
