"""The service's refusals and the one place they become HTTP answers.

The job service (:mod:`api.job_service`) and the upload checks (:mod:`api.uploads`) raise
domain errors: a :class:`ServiceError` (a :class:`Refusal` kind and a message that says what to
do), or an error of the core (a budget too small, the active-job cap, an unknown solver, ...).
:func:`refusal_of` turns each into a status code and the ``detail`` text; ``create_app``
(:mod:`api.app`) answers every one of :data:`DOMAIN_ERRORS` with it. So a helper never raises
``HTTPException``, and bad input is a 4xx, never a 500.
"""

from __future__ import annotations

import errno
from enum import Enum

import redis

from shared.ground_truth import ScaleNotInferredError
from shared.solvers.errors import UnknownSolverError
from shared.solvers.params import InvalidSolverParamsError
from workers.quota import QuotaExceededError
from workers.store import ActiveJobsCapError


class Refusal(Enum):
    """Why a request is refused; the value is the HTTP status it is answered with."""

    MALFORMED = 400  # the request does not parse (params is not JSON)
    FORBIDDEN = 403  # not the caller's to do: a QPU budget too small
    NOT_FOUND = 404  # no such job, or not the caller's
    CONFLICT = 409  # the job's state does not allow it
    EXPIRED = 410  # the job's data has expired
    TOO_LARGE = 413  # a file or image above the limits
    UNSUPPORTED = 415  # not an image format the service reads
    INVALID = 422  # parameters, sizes or solver the service cannot use
    TOO_MANY = 429  # the owner's active-job cap, or too many of their estimates open


class ServiceError(Exception):
    """A request the service refuses: ``kind`` says why, ``message`` what to do instead."""

    def __init__(self, kind: Refusal, message: str):
        super().__init__(message)
        self.kind = kind
        self.message = message

    @property
    def status_code(self) -> int:
        return self.kind.value


class AdmissionError(ServiceError):
    """A job (or an estimate) refused before anything is stored or queued."""


class PricingBusyError(ServiceError):
    """The user already has ``max_estimates_per_user`` estimates waiting or computing."""

    def __init__(self, limit: int):
        super().__init__(
            Refusal.TOO_MANY,
            f"you already have {limit} estimates waiting or computing, the limit per user "
            "(QHSM_MAX_ESTIMATES_PER_USER); wait for one (GET /v1/estimates/{id}) or cancel "
            "one (DELETE /v1/estimates/{id}), then ask again",
        )


class EstimateNotFoundError(ServiceError):
    """No such estimate for the caller: it never existed, expired, or is someone else's."""

    def __init__(self, estimate_id: str, ttl_seconds: int):
        super().__init__(
            Refusal.NOT_FOUND,
            f"no estimate {estimate_id!r}: it never existed or expired (estimates are kept "
            f"{ttl_seconds} s); ask again with POST /v1/estimate",
        )


class JobNotFoundError(ServiceError):
    """No such job for the caller: it never existed, expired, or is someone else's."""

    def __init__(self, job_id: str, ttl_seconds: int):
        super().__init__(
            Refusal.NOT_FOUND,
            f"no job {job_id!r}: it never existed or its results expired "
            f"(results are kept {ttl_seconds} s)",
        )


class JobStateError(ServiceError):
    """The job's state does not allow what was asked (cancel a finished job, read a result
    that is not there yet)."""

    def __init__(self, message: str):
        super().__init__(Refusal.CONFLICT, message)


class ExpiredError(ServiceError):
    """A job's result or uploaded data has expired (its record may still be there)."""

    def __init__(self, job_id: str, what: str):
        super().__init__(Refusal.EXPIRED, f"the {what} of job {job_id} has expired")


class BatchPairError(ServiceError):
    """One pair of a batch refused (``POST /v1/batches``): its index, name and why, with the
    status the same refusal of a single job has; nothing of the batch was created."""


class BatchNotFoundError(ServiceError):
    """No such batch for the caller: it never existed, expired, or is someone else's."""

    def __init__(self, batch_id: str, ttl_seconds: int):
        super().__init__(
            Refusal.NOT_FOUND,
            f"no batch {batch_id!r}: it never existed, is someone else's, or expired with its "
            f"jobs (kept {ttl_seconds} s after it was made or last read)",
        )


def too_many_jobs(error: ActiveJobsCapError) -> str:
    """What a user at the per-user cap of jobs in flight is told."""
    return (
        f"user {error.owner!r} already has {error.active} jobs queued or running, the limit per "
        f"user (QHSM_MAX_ACTIVE_JOBS_PER_USER={error.cap}); wait for one to finish or cancel "
        "one (DELETE /v1/jobs/{id}), then submit again"
    )


#: Every error :func:`refusal_of` answers (``create_app`` registers one handler for each).
DOMAIN_ERRORS: tuple[type[Exception], ...] = (
    ServiceError,
    QuotaExceededError,
    ActiveJobsCapError,
    UnknownSolverError,
    InvalidSolverParamsError,
    ScaleNotInferredError,
)


def refusal_of(error: Exception) -> tuple[int, str]:
    """The HTTP status and ``detail`` of a domain error (one of :data:`DOMAIN_ERRORS`)."""
    if isinstance(error, ServiceError):
        return error.status_code, error.message
    if isinstance(error, QuotaExceededError):
        return Refusal.FORBIDDEN.value, str(error)
    if isinstance(error, ActiveJobsCapError):
        return Refusal.TOO_MANY.value, too_many_jobs(error)
    if isinstance(error, UnknownSolverError | InvalidSolverParamsError):
        return Refusal.INVALID.value, f"params: {error}"  # the form field that names them
    if isinstance(error, ScaleNotInferredError):
        return Refusal.INVALID.value, f"gt_scale: {error}"
    raise TypeError(f"not a domain error: {type(error).__name__}") from error


#: errno values of a full disk or an exhausted quota.
DISK_FULL = {errno.ENOSPC, errno.EDQUOT}
#: How Redis refuses writes when it cannot persist them (full disk) or is out of memory
#: (also quoted inside a pipeline's "Command # 1 (...) of pipeline caused error: ...").
REDIS_FULL = ("MISCONF ", "OOM command not allowed")


def full_storage(error: BaseException | None) -> BaseException | None:
    """The error in ``error``'s chain (itself or one it was raised from: kombu re-raises Redis's
    refusal to write a task message as its own ``ChannelError``) that says the service's storage
    is full: the data directory's disk, or Redis refusing writes it cannot persist; None when
    none does."""
    for _ in range(8):  # a chain, short in practice; never a cycle
        if error is None:
            return None
        if isinstance(error, OSError) and error.errno in DISK_FULL:
            return error
        if isinstance(error, redis.ResponseError) and any(s in str(error) for s in REDIS_FULL):
            return error
        error = error.__cause__ or error.__context__
    return None


def storage_full(error: BaseException | None) -> bool:
    """Whether ``error`` says the service's storage is full (:func:`full_storage`)."""
    return full_storage(error) is not None
