"""Celery workers: ``celery -A workers worker -Q <queues>`` (see ``workers.app``)."""

from workers.app import app

__all__ = ["app"]
