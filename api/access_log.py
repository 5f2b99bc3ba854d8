"""Uvicorn's access log without the polling: a client waiting for a job asks for its status
every second or so, and health checks come every few seconds, which buried everything else in
the serve terminal. Those requests are logged at DEBUG (shown with ``--log-level debug``).

A key a client puts in the query string (``?api_key=...``; the service only reads the
``Authorization`` header and refuses it) is redacted in every log record of the process, the
access log's included: :func:`redact_secrets`."""

from __future__ import annotations

import logging
import re

ACCESS_LOGGER = "uvicorn.access"
#: A credential in a query string: its value is replaced by :data:`REDACTED` in every log.
SECRET_QUERY = re.compile(
    r"(?i)([?&;](?:api[_-]?key|key|token|access[_-]?token|secret|password)=)[^&;\s\"'#]*"
)
REDACTED = "[redacted]"
#: Quick test before the regular expression (most records have no query string at all).
_MAYBE_SECRET = re.compile(r"(?i)key=|token=|secret=|password=")


def redacted(value: object) -> object:
    """``value`` with the credentials of its query strings redacted: a string, or an object
    formatted as one (httpx logs its ``URL``), which then becomes the redacted string; numbers
    and None stay as they are (``%d`` formats them)."""
    if value is None or isinstance(value, int | float):
        return value
    text = value if isinstance(value, str) else str(value)
    if _MAYBE_SECRET.search(text):
        return SECRET_QUERY.sub(rf"\1{REDACTED}", text)
    return value


def redact_secrets() -> None:
    """Wrap the process's log record factory (once) so that every record, whichever logger
    makes it (uvicorn's access and error logs, ours, a library's), has query-string credentials
    redacted in its message and arguments before any handler sees it."""
    previous = logging.getLogRecordFactory()
    if getattr(previous, "redacts", False):
        return

    def factory(*args: object, **kwargs: object) -> logging.LogRecord:
        record = previous(*args, **kwargs)
        record.msg = redacted(record.msg)
        if isinstance(record.args, tuple):
            record.args = tuple(redacted(arg) for arg in record.args)
        elif isinstance(record.args, dict):
            record.args = {key: redacted(value) for key, value in record.args.items()}
        return record

    factory.redacts = True  # type: ignore[attr-defined]
    logging.setLogRecordFactory(factory)


#: GETs that clients and orchestrators repeat: a job's or an estimate's status, liveness and
#: readiness.
POLL_PATH = re.compile(r"^/(v1/jobs/[^/?]+|v1/estimates/[^/?]+|healthz|readyz)(\?.*)?$")


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
    """Install :class:`PollsAtDebug` on uvicorn's access logger (once per process), and the
    redaction of credentials in query strings (:func:`redact_secrets`)."""
    redact_secrets()
    logger = logging.getLogger(ACCESS_LOGGER)
    if not any(isinstance(f, PollsAtDebug) for f in logger.filters):
        logger.addFilter(PollsAtDebug())
