"""What a deployment reads from the environment (prefix ``QHSM_``): ``Settings``, the one place
for the service's addresses, limits, timeouts, folders and credentials. Re-exported by
:mod:`shared.config`, where a run's ``MatchConfig`` is.
"""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path
from typing import Any, Literal

from pydantic import AliasChoices, Field, SecretStr
from pydantic_settings import BaseSettings, SettingsConfigDict


class BudgetPeriod(StrEnum):
    """Over what QPU budgets are counted: every charge ever (``lifetime``), or the current UTC
    calendar month (``monthly``) or ISO week, Monday 00:00 UTC on (``weekly``)."""

    LIFETIME = "lifetime"
    MONTHLY = "monthly"
    WEEKLY = "weekly"


def seconds_field(default: float, description: str) -> Any:
    """A setting that is a positive duration in seconds (every timeout and delay here).

    Parameters
    ----------
    default : float
        Its default, seconds.
    description : str
        What it times.

    Returns
    -------
    Any
        The pydantic ``Field`` (positive, described).
    """
    return Field(default, gt=0, description=description)


class Settings(BaseSettings):
    """Deployment settings, read from the environment (prefix ``QHSM_``).

    Ocean's and Gurobi's own variables (``DWAVE_API_TOKEN``, ``GRB_LICENSE_FILE``, ...) are read by
    those libraries; the ones we pass on explicitly are listed here without the prefix.
    """

    model_config = SettingsConfigDict(env_prefix="QHSM_", env_file=None, extra="ignore")

    redis_url: str | None = Field(
        None,
        validation_alias=AliasChoices("QHSM_REDIS_URL", "REDIS_URL", "redis_url"),
        description="Broker, results and job store (QHSM_REDIS_URL or REDIS_URL); "
        "unset: `qhsm serve` starts an embedded redis-server",
    )
    key_prefix: str = Field(
        "qhsm",
        pattern=r"^[A-Za-z0-9_.-]+$",
        description="Prefix of every Redis key the service writes (jobs, queues, results)",
    )
    data_dir: Path = Field(
        default_factory=lambda: default_data_dir(),
        description="Uploads, the embedded Redis, the local admin key, logs, embedding cache, "
        "demo output; the same wherever a command runs (default: the user's data folder)",
    )
    result_ttl_seconds: int = Field(7 * 24 * 3600, ge=60)
    max_image_pixels: int = Field(4_000_000, ge=1)
    rows_per_task: int = Field(8, ge=1, description="Bundles' rows grouped into one Celery task")
    task_visibility_timeout: int = Field(6 * 3600, ge=60)
    embedding_timeout: float = seconds_field(300.0, "minorminer time limit, seconds")
    embedding_search_timeout: float = seconds_field(
        30.0,
        "minorminer time limit per width tried by --bundle-width auto, seconds "
        "(the widest segment that embeds within it wins)",
    )
    embedding_tries: int = Field(
        10,
        ge=1,
        le=1000,
        description="minorminer tries (seed 0) per sublattice size when a small tile shape is "
        "embedded and copied across a Pegasus/Zephyr QPU: a budget in tries, not seconds",
    )
    dataset_mirror: str | None = Field(
        None,
        description="Base URL replacing https://vision.middlebury.edu/ for `qhsm datasets fetch`",
    )
    solver_rows_per_task: dict[str, int] = Field(
        default_factory=lambda: {"exact": 144},
        description="Per-solver rows_per_task (JSON); the exact row DP is vectorised over rows, "
        "so small tasks only add broker overhead",
    )
    control_queue: str = Field("control", description="Celery queue of the orchestration tasks")
    watchdog_stall_seconds: float = seconds_field(
        300.0,
        "A running job whose progress has not moved this long gets its unsolved "
        "bundles re-sent by the watchdog (seconds; tasks are idempotent)",
    )
    watchdog_lost_seconds: float = seconds_field(
        30.0,
        "An active job (queued or running) without progress this long, none of whose tasks "
        "is in any queue or held by a live worker, has its work sent again (seconds)",
    )
    worker_heartbeat_seconds: float = seconds_field(
        2.0,
        "How often a worker says it is alive and which messages it holds; one silent for 5 "
        "of them is dead and what it held is put back in its queues (seconds)",
    )
    watchdog_max_resends: int = Field(
        3, ge=1, description="Re-sends without progress after which the watchdog fails the job"
    )
    task_retries: int = Field(5, ge=0, description="Retries after a transient solver error")
    retry_backoff: float = seconds_field(
        2.0, "First retry delay after a transient error, seconds (doubles)"
    )
    retry_backoff_max: float = seconds_field(300.0, "Longest retry delay, seconds")
    redis_max_command_bytes: int = Field(
        4 * 2**20,
        ge=64 * 2**10,
        description="Largest Redis command or reply a job's data travels in (uploads, level "
        "inputs, solved bundles, results go in pieces of this size), so one large job never "
        "stalls Redis for the others",
    )
    max_upload_bytes: int = Field(64 * 2**20, ge=1, description="Largest accepted upload file")
    max_batch_pairs: int = Field(
        100, ge=1, description="Most stereo pairs one POST /v1/batches may send"
    )
    max_batch_pixels: int = Field(
        40_000_000,
        ge=1,
        description="Most left-view pixels of all the pairs of one POST /v1/batches together "
        "(the API holds them decoded until every pair is admitted); more is a 413 naming the "
        "pair",
    )
    max_json_body_bytes: int = Field(
        64 * 2**10,
        ge=1024,
        description="Largest request body of a route without file uploads (JSON: users, "
        "quotas, ...); larger is a 413 before the body is read",
    )
    api_host: str = Field("127.0.0.1", description="`qhsm serve` / `qhsm api` bind address")
    api_port: int = Field(8000, ge=0, le=65535, description="`qhsm serve` / `qhsm api` port")
    api_url: str = Field(
        default_factory=lambda: _local_api_url(), description="Where `qhsm submit` sends jobs"
    )
    worker_concurrency: int | None = Field(
        None, ge=1, description="Processes per `qhsm serve` CPU worker (default: CPU count)"
    )
    control_concurrency: int = Field(
        2, ge=1, description="Processes of the worker that runs only the control queue"
    )
    inspect_timeout: float = seconds_field(
        1.0, "Seconds to wait for workers to report their queues"
    )
    pricing_queue: str = Field(
        "pricing",
        description="Celery queue of the pricing tasks (POST /v1/estimate, a metered job's "
        "budget check): the API never computes an estimate itself",
    )
    max_concurrent_pricing: int = Field(
        2,
        ge=1,
        description="Processes of `qhsm serve`'s pricing worker: estimates computed at once "
        "(more wait in the pricing queue)",
    )
    max_estimates_per_user: int = Field(
        4,
        ge=1,
        description="Estimates one user may have waiting or computing at once; more is a 429",
    )
    estimate_abandon_seconds: float = seconds_field(
        60.0,
        "An estimate nobody polls (GET /v1/estimates/{id}) for this long is cancelled and its "
        "task stopped (seconds)",
    )
    estimate_ttl_seconds: int = Field(
        3600,
        ge=60,
        description="How long an estimate's answer is kept, and a finished estimate serves an "
        "identical request (same views, config and solver) from the cache (seconds)",
    )
    api_shutdown_seconds: float = seconds_field(
        5.0,
        "Seconds the API waits for requests in flight after SIGTERM or Ctrl-C before it stops "
        "regardless",
    )
    max_active_jobs_per_user: int | None = Field(
        8,
        ge=0,
        description="Jobs one user may have queued or running at once; more is a 429 "
        "(0 or None: no limit)",
    )
    task_soft_time_limit: float = seconds_field(
        900.0,
        "Seconds one solver task may run before it is stopped and its job fails "
        "(per solver: QHSM_SOLVER_TIME_LIMITS)",
    )
    solver_time_limits: dict[str, float] = Field(
        default_factory=dict,
        description='Per-solver soft time limit of a task, seconds (JSON, e.g. {"gurobi": 3600})',
    )
    task_time_limit_grace: float = seconds_field(
        30.0,
        "Seconds after the soft limit at which a task that ignores it is killed",
    )

    dimod_samplers: dict[str, dict[str, tuple[float, float]]] = Field(
        default_factory=dict,
        description="dimod: sampler classes jobs may name besides the built-in list, each with "
        'its parameters\' [low, high] bounds (JSON, e.g. {"my_pkg.MySampler": {"num_reads": '
        "[1, 100]}}); any other class or parameter is refused",
    )
    build_kernels: Literal["auto", "never"] = Field(
        "auto",
        description="`qhsm match` in a terminal without compiled kernels builds them in the "
        "background, once (auto; never in CI or without a terminal), or not (never)",
    )
    solver_nice: int = Field(
        10,
        ge=0,
        le=19,
        description="Niceness a worker process takes when it first solves bundles: "
        "orchestration (starting jobs, assembling levels) and the API get the CPU first on a "
        "shared machine (0: as started)",
    )
    task_memory_limit_mb: int | None = Field(
        None,
        ge=0,
        description="Most memory one worker process may use, MiB; unset: its share of the "
        "host's (QHSM_MEMORY_HOST_FRACTION x the host's memory / its worker processes); a job "
        "estimated above it is refused (413), a task that grows past it fails its job with a "
        "message (0: no limit)",
    )
    memory_host_fraction: float = Field(
        0.8,
        gt=0,
        le=1,
        description="Share of a host's memory its worker processes may use together (each "
        "worker reads its own host's memory)",
    )
    host_worker_processes: int | None = Field(
        None,
        ge=1,
        description="Worker processes on this host that share its memory (`qhsm serve` sets it "
        "for the workers it starts; unset: one per core)",
    )

    # users, API keys and QPU quotas (issue 5)
    auth_enabled: bool = Field(
        True, description="Require `Authorization: Bearer KEY` on /v1 (off: everyone is `local`)"
    )
    default_qpu_seconds: float = Field(
        60.0,
        ge=0,
        allow_inf_nan=False,
        description="QPU/hybrid budget of a new user without --qpu-seconds, seconds",
    )
    budget_period: BudgetPeriod = Field(
        BudgetPeriod.LIFETIME,
        description="What a QPU budget covers: lifetime (every charge ever), monthly (the UTC "
        "calendar month) or weekly (the ISO week, from Monday 00:00 UTC); a user's own period "
        "(qhsm admin set-quota --period) overrides it",
    )
    qpu_max_in_flight: int = Field(
        2, ge=1, description="Lab-wide limit on QPU/hybrid problems being solved at once"
    )
    qpu_max_in_flight_per_user: int | None = Field(
        None, ge=1, description="Per-user share of those slots (unset: no per-user limit)"
    )
    qpu_slot_ttl: float = seconds_field(
        900.0,
        "Seconds after which a QPU slot or budget reservation of a dead worker "
        "expires (added to the bundle's estimate; must exceed the longest QPU/hybrid call)",
    )
    qpu_slot_wait: float = seconds_field(
        30.0, "Seconds a worker waits for a free QPU slot before retrying later"
    )
    api_key: SecretStr | None = Field(
        None, description="The API key `qhsm submit` (and other clients) send (QHSM_API_KEY)"
    )

    dwave_api_token: SecretStr | None = Field(None, validation_alias="DWAVE_API_TOKEN")
    dwave_solver: str | None = Field(None, validation_alias="DWAVE_SOLVER")
    dwave_region: str | None = Field(None, validation_alias="DWAVE_API_REGION")
    dwave_endpoint: str | None = Field(None, validation_alias="DWAVE_API_ENDPOINT")

    grb_license_file: Path | None = Field(None, validation_alias="GRB_LICENSE_FILE")
    grb_wls_access_id: SecretStr | None = Field(None, validation_alias="GRB_WLSACCESSID")
    grb_wls_secret: SecretStr | None = Field(None, validation_alias="GRB_WLSSECRET")
    grb_license_id: int | None = Field(None, validation_alias="GRB_LICENSEID")


def default_data_dir() -> Path:
    """The user's data folder for qhsm (platformdirs: ``~/.local/share/qhsm`` on Linux, or
    under ``$XDG_DATA_HOME``; ``~/Library/Application Support/qhsm`` on macOS; ``%LOCALAPPDATA%``
    on Windows): the same from every directory, so ``qhsm submit`` and ``qhsm admin`` find what
    ``qhsm serve`` keeps wherever they are run.

    Returns
    -------
    Path
    """
    import platformdirs

    return platformdirs.user_data_path("qhsm", appauthor=False)


def _local_api_url() -> str:
    """`qhsm serve`'s address with the default host and port (written once, in their fields)."""
    fields = Settings.model_fields
    return f"http://{fields['api_host'].default}:{fields['api_port'].default}"


def get_settings() -> Settings:
    """Read the settings from the environment now (cheap; no caching so tests can patch env)."""
    return Settings()
