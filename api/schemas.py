"""API schemas: what clients send and receive (separate from the storage records in
``workers.store``, so the wire format can stay stable while storage changes)."""

from __future__ import annotations

import math
from datetime import datetime
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel, ConfigDict, Field, create_model

from shared.config import MatchConfig
from shared.disparity_range import RangeEstimate
from shared.metrics import Scores
from shared.settings import BudgetPeriod
from shared.wire import model_of
from workers.estimates import EstimateRecord, EstimateState
from workers.records import Cameras, GroundTruth, JobState, LevelRecord, Progress

if TYPE_CHECKING:
    from workers.quota.ledger import UserUsage as LedgerUsage


class Links(BaseModel):
    self: str
    disparity: str
    preview: str
    validity: str | None = Field(
        None, description="Left-right check's validity map (8-bit PNG, 255 = confirmed)"
    )
    confidence: str | None = Field(None, description="Confidence map in [0, 1] (PFM or npy)")
    provenance: str | None = Field(
        None,
        description="Provenance map: which stage decided each pixel (colour PNG, or npy of the "
        "codes; legend: GET /v1/provenance-legend, README)",
    )
    depth: str | None = Field(
        None, description="Depth map in the baseline's unit (jobs submitted with cameras)"
    )
    points: str | None = Field(None, description="Coloured point cloud (binary PLY)")


class LegendEntry(BaseModel):
    """One code of the provenance map (``shared.provenance_map.legend``)."""

    code: int
    name: str
    colour: str = Field(description="Its colour in the PNG, RGB hex")
    meaning: str


class JobCreated(BaseModel):
    id: str
    state: JobState
    links: Links
    warnings: list[str] = Field(
        default_factory=list,
        description="What you should know before it runs: views that look swapped or not "
        "rectified, a ground-truth scale that was inferred",
    )


#: What the job status says of a level's fields (the OpenAPI descriptions); the fields themselves
#: are the core's (:class:`shared.level_report.LevelReport`, as the record keeps them).
LEVEL_DOCS = {
    "bin_width": "Disparity-bin width of the level's labels (px)",
    "views": "2 when the right view is matched too (rows stacked)",
    "energy": "MRF energy of the level (null if not finite)",
    "lower_bound": "A lower bound on the level's least energy (grid inference with exact: "
    "the dual decomposition's), null when the solver gives none",
    "gap": "(energy - lower_bound) / energy: how far above the optimum the level's "
    "labelling can be, at most",
    "repaired": "Pixels whose QUBO sample was not a valid label encoding (one-hot: no or "
    "several bits set; domain-wall: a broken wall) and that were given their cheapest "
    "label next to their valid neighbours; 0 for the exact row solver",
    "residual": "Grid inference with a QUBO solver (shared.settle): the level's pixels, "
    "those the host's dual decomposition certified (row and column copies agree) and left "
    "unsettled, the 4x4 tiles sent and their pixels, the tiles and pixels whose solver "
    "answer lowered the energy and replaced the host's (tiles_improved, pixels_improved), "
    "and the host's seconds; null for other solvers",
    "termination": "Why the level's minimisation stopped: optimal (every bundle proven "
    "optimal), gap (a grid reached dual_gap), iterations (a grid reached dual_iterations), "
    "sampled (the QUBO solver's answers), settled (the host settled every pixel, nothing "
    "sent); null from an older worker",
    "provenance_counts": "The level's pixels (every view) per stage that decided them as "
    "solved (certified, host, roof_duality, solver, repaired; the job's provenance_counts "
    "are the final map's)",
}


class _FromRecord(BaseModel):
    model_config = ConfigDict(from_attributes=True)


if TYPE_CHECKING:
    LevelTiming = Any  # made at import from the record's fields
else:
    LevelTiming = model_of(
        LevelRecord,
        "LevelTiming",
        base=_FromRecord,
        exclude={"info"},
        docs=LEVEL_DOCS,
        module=__name__,
        doc="""One pyramid level of a job's status; times in seconds.

    The wire form of ``shared.level_report.LevelReport`` as the job record keeps it
    (``workers.records.LevelRecord``: numbers that are not finite are null, as JSON has no
    Infinity), derived from it (a field is declared once, in the core) less the report's
    ``info`` (the solver's embedding notes), with the OpenAPI descriptions of
    :data:`LEVEL_DOCS`.""",
    )


