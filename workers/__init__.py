"""Celery workers: ``celery -A workers worker -Q <queues>`` (see ``workers.app``).

``tasks`` wraps ``orchestration`` (a chord per pyramid level) on top of ``store`` (job records),
``quota`` (QPU budgets) and ``watchdog``; ``supervisor`` starts and restarts the worker processes
for ``qhsm serve`` / ``qhsm demo``, beside the ``embedded_redis`` server they share."""

from workers.app import app

__all__ = ["app"]
