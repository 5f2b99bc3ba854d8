"""What the service stores about a job, as models: its state, record, per-chunk reports and
progress. :mod:`workers.store` keeps them in Redis; the API's schemas and the client read them."""

from __future__ import annotations

import logging
import math
import re
import uuid
from datetime import UTC, datetime
from enum import StrEnum
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from shared.config import MatchConfig

log = logging.getLogger(__name__)

JOB_ID = re.compile(r"^[0-9a-f]{32}$")


class JobState(StrEnum):
    QUEUED = "queued"
    RUNNING = "running"
    SUCCEEDED = "succeeded"
    FAILED = "failed"
    CANCELLED = "cancelled"

    @property
    def terminal(self) -> bool:
        return self in (JobState.SUCCEEDED, JobState.FAILED, JobState.CANCELLED)


ACTIVE = frozenset({JobState.QUEUED, JobState.RUNNING})


class GroundTruth(BaseModel):
    """Evaluation protocol of an uploaded ground truth (stored values = disparity x scale)."""

    scale: float = Field(1.0, gt=0, description="Stored value per pixel of disparity")
    border: int = Field(0, ge=0, description="Ignored frame, pixels")
    inferred: bool = Field(
        False, description="The scale was not given but inferred from the views (see warnings)"
    )


class JobRecord(BaseModel):
    """What the service knows about a job (storage model; API schemas are separate).

    Any float survives the JSON round trip (``Infinity``/``NaN`` are written as such, not as
    ``null``), so a stored record always loads again; in metrics and level reports, which
    clients read, numbers that are not finite are stored as null.
    """

    model_config = ConfigDict(ser_json_inf_nan="constants")

    id: str
    state: JobState = JobState.QUEUED
    owner: str | None = None
    config: MatchConfig
    width: int
    height: int
    label: str | None = None  # the submitter's name for the job
    files: list[str] = Field(default_factory=list)  # the uploads' file names: left, right
    #: What the submitter should know: views that look swapped, a scale that was inferred, ...
    warnings: list[str] = Field(default_factory=list)
    ground_truth: GroundTruth | None = None
    created_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None
    level: int = 0  # 1-based index of the level being solved; 0 before the first
    levels_total: int = 0  # levels of the run (the bin pyramid's depend on the range)
    bundles_total: int = 0  # bundles of that level
    #: ``shared.disparity_range.RangeEstimate`` as a dict: the range the job runs with
    disparity_range: dict[str, Any] | None = None
    levels: list[dict[str, Any]] = Field(default_factory=list)  # shared.pipeline.LevelReport
    metrics: dict[str, float | None] | None = None
    error: str | None = None

    @field_validator("metrics", "levels")
    @classmethod
    def _finite_or_null(cls, value: Any) -> Any:
        return finite_or_null(value)

    @field_validator("error")
    @classmethod
    def _bounded(cls, value: str | None) -> str | None:
        return bounded_message(value)


#: Longest message a record keeps (a solver's error may quote a whole problem); the workers'
#: log has the full text.
MAX_MESSAGE_CHARS = 2000


def bounded_message(message: str | None) -> str | None:
    """``message`` cut at :data:`MAX_MESSAGE_CHARS`, saying so."""
    if message is None or len(message) <= MAX_MESSAGE_CHARS:
        return message
    return message[:MAX_MESSAGE_CHARS] + " ... (cut; the full message is in the worker log)"


def finite_or_null(value: Any) -> Any:
    """``value`` with every float that is not finite (in nested dicts and lists) made None: what
    clients read must be valid JSON, which has no Infinity or NaN."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: finite_or_null(item) for key, item in value.items()}
    if isinstance(value, list):
        return [finite_or_null(item) for item in value]
    return value


def load_record(raw: bytes | str, job_id: str) -> JobRecord | None:
    """The stored record, or None (logged) when it no longer validates: one broken record must
    not make the job listings or the workers fail."""
    try:
        return JobRecord.model_validate_json(raw)
    except ValidationError as error:
        log.error("job %s: stored record does not load, skipped: %s", job_id, error)
        return None


class ChunkReport(BaseModel):
    """One solved task: how many bundles, the solver's summed timing (seconds), who solved it.

    Timing entries that are not finite numbers are dropped (they would poison the job's usage).
    """

    model_config = ConfigDict(ser_json_inf_nan="constants")

    level: int
    bundles: int
    wall_time: float
    timing: dict[str, float] = Field(default_factory=dict)
    worker: str = ""

    @field_validator("timing")
    @classmethod
    def _finite_timing(cls, value: dict[str, float]) -> dict[str, float]:
        return {key: seconds for key, seconds in value.items() if math.isfinite(seconds)}


class Progress(BaseModel):
    """How far a job is (the API's job status and the client's progress bar read this model)."""

    level: int = Field(description="1-based level being solved (0: not started)")
    levels: int
    bundles_done: int = Field(description="Bundles of the current level solved so far")
    bundles_total: int


def now() -> datetime:
    return datetime.now(UTC)


def new_job_id() -> str:
    return uuid.uuid4().hex
