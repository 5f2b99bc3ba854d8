"""What the service stores about a job, as models: its state, record, per-chunk reports and
progress. :mod:`workers.store` keeps them in Redis; the API's schemas and the client read them."""

from __future__ import annotations

import logging
import math
import re
import uuid
from collections.abc import Iterable
from dataclasses import asdict
from datetime import UTC, datetime
from enum import StrEnum
from typing import TYPE_CHECKING, Any

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from shared.config import MatchConfig
from shared.datasets.calibration import Calibration
from shared.disparity_range import RangeEstimate
from shared.level_report import LevelReport
from shared.wire import model_of

log = logging.getLogger(__name__)

JOB_ID = re.compile(r"^[0-9a-f]{32}$")


class JobState(StrEnum):
    #: A metered job being priced on a worker (``workers.pricing``): its estimate is checked
    #: against its owner's budget before it is queued
    PRICING = "pricing"
    QUEUED = "queued"
    RUNNING = "running"
    SUCCEEDED = "succeeded"
    FAILED = "failed"
    CANCELLED = "cancelled"

    @property
    def terminal(self) -> bool:
        return self in (JobState.SUCCEEDED, JobState.FAILED, JobState.CANCELLED)


ACTIVE = frozenset({JobState.PRICING, JobState.QUEUED, JobState.RUNNING})

#: Every change of a job's state, from -> to: the one table a record's writes are checked against
#: (:meth:`workers.store.JobStore.apply`). A record may also change without changing its state
#: (a level's progress while running). Pricing -> queued is a metered job admitted within its
#: owner's budget; running -> queued is the watchdog's restart; a final state is never left.
TRANSITIONS: dict[JobState, frozenset[JobState]] = {
    JobState.PRICING: frozenset({JobState.QUEUED, JobState.FAILED, JobState.CANCELLED}),
    JobState.QUEUED: frozenset({JobState.RUNNING, JobState.FAILED, JobState.CANCELLED}),
    JobState.RUNNING: frozenset(
        {JobState.QUEUED, JobState.SUCCEEDED, JobState.FAILED, JobState.CANCELLED}
    ),
    JobState.SUCCEEDED: frozenset(),
    JobState.FAILED: frozenset(),
    JobState.CANCELLED: frozenset(),
}


def allowed(before: JobState, after: JobState) -> bool:
    """Whether a record in state ``before`` may be written in state ``after``."""
    return before is after or after in TRANSITIONS[before]


class TransitionError(RuntimeError):
    """A change wrote a state :data:`TRANSITIONS` does not allow (a bug, not a race)."""


class GroundTruth(BaseModel):
    """Evaluation protocol of an uploaded ground truth (stored values = disparity x scale)."""

    scale: float = Field(1.0, gt=0, description="Stored value per pixel of disparity")
    border: int = Field(0, ge=0, description="Ignored frame, pixels")
    inferred: bool = Field(
        False, description="The scale was not given but inferred from the views (see warnings)"
    )


class Cameras(BaseModel):
    """A rectified pair's cameras as given at submit: what the job's depth and point cloud
    need (:class:`shared.datasets.calibration.Calibration`; the principal point defaults to
    the image's centre)."""

    focal: float = Field(gt=0, description="Focal length, pixels")
    baseline: float = Field(gt=0, description="Distance between the cameras (depth's unit)")
    doffs: float = Field(0.0, description="cx(right) - cx(left), pixels (Middlebury's doffs)")
    cx: float | None = Field(None, description="Principal point, px (None: the centre)")
    cy: float | None = None
    unit: str = Field("", description="The baseline's unit, when a calibration file says")

    @classmethod
    def of(cls, calibration: Calibration) -> Cameras:
        """What a calibration file gives (:mod:`shared.datasets.calibration`)."""
        return cls(
            focal=calibration.focal, baseline=calibration.baseline, doffs=calibration.doffs,
            cx=calibration.cx, cy=calibration.cy, unit=calibration.unit,
        )  # fmt: skip

    def calibration(self, width: int, height: int) -> Calibration:
        cx = (width - 1) / 2 if self.cx is None else self.cx
        cy = (height - 1) / 2 if self.cy is None else self.cy
        return Calibration(self.focal, cx, cy, self.baseline, self.doffs, self.unit, source="job")


class _LevelRecordBase(BaseModel):
    """What :data:`LevelRecord` adds to the core's fields: unknown fields kept, numbers that are
    not finite stored as null, and :meth:`of`."""

    model_config = ConfigDict(extra="allow", ser_json_inf_nan="constants")

    @model_validator(mode="before")
    @classmethod
    def _finite_or_null(cls, value: Any) -> Any:
        return finite_or_null(value)

    @classmethod
    def of(cls, report: LevelReport) -> Any:
        """The record of a level's report (a :data:`LevelRecord`)."""
        return cls.model_validate(asdict(report))


