"""What the D-Wave cloud's failures and logs need before anyone sees them: the API token masked in
dwave-cloud-client's logs, and a failed request's endpoint and innermost cause named (the
messages of :func:`shared.solvers.qpu.leap.translate`)."""

from __future__ import annotations

import logging

from shared.config import Settings


class _TokenScrubber(logging.Filter):
    """Replaces the API token in log records: dwave-cloud-client logs its whole configuration,
    token included, at DEBUG level when a client is created."""

    def __init__(self, secret: str) -> None:
        super().__init__()
        self.secret = secret

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        if self.secret in message:
            record.msg, record.args = message.replace(self.secret, "***"), ()
        return True


def scrub_cloud_logs(secret: str) -> None:
    """Put a :class:`_TokenScrubber` on every ``dwave.cloud`` logger (a filter on a parent logger
    does not see its children's records, so each one gets its own).

    Parameters
    ----------
    secret : str
        The API token to mask as ``***``; a logger that already has a filter for it gets no other.
    """
    names = [n for n in list(logging.root.manager.loggerDict) if n.startswith("dwave.cloud.")]
    for name in ["dwave.cloud", *names]:
        logger = logging.getLogger(name)
        if not any(getattr(f, "secret", None) == secret for f in logger.filters):
            logger.addFilter(_TokenScrubber(secret))


def is_connection_error(error: Exception) -> bool:
    """Whether a request failed before an answer (refused, unreachable, timed out)."""
    import requests

    return isinstance(error, requests.ConnectionError | requests.Timeout)


def _chain(error: BaseException) -> list[BaseException]:
    """``error`` and the errors it was raised from or during, outermost first."""
    seen: list[BaseException] = []
    current: BaseException | None = error
    while current is not None and current not in seen:
        seen.append(current)
        current = current.__cause__ or current.__context__
    return seen


def reached(error: BaseException, settings: Settings) -> str:
    """Which endpoint a failed request was for: its URL (without the query), else the
    configured ``DWAVE_API_ENDPOINT``, else the region Leap's default endpoint serves."""
    for link in _chain(error):
        url = getattr(getattr(link, "request", None), "url", None)
        if url:
            return f"endpoint {str(url).split('?')[0]}"
    if settings.dwave_endpoint:
        return f"endpoint {settings.dwave_endpoint}"
    from dwave.cloud.config.constants import DEFAULT_REGION

    return f"the Leap endpoint of region {settings.dwave_region or DEFAULT_REGION}"


def cause(error: BaseException) -> str:
    """The innermost reason of a failed request, e.g. ``ConnectionRefusedError: [Errno 111]
    Connection refused`` (the outer ones only wrap it)."""
    inner = _chain(error)[-1]
    reason = getattr(inner, "reason", None)  # urllib3's errors wrap the socket's
    if isinstance(reason, BaseException):
        inner = reason
    return f"{type(inner).__name__}: {inner}"
