"""Uvicorn's access log without the polling: a client waiting for a job asks for its status
every second or so, and health checks come every few seconds, which buried everything else in
the serve terminal. Those requests are logged at DEBUG (shown with ``--log-level debug``)."""

from __future__ import annotations

import logging
import re

ACCESS_LOGGER = "uvicorn.access"
#: GETs that clients and orchestrators repeat: a job's status, liveness and readiness.
POLL_PATH = re.compile(r"^/(v1/jobs/[^/?]+|healthz|readyz)(\?.*)?$")


class PollsAtDebug(logging.Filter):
    """Moves successful poll requests of uvicorn's access log to DEBUG."""

    def filter(self, record: logging.LogRecord) -> bool:
        args = record.args
        # uvicorn logs '%s - "%s %s HTTP/%s" %d' with (client, method, path, version, status)
        if not isinstance(args, tuple) or len(args) != 5:
            return True
        _, method, path, _, code = args
        if method != "GET" or not POLL_PATH.match(str(path)) or int(str(code)) >= 400:
            return True
        record.levelno, record.levelname = logging.DEBUG, logging.getLevelName(logging.DEBUG)
        return logging.getLogger(record.name).isEnabledFor(logging.DEBUG)


def quiet_polls() -> None:
    """Install :class:`PollsAtDebug` on uvicorn's access logger (once per process)."""
    logger = logging.getLogger(ACCESS_LOGGER)
    if not any(isinstance(f, PollsAtDebug) for f in logger.filters):
        logger.addFilter(PollsAtDebug())