def nullable(model: type[BaseModel], name: str, doc: str) -> type[BaseModel]:
    """The wire form of ``model``: the same fields (descriptions included), each of them null
    where the value is not a finite number (JSON has no Infinity or NaN)."""
    fields: dict[str, Any] = {}
    for field_name, field in model.model_fields.items():
        annotation: Any = field.annotation  # a type at run time
        default = ... if field.is_required() else field.default  # records from before a field
        fields[field_name] = (annotation | None, Field(default, description=field.description))
    return create_model(name, __doc__=doc, __module__=__name__, **fields)


if TYPE_CHECKING:
    Metrics = Any  # made at import from Scores: its fields are known at run time only
else:
    Metrics = nullable(
        Scores,
        "Metrics",
        "Scores against the uploaded ground truth (``shared.metrics.Scores``); null where a "
        "score is not a finite number.",
    )


def record_fields(model: type[BaseModel], record: BaseModel) -> dict[str, Any]:
    """The fields ``model`` shares with ``record`` by name, read from it: a value the wire sends
    as it is stored is declared on the record and on the wire model (with its description),
    and copied by no hand-written list."""
    stored = type(record).model_fields
    return {name: getattr(record, name) for name in model.model_fields if name in stored}


class JobSummary(BaseModel):
    """What a job list shows; :class:`JobStatus` adds the details."""

    id: str
    owner: str | None = Field(None, description="User who submitted the job")
    label: str | None = Field(None, description="The name the submitter gave the job")
    tags: list[str] = Field(
        default_factory=list, description="The submitter's tags (GET /v1/jobs?tag= filters)"
    )
    files: list[str] = Field(
        default_factory=list, description="File names of the uploaded views: left, right"
    )
    batch: str | None = Field(None, description="The batch it was submitted in (/v1/batches)")
    state: JobState
    solver: str
    width: int
    height: int
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    metrics: Metrics | None = None
    qpu_seconds: float | None = Field(
        None,
        description="QPU access (hybrid: charge) seconds charged to the job so far; null for "
        "solvers that are not metered",
    )
    memory_mb: int | None = Field(
        None,
        description="Estimated peak memory of a worker process running the job, MiB (null "
        "until its disparity range is known); a job above a worker's budget is refused",
    )
    pinned: bool = Field(
        False, description="Kept past the retention until unpinned (POST/DELETE .../pin)"
    )
    links: Links

    @classmethod
    def fields_of(cls, record, links: Links, qpu_seconds: float | None = None) -> dict:
        """The fields of a job record (``workers.records.JobRecord``) for this model (a
        summary, or with :class:`JobStatus` the details the record keeps): those it shares
        with the record by name (:func:`record_fields`), the config's solver, the charge and
        the links; the caller adds what the record does not keep."""
        return {
            **record_fields(cls, record),
            "solver": record.config.solver,
            "qpu_seconds": qpu_seconds,
            "links": links,
        }


class JobStatus(JobSummary):
    progress: Progress
    levels: list[LevelTiming]
    usage: dict[str, float] = Field(
        description="Solver time spent so far, seconds (solver_seconds, qpu_access_time, ...)"
    )
    problem_ids: list[str] = Field(
        default_factory=list,
        description="The ids SAPI gave the job's D-Wave problems (QPU, hybrid), by level: find "
        "them on Leap, where each is labelled 'qhsm job <id> level <n> bundle <first> #k'",
    )
    error: str | None = None
    warnings: list[str] = Field(
        default_factory=list,
        description="Views that look swapped or not rectified, an inferred ground-truth "
        "scale: what to check",
    )
    ground_truth: GroundTruth | None = Field(
        None, description="How the uploaded ground truth is scored (none: no metrics)"
    )
    config: MatchConfig
    disparity_range: RangeEstimate | None = Field(
        None, description="The disparity range used: given, or estimated (max_disparity auto)"
    )
    version: str | None = Field(
        None, description="The qhsm version that ran the job (with config: preset, solver)"
    )
    cameras: Cameras | None = Field(
        None, description="The cameras given at submit (calib or focal/baseline/doffs)"
    )
    expires_at: datetime | None = Field(
        None,
        description="When the job's record, uploads and result are deleted (finished_at + "
        "QHSM_RESULT_TTL_SECONDS); null while it runs or while pinned",
    )
    provenance_counts: dict[str, int] | None = Field(
        None,
        description="Pixels of the provenance map per stage that decided them (filled, "
        "certified, host, roof_duality, solver, repaired, filtered); null until it succeeded",
    )


class JobPage(BaseModel):
    items: list[JobSummary]
    total: int
    offset: int
    limit: int
    next: str | None = Field(None, description="URL of the next page, if any")


