"""Celery workers: ``celery -A workers worker -Q <queues>`` (see ``workers.app``).

``tasks`` wraps ``orchestration`` (a chord per pyramid level) on top of ``store`` (job records),
``quota`` (QPU budgets) and ``watchdog``; ``supervisor`` starts and restarts the worker processes
for ``qhsm serve`` / ``qhsm demo``, beside the ``embedded_redis`` server they share.

``app`` is imported on first use (PEP 562): ``qhsm match`` registers the service's commands from
``workers.cli`` and should not pay for Celery and redis-py to do so."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from celery import Celery

    app: Celery

__all__ = ["app"]


def __getattr__(name: str) -> Any:
    if name == "app":
        from workers.app import app

        return app
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
