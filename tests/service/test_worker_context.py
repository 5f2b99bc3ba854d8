"""A worker process's context (issue 30): built from its app's settings at process start, its
services made on first use on one connection, and made anew in a forked pool process."""

from __future__ import annotations

import pytest

from shared.config import Settings
from workers import context, fair


@pytest.fixture
def no_context(monkeypatch):
    monkeypatch.setattr(context, "_current", None)
    monkeypatch.setattr(fair.FewestRunningFirst, "settings", None)


def test_the_tasks_need_a_started_context(no_context):
    with pytest.raises(RuntimeError, match="start"):
        context.current()


def test_services_are_made_from_the_settings_on_one_connection(no_context):
    settings = Settings(key_prefix="qhsm-context-test", redis_url="redis://127.0.0.1:1/0")
    ctx = context.start(settings)
    assert context.current() is ctx and ctx.settings is settings
    assert fair.FewestRunningFirst.settings is settings  # kombu's queue order: the same Redis
    store = ctx.store  # no command sent: clients connect on first use
    assert store.settings is settings and ctx.store is store
    assert ctx.telemetry.redis is store.redis and ctx.estimates.redis is store.redis
    assert ctx.ledger.redis is store.redis and ctx.estimates.settings is settings


def test_the_pricing_ledger_keeps_the_deployments_budget_period(no_context):
    """The pricing's admission check counts a monthly deployment's month, not the lifetime."""
    settings = Settings(
        key_prefix="qhsm-context-test", redis_url="redis://127.0.0.1:1/0", budget_period="monthly"
    )
    assert context.start(settings).ledger.period == "monthly"


def test_a_pool_process_starts_its_own_services(no_context):
    """After the fork each pool process starts a context: nothing of the parent's is reused."""
    settings = Settings(key_prefix="qhsm-context-test", redis_url="redis://127.0.0.1:1/0")
    parent = context.start(settings)
    parent_store = parent.store
    child = context.start(settings)
    assert child is not parent and child.store is not parent_store
    assert child.store.redis is not parent_store.redis