class SolverInfo(BaseModel):
    """One solver as the registry declares it (``shared.solvers.registry.SolverSpec``)."""

    name: str
    description: str
    available: bool = Field(description="Usable by a job: runnable here or a worker consumes it")
    available_here: bool = Field(description="The solver can run in the API's environment")
    reason: str
    offline: bool = Field(description="An offline stand-in for a cloud service")
    metered: bool = Field(description="Jobs spend (real or simulated) QPU/hybrid budget")
    uses_qpu_time: bool = Field(description="Spends real D-Wave time (needs the token)")
    row_solver: bool = Field(description="Solves whole rows on the MRF costs, not a QUBO")
    queue: str
    workers: list[str] | None = Field(
        description="Workers consuming the queue (None: the workers did not answer in time)"
    )


class Health(BaseModel):
    status: str
    redis: str | None = None
    storage: str | None = Field(
        None,
        description='"ok", or "full: ..." naming what is full (the data directory\'s disk, or '
        "Redis refusing writes it cannot persist): submits are then answered 507",
    )
    queues_without_consumer: list[str] | None = Field(
        None,
        description="The control queue and solver queues no worker consumes (null: unknown); "
        "jobs for those solvers wait until one starts",
    )


class LevelEstimate(BaseModel):
    """One pyramid level of an estimate: bundle count x per-bundle metered time.

    The wire form of ``shared.solvers.meters.qpu_time.LevelEstimate`` (its ``as_dict``): height and
    width instead of its ``shape`` tuple, and the derived ``bundles_sent`` and
    ``classical_share`` as fields. Built only by ``Estimate.of``."""

    index: int
    height: int
    width: int
    bundles: int
    bundles_sent: int = Field(
        description="Bundles expected to reach the metered solver; the host solves the others "
        "exactly (the host's settling, roof duality), charged nothing"
    )
    classical_share: float = Field(description="Share of the bundles solved classically")
    variables_share: float = Field(description="Share of the variables sent to the solver")
    variables_per_bundle: int
    qubits_per_bundle: int | None = Field(
        description="QPU qubits per bundle the estimate used (null: hybrid, no embedding)"
    )
    embedding_known: bool = Field(
        description="true: an actual embedding of this bundle shape; false: the assumption of "
        "2 qubits per variable (no job has embedded this shape yet)"
    )
    pixels_certified: int | None = Field(
        None,
        description="Grid inference with a QUBO solver: pixels the host's dual decomposition "
        "settles (row and column copies agree); null without a survey",
    )
    pixels_sent: int | None = Field(
        None,
        description="Pixels in the 4x4 tiles around the unsettled ones, the only ones sent",
    )
    seconds: float


class Estimate(BaseModel):
    """What a job would be charged, before it is run (``POST /v1/estimate``).

    The wire form of ``shared.solvers.meters.qpu_time.JobEstimate`` (its ``as_dict``: the derived
    ``metered``, ``bundles_sent`` and ``classical_share`` as fields) plus what the request
    resolved and the caller's budget; built by ``of``."""

    solver: str
    metered: bool = Field(description="false: the solver spends no QPU/hybrid budget")
    seconds: float = Field(description="Estimated QPU access (hybrid: charge) time of the job")
    max_disparity: int = Field(description="The disparity range the job would use (resolved)")
    bundles: int
    bundles_sent: int = Field(description="Bundles expected to reach the metered solver")
    classical_share: float = Field(
        description="Share of the bundles solved classically (the host's settling, roof duality), "
        "charged nothing"
    )
    levels: list[LevelEstimate]
    remaining_seconds: float | None = Field(
        description="Your budget left; null: unlimited, or the solver is not metered"
    )
    fits: bool = Field(description="false: POST /v1/jobs would answer 403 for this job")
    memory_mb: int | None = Field(
        None, description="Estimated peak memory of a worker process running the job, MiB"
    )
    memory_budget_mb: int | None = Field(
        None,
        description="A worker process's memory budget, MiB (null: no limit); POST /v1/jobs "
        "answers 413 when memory_mb is above it",
    )

    @classmethod
    def of(
        cls, priced: dict[str, Any], remaining_seconds: float, memory_budget_mb: int | None = None
    ) -> Estimate:
        """The estimate a pricing worker computed (``workers.pricing.Priced.result``: the core
        ``JobEstimate``'s ``as_dict`` with the resolved range and the job's peak memory)
        against the owner's budget left (infinite: unlimited, or nothing to charge) and the
        memory budget the API admits jobs with."""
        return cls(
            **priced,
            remaining_seconds=None if math.isinf(remaining_seconds) else remaining_seconds,
            fits=priced["seconds"] <= remaining_seconds,
            memory_budget_mb=memory_budget_mb,
        )