#: One assembled level as the record keeps it: :class:`shared.level_report.LevelReport`'s
#: fields, derived from it (declared once, in the core), every number nullable (not finite:
#: null), with the defaults a record written before a field existed reads as. Fields it does
#: not name are kept (a report field added later, or read from a newer worker).
if TYPE_CHECKING:
    LevelRecord = _LevelRecordBase  # its fields are the report's, made at import
else:
    LevelRecord = model_of(
        LevelReport,
        "LevelRecord",
        base=_LevelRecordBase,
        nullable_numbers=True,
        defaults={
            "downsample": 1,
            "bin_width": 1,
            "views": 1,
            "lower_bound": None,
            "gap": None,
            "repaired": 0,
        },
        module=__name__,
        doc=_LevelRecordBase.__doc__,
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
    tags: list[str] = Field(default_factory=list)  # the submitter's tags (list filter)
    batch: str | None = None  # the batch it was submitted in (POST /v1/batches)
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
    #: The range the job runs with (given, or estimated when it started)
    disparity_range: RangeEstimate | None = None
    levels: list[LevelRecord] = Field(default_factory=list)  # the levels assembled so far
    #: A metered job's estimated seconds per level when it was accepted: what its workers
    #: reserve for the level's bundles (None: not metered, or accepted before this was kept).
    estimate_seconds: list[float] | None = None
    metrics: dict[str, float | None] | None = None
    error: str | None = None
    #: The qhsm version that accepted the job (None: a record from before versions were kept)
    version: str | None = None
    #: The API sent the job's start (False from the write until then): a queued job whose start
    #: was never sent (its submit failed, e.g. on a full disk) is failed by the watchdog, never
    #: started later, so the client's retry is the only run
    dispatched: bool = True
    #: Estimated peak memory of a worker process running it, MiB (``shared.memory``); None
    #: until its range is known
    memory_mb: int | None = None
    #: The cameras given at submit (None: no depth or point cloud for the job)
    cameras: Cameras | None = None
    #: Kept past the retention (``result_ttl_seconds``) until unpinned
    pinned: bool = False
    #: The maps saved beside the result (``validity``, ``confidence``, ``provenance``: those
    #: the run has)
    maps: list[str] = Field(default_factory=list)
    #: Pixels of the provenance map per stage (``shared.provenance_map.counts``); None before
    #: the job succeeded
    provenance_counts: dict[str, int] | None = None
    #: While pricing: what the pricing worker is doing (``workers.pricing.STAGES``)
    pricing_stage: str | None = None
    #: While pricing: the share of the job's levels priced so far (0-1)
    pricing_fraction: float | None = None

    @field_validator("metrics")
    @classmethod
    def _finite_or_null(cls, value: Any) -> Any:
        return finite_or_null(value)

    def level_estimate(self, index: int) -> float | None:
        """The accepted estimate of level ``index`` (0-based), seconds; None when not kept."""
        if self.estimate_seconds is None or index >= len(self.estimate_seconds):
            return None
        return self.estimate_seconds[index]

    @field_validator("error")
    @classmethod
    def _bounded(cls, value: str | None) -> str | None:
        return bounded_message(value)

    # State changes: pure, each the record as it is to be written, or None where it does not
    # apply to the record as it is now (the job ended or moved on meanwhile: a race, not an
    # error). The store applies them atomically (JobStore.apply).

    def moved(
        self,
        to: JobState,
        at: datetime,
        allowed_from: Iterable[JobState] | None = None,
        **fields: Any,
    ) -> JobRecord | None:
        """In state ``to`` with ``fields`` (stamped ``at``: ``started_at`` when it runs,
        ``finished_at`` when it ends), if :data:`TRANSITIONS` allows it from the current state
        (and ``allowed_from`` has it)."""
        if self.state is to or not allowed(self.state, to):
            return None
        if allowed_from is not None and self.state not in set(allowed_from):
            return None
        updates = {"state": to, **fields}
        if to is JobState.RUNNING:
            updates.setdefault("started_at", at)
        if to is JobState.QUEUED:  # queued again: nothing of the run so far is kept
            updates |= {"level": 0, "bundles_total": 0, "levels": []}
        if to.terminal:
            updates.setdefault("finished_at", at)
        return self.model_copy(update=updates)

    def pricing_at(self, stage: str, fraction: float | None = None) -> JobRecord | None:
        """The pricing job's current stage and share of its levels priced; None once it is no
        longer pricing (or nothing changed)."""
        if self.state is not JobState.PRICING:
            return None
        if (self.pricing_stage, self.pricing_fraction) == (stage, fraction):
            return None
        return self.model_copy(update={"pricing_stage": stage, "pricing_fraction": fraction})

    def priced(
        self,
        at: datetime,
        estimate_seconds: list[float],
        disparity_range: RangeEstimate | None,
        levels_total: int,
        memory_mb: int | None,
    ) -> JobRecord | None:
        """The priced job admitted within its owner's budget: queued with its levels'
        estimate (what its workers reserve), its range and memory when the pricing resolved
        them (the range's warning first among the warnings), its start not yet sent."""
        warnings = self.warnings
        if disparity_range is not None and disparity_range.warning:
            warnings = [disparity_range.warning, *warnings]
        return self.moved(
            JobState.QUEUED,
            at,
            allowed_from=(JobState.PRICING,),
            estimate_seconds=estimate_seconds,
            disparity_range=disparity_range or self.disparity_range,
            levels_total=levels_total,
            memory_mb=memory_mb,
            warnings=warnings,
            pricing_stage=None,
            pricing_fraction=None,
            dispatched=False,
        )

    def started(self, at: datetime) -> JobRecord | None:
        """A queued job begins."""
        return self.moved(JobState.RUNNING, at)

    def with_range(
        self, estimate: RangeEstimate, levels_total: int, also: tuple[str, ...] = ()
    ) -> JobRecord | None:
        """The running job's disparity range, the levels it makes, and the views' warning
        (then ``also``: a range the preset's pyramid does not serve) first among the warnings;
        None once a range is recorded."""
        if self.state is not JobState.RUNNING or self.disparity_range is not None:
            return None
        notes = [estimate.warning] if estimate.warning else []
        notes += also
        return self.model_copy(
            update={
                "disparity_range": estimate,
                "levels_total": levels_total,
                "warnings": [*notes, *self.warnings],
            }
        )

    def at_level(self, index: int, total: int, launched_here: bool = True) -> JobRecord | None:
        """Level ``index`` current with ``total`` bundles (0 while planned elsewhere); without
        ``launched_here`` only a current level not fanned out yet takes its count."""
        if self.state is not JobState.RUNNING:
            return None
        if not launched_here and (self.level != index + 1 or self.bundles_total):
            return None
        return self.model_copy(update={"level": index + 1, "bundles_total": total})

    def with_level(self, index: int, report: LevelRecord) -> JobRecord | None:
        """Level ``index``'s report appended; None unless it is the next one (a repeated
        fan-in of the same level adds nothing)."""
        if self.state is not JobState.RUNNING or len(self.levels) != index:
            return None
        return self.model_copy(update={"levels": [*self.levels, report]})

    def succeeded(
        self,
        at: datetime,
        metrics: dict[str, float | None] | None,
        warning: str | None = None,
        maps: list[str] | None = None,
        provenance_counts: dict[str, int] | None = None,
    ) -> JobRecord | None:
        """The running job's end, with its scores, a warning about them (kept as its
        ``error``), the names of the maps saved beside the result and the provenance map's
        pixels per stage."""
        fields: dict[str, Any] = {
            "metrics": finite_or_null(metrics),
            "maps": maps or [],
            "provenance_counts": provenance_counts,
        }
        if warning:
            fields["error"] = warning
        return self.moved(JobState.SUCCEEDED, at, **fields)

    def failed(self, at: datetime, message: str) -> JobRecord | None:
        """An active job fails, telling the user why."""
        return self.moved(JobState.FAILED, at, error=bounded_message(message))

    def cancelled(self, at: datetime) -> JobRecord | None:
        return self.moved(JobState.CANCELLED, at)

    def pinned_as(self, pinned: bool) -> JobRecord | None:
        """Pinned (kept past the retention) or not; None when it already is."""
        return None if self.pinned is pinned else self.model_copy(update={"pinned": pinned})

    def restarted(self, at: datetime, level: int) -> JobRecord | None:
        """Queued again from its uploads (the watchdog), if still running at ``level``."""
        if self.state is not JobState.RUNNING or self.level != level:
            return None
        return self.moved(JobState.QUEUED, at)


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
    """One solved task: how many bundles, the solver's summed timing (seconds), who solved it,
    and the D-Wave problems it sent (their ids, to find them on Leap).

    Timing entries that are not finite numbers are dropped (they would poison the job's usage).
    """

    model_config = ConfigDict(ser_json_inf_nan="constants")

    level: int
    bundles: int
    wall_time: float
    timing: dict[str, float] = Field(default_factory=dict)
    worker: str = ""
    #: Ids SAPI gave the D-Wave problems the task sent (``shared.solvers.qpu.problems``), in order.
    problem_ids: list[str] = Field(default_factory=list)

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
    phase: str | None = Field(
        None,
        description="While the level is prepared (bundles_total 0): what it is doing, e.g. "
        "'embedding a 64-variable tile shape into Pegasus P16: sublattice m=4 (1/4), 10 tries'",
    )
    stage: str | None = Field(
        None, description="While pricing: what the pricing worker is doing (range, survey, ...)"
    )
    fraction: float | None = Field(
        None,
        description="While pricing: the share of the levels priced so far (0-1; null before "
        "a pricing worker has taken the job)",
    )


def now() -> datetime:
    return datetime.now(UTC)


def new_job_id() -> str:
    return uuid.uuid4().hex
