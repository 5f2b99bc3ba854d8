"""Leap, D-Wave's cloud, for the adapters that sample there (``qpu``, ``hybrid``): each holds
its way in by composition (the hybrid solver embeds nothing, so it is no QPU adapter).

The token, solver, region and endpoint come from ``Settings`` (``DWAVE_API_TOKEN``, ...); a
client sampler is built with them, its problems labelled (:mod:`shared.solvers.qpu.problems`);
the token is scrubbed from the cloud client's loggers and from every message: Ocean's
exceptions become our typed errors (:func:`translate`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import dimod

from shared.config import Settings
from shared.solvers.base import (
    Availability,
    SolverError,
    SolverUnavailableError,
    TransientSolverError,
)
from shared.solvers.qpu.cloud_errors import cause, is_connection_error, reached, scrub_cloud_logs
from shared.solvers.qpu.problems import LabelledSampler

TOKEN_HELP = "set DWAVE_API_TOKEN (and optionally DWAVE_SOLVER, DWAVE_API_REGION)"


def available(settings: Settings) -> Availability:
    """Whether a Leap sampler can run here: a token is configured."""
    if settings.dwave_api_token is None:
        return Availability(False, f"no D-Wave API token: {TOKEN_HELP}")
    return Availability(True, "DWAVE_API_TOKEN configured")


def secret(settings: Settings) -> str | None:
    """The token, to scrub from messages (None: none configured)."""
    token = settings.dwave_api_token
    return token.get_secret_value() if token is not None else None


def connect(
    name: str, factory: Callable[..., Any], settings: Settings, **options: Any
) -> LabelledSampler:
    """A Leap client sampler of solver ``name`` built with the token, region and endpoint of
    ``settings`` (the adapter's), labelling its problems and logging their ids; the token is
    scrubbed from the cloud client's loggers before and after."""
    if settings.dwave_api_token is None:
        raise SolverUnavailableError(f"{name}: no D-Wave API token: {TOKEN_HELP}")
    token = settings.dwave_api_token.get_secret_value()
    if settings.dwave_region:
        options["region"] = settings.dwave_region
    if settings.dwave_endpoint:
        options["endpoint"] = settings.dwave_endpoint
    scrub_cloud_logs(token)
    sampler = factory(token=token, **options)
    scrub_cloud_logs(token)  # loggers of modules the client imported lazily
    return LabelledSampler(sampler)


def scrub(text: str, token: str | None) -> str:
    """``text`` with ``token`` replaced by ``***``."""
    return text.replace(token, "***") if token else text


def translate(
    name: str, error: Exception, settings: Settings, token: str | None = None
) -> SolverError:
    """Ocean's exception ``error`` of solver ``name`` as our typed error, ``token`` scrubbed
    from the text.

    Parameters
    ----------
    name : str
        The solver, for the message.
    error : Exception
        What Ocean (the cloud client, dimod) raised.
    settings : Settings
        The adapter's (the endpoint or region a failed request was for).
    token : str, optional
        The secret to scrub (None: nothing to scrub, e.g. the simulator).

    Returns
    -------
    SolverError
        ``SolverUnavailableError`` (token, access, configuration), ``TransientSolverError``
        (rate limit, offline, timeouts, connection) or a ``SolverError`` saying what to do.
    """
    from dwave.cloud import exceptions as cloud
    from dwave.cloud.api import exceptions as api

    detail = scrub(f"{type(error).__name__}: {error}", token)
    if isinstance(error, cloud.SolverAuthenticationError | api.ResourceAuthenticationError):
        return SolverUnavailableError(
            f"{name}: D-Wave rejected the API token (authentication failed); check DWAVE_API_TOKEN"
        )
    if isinstance(error, api.ResourceAccessForbiddenError):
        return SolverUnavailableError(
            f"{name}: access to the D-Wave solver is forbidden for this token "
            "(check the project and solver access of the account)"
        )
    if isinstance(error, cloud.SolverNotFoundError):
        return SolverUnavailableError(
            f"{name}: no D-Wave solver matches the configuration "
            f"(DWAVE_SOLVER / DWAVE_API_REGION): {detail}"
        )
    if isinstance(error, api.ResourceLimitsExceededError):
        return TransientSolverError(
            f"{name}: D-Wave rate limit reached (HTTP 429) at "
            f"{scrub(reached(error, settings), token)}; retry later"
        )
    if isinstance(error, cloud.SolverOfflineError):
        return TransientSolverError(
            f"{name}: the D-Wave solver is offline ({scrub(reached(error, settings), token)}); "
            "retry later"
        )
    if isinstance(
        error,
        api.RequestTimeout
        | cloud.PollingTimeout
        | cloud.ProblemUploadError
        | api.InternalServerError
        | TimeoutError
        | ConnectionError,
    ) or is_connection_error(error):
        return TransientSolverError(
            f"{name}: D-Wave did not answer in time, refused, or the connection "
            f"failed: {scrub(reached(error, settings), token)} ({scrub(cause(error), token)}); "
            "retry later"
        )
    if isinstance(
        error,
        cloud.ProblemStructureError
        | dimod.exceptions.BinaryQuadraticModelStructureError
        | api.ResourceBadRequestError,
    ):
        return SolverError(
            f"{name}: D-Wave refused the problem as too large or not fitting the solver "
            f"({detail}); use smaller bundles (--bundle-height 1) or --encoding domain-wall"
        )
    if isinstance(error, cloud.ConfigFileError):
        return SolverUnavailableError(f"{name}: invalid D-Wave configuration: {detail}")
    return SolverError(f"{name}: D-Wave sampling failed: {detail}")