class EstimateStatus(BaseModel):
    """An estimate being computed on a pricing worker (``POST /v1/estimate`` answers it, 202;
    poll ``GET /v1/estimates/{id}`` until ``state`` is ``done``, ``failed`` or ``cancelled``).
    The wire form of ``workers.estimates.EstimateRecord``; built by ``of``."""

    id: str
    state: EstimateState
    cached: bool = Field(
        False, description="true: answered from an identical request's estimate (the cache)"
    )
    created_at: datetime
    finished_at: datetime | None = None
    result: Estimate | None = Field(None, description="Once done: the estimate")
    error: str | None = Field(None, description="Once failed or cancelled: why")
    stage: str | None = Field(None, description="While running: what the worker is doing")
    fraction: float | None = Field(
        None, description="While running: the share of the levels priced so far (0-1)"
    )
    links: dict[str, str] = Field(description="self: where to poll (and DELETE to cancel)")

    @classmethod
    def of(cls, record: EstimateRecord, result: Estimate | None) -> EstimateStatus:
        fields = record_fields(cls, record)  # id, state, dates, error, stage...: as stored
        return cls(**{**fields, "result": result, "links": {"self": f"/v1/estimates/{record.id}"}})


class JobUsage(BaseModel):
    """What one job was charged (``GET /v1/usage``): the wire form of
    ``workers.quota.ledger.JobUsage``, whose ``job_id`` and ``seconds`` are sent as ``id`` and
    ``qpu_seconds``. Built only by ``UserUsage.of``."""

    id: str
    qpu_seconds: float = Field(description="QPU access time (hybrid: charge time) charged")
    problems: int = Field(description="QPU / hybrid problems sent")
    problem_ids: list[str] = Field(
        default_factory=list, description="The ids SAPI gave those problems (find them on Leap)"
    )
    first_charged_at: datetime | None = Field(
        None, description="When the job was first charged (null: before dates were kept)"
    )
    last_charged_at: datetime | None = Field(None, description="When it was last charged")


class UserUsage(BaseModel):
    """One user's budget and charges (``GET /v1/usage``): the wire form of
    ``workers.quota.ledger.UserUsage``, whose budget (a ``QuotaStatus``) is sent flat, as
    ``{what}_seconds`` fields beside the jobs; built by ``of``."""

    user: str
    limit_seconds: float | None = Field(description="Budget per period; null: unlimited")
    used_seconds: float = Field(description="Charged in the current period")
    reserved_seconds: float = Field(description="Held by bundles being solved right now")
    remaining_seconds: float | None = Field(description="Left in the current period")
    total_used_seconds: float = Field(description="Everything ever charged, in any period")
    period: BudgetPeriod = Field(
        description="What the budget covers (QHSM_BUDGET_PERIOD or the user's own)"
    )
    period_start: datetime | None = Field(description="Start of the current period (UTC)")
    resets_at: datetime | None = Field(
        description="When the period ends and the whole budget is available again; null: never"
    )
    warning: str | None = Field(
        None, description="Set when less than 10 % of the period's budget is left: what to do"
    )
    jobs: list[JobUsage]

    @classmethod
    def of(cls, usage: LedgerUsage) -> UserUsage:
        """The wire form of a user's usage (the ledger's ``as_dict``, which ``qhsm admin
        usage`` prints too)."""
        return cls.model_validate(usage.as_dict())


class Usage(BaseModel):
    users: list[UserUsage] = Field(description="Your own entry; admins: everyone's")
    total_used_seconds: float
    qpu_in_flight: int | None = Field(None, description="Lab-wide problems in flight (admins)")


class BatchCreated(BaseModel):
    """``POST /v1/batches``: the batch and its jobs, one per pair, in the order sent."""

    id: str
    jobs: list[JobCreated]
    links: dict[str, str] = Field(description="self: the batch's status")


class BatchProgress(BaseModel):
    """How far a batch is: its jobs by state (``expired``: a job whose record is gone)."""

    total: int
    by_state: dict[str, int] = Field(description="Jobs per state (queued, running, ...)")
    finished: int = Field(description="Jobs that ended (succeeded, failed, cancelled, expired)")
    fraction: float = Field(description="Finished jobs' share, 0-1")


class BatchJob(BaseModel):
    """One pair of a batch: its name and its job (null once the job's record expired)."""

    pair: int = Field(description="The pair's index in the request, from 0")
    name: str
    id: str
    job: JobSummary | None


class Batch(BaseModel):
    """``GET /v1/batches/{id}``: the batch's jobs with their states and its progress."""

    id: str
    owner: str
    created_at: datetime
    tags: list[str]
    jobs: list[BatchJob]
    progress: BatchProgress
