"""A small HTTP client of the API (used by ``qhsm submit``, ``qhsm demo`` and the benchmark)."""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import httpx

if TYPE_CHECKING:
    from shared.progress_bar import LevelBar

TERMINAL = {"succeeded", "failed", "cancelled"}
#: An estimate's states before it ends (``workers.estimates.EstimateState``).
ESTIMATE_OPEN = {"pending", "running"}
#: ``Client.wait`` polls every this share of the time waited so far (bounded both ways).
POLL_SHARE = 0.1


class ClientError(RuntimeError):
    """The API refused a request or cannot be reached; the message says why."""


def default_key() -> tuple[str | None, str]:
    """``QHSM_API_KEY``, else the local admin key ``qhsm serve`` keeps in the data directory;
    with where it was looked for (a wrong key is most often another data directory's)."""
    from shared.config import get_settings

    settings = get_settings()
    if settings.api_key is not None:
        return settings.api_key.get_secret_value(), "the QHSM_API_KEY environment variable"
    from api.users import LOCAL_KEY_FILE, read_local_key

    path = (settings.data_dir / LOCAL_KEY_FILE).resolve()
    return read_local_key(settings.data_dir), f"the file {path} (QHSM_DATA_DIR's local admin key)"


@dataclass(frozen=True)
class BatchPair:
    """One pair of :meth:`Client.submit_batch`: the views' bytes and what is its own."""

    left: bytes
    right: bytes
    names: tuple[str, str] = ("left.png", "right.png")
    name: str | None = None  # the job's label (default: the left file's name)
    ground_truth: bytes | None = None
    gt_scale: float | None = None
    gt_border: int | None = None
    calib: bytes | None = None
    max_disparity: int | str | None = None  # over the shared params'


@dataclass
class Client:
    """``key``: the API key sent as ``Authorization: Bearer``; default :func:`default_key`.
    ``key_source`` says where ``key`` came from (``--key``, ...), for the message of a 401."""

    url: str
    timeout: float = 60.0
    key: str | None = field(default=None, repr=False)
    key_source: str | None = None
    http: httpx.Client = field(init=False, repr=False)
    _has_key: bool = field(init=False, repr=False, default=False)

    def __post_init__(self) -> None:
        key = self.key
        if key:
            self.key_source = self.key_source or "the key given to the client"
        else:
            key, self.key_source = default_key()
        headers = {"Authorization": f"Bearer {key}"} if key else {}
        self.http = httpx.Client(
            base_url=self.url.rstrip("/"), timeout=self.timeout, headers=headers
        )
        self._has_key = bool(key)

    def _unauthorized_hint(self) -> str:
        if not self._has_key:
            return (
                f"no API key was sent: no --key, no QHSM_API_KEY, and no key in "
                f"{self.key_source}; pass --key or set QHSM_API_KEY"
            )
        return (
            f"the key came from {self.key_source}; if that is another service's or data "
            "directory's key, pass --key or set QHSM_API_KEY"
        )

    def close(self) -> None:
        self.http.close()

    def _request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        try:
            response = self.http.request(method, path, **kwargs)
        except httpx.TransportError as error:
            raise ClientError(
                f"cannot reach the qhsm API at {self.url} ({error}); is `qhsm serve` running?"
            ) from None
        if response.status_code >= 400:
            try:
                detail = response.json().get("detail", response.text)
            except ValueError:
                detail = response.text
            if response.status_code == 401:
                detail = f"{detail} ({self._unauthorized_hint()})"
            raise ClientError(f"{method} {path}: {response.status_code}: {detail}")
        return response

    def submit(
        self,
        left: bytes,
        right: bytes,
        params: dict[str, Any] | None = None,
        ground_truth: bytes | None = None,
        gt_scale: float | None = None,
        gt_border: int | None = None,
        names: tuple[str, str] = ("left.png", "right.png"),
        label: str | None = None,
        tags: list[str] | None = None,
        calib: bytes | None = None,
    ) -> dict:
        """POST /v1/jobs; returns ``{id, state, links, warnings}``. ``gt_scale`` not given:
        inferred by the service (with a warning); ``gt_border`` not given: the service's
        default. ``label``: a name for the job in job lists; ``tags``: what
        ``GET /v1/jobs?tag=`` lists it by; ``calib``: a calibration file's bytes (Middlebury
        calib.txt or KITTI's), for the job's depth and point cloud."""
        files = {"left": (names[0], left), "right": (names[1], right)}
        data = {"params": json.dumps(params or {})}
        if label:
            data["label"] = label
        if tags:
            data["tags"] = ",".join(tags)
        if calib is not None:
            files["calib"] = ("calib.txt", calib)
        if ground_truth is not None:
            files["ground_truth"] = ("ground_truth", ground_truth)
            given = {"gt_scale": gt_scale, "gt_border": gt_border}
            data.update({name: str(value) for name, value in given.items() if value is not None})
        return self._request("POST", "/v1/jobs", files=files, data=data).json()

    def submit_batch(
        self,
        pairs: list[BatchPair],
        params: dict[str, Any] | None = None,
        tags: list[str] | None = None,
    ) -> dict:
        """POST /v1/batches: one job per pair with shared ``params`` and ``tags``, all or none
        (a refused pair is named in the error); returns ``{id, jobs, links}``, the jobs in the
        order of ``pairs``."""
        files: list[tuple[str, tuple[str, bytes]]] = []
        specs: list[dict[str, Any]] = []
        truths = calibs = 0
        for pair in pairs:
            files += [("left", (pair.names[0], pair.left)), ("right", (pair.names[1], pair.right))]
            spec: dict[str, Any] = {"name": pair.name} if pair.name else {}
            if pair.max_disparity is not None:
                spec["max_disparity"] = pair.max_disparity
            if pair.ground_truth is not None:
                files.append(("ground_truth", (f"gt{truths}", pair.ground_truth)))
                spec["ground_truth"], truths = truths, truths + 1
                given = {"gt_scale": pair.gt_scale, "gt_border": pair.gt_border}
                spec.update({k: value for k, value in given.items() if value is not None})
            if pair.calib is not None:
                files.append(("calib", (f"calib{calibs}.txt", pair.calib)))
                spec["calib"], calibs = calibs, calibs + 1
            specs.append(spec)
        data = {"params": json.dumps(params or {}), "pairs": json.dumps(specs)}
        if tags:
            data["tags"] = ",".join(tags)
        return self._request("POST", "/v1/batches", files=files, data=data).json()

    def batch(self, batch_id: str) -> dict:
        """GET /v1/batches/{id}: the batch's jobs with their states, and its progress."""
        return self._request("GET", f"/v1/batches/{batch_id}").json()

    def usage(self) -> dict:
        """GET /v1/usage: your QPU budget in its period (admins: everyone's) and your jobs'
        charges."""
        return self._request("GET", "/v1/usage").json()

    def estimate(
        self,
        left: bytes,
        right: bytes,
        params: dict[str, Any] | None = None,
        names: tuple[str, str] = ("left.png", "right.png"),
    ) -> dict:
        """POST /v1/estimate: the job's metered seconds per level and whether they fit.

        The service computes it on a worker: this polls ``GET /v1/estimates/{id}`` (as
        :meth:`wait` polls a job) and returns the result; a failed or cancelled estimate is a
        :class:`ClientError` with the reason. Leaving early (Ctrl-C) cancels it."""
        files = {"left": (names[0], left), "right": (names[1], right)}
        data = {"params": json.dumps(params or {})}
        status = self._request("POST", "/v1/estimate", files=files, data=data).json()
        path = status["links"]["self"]
        started = time.monotonic()
        try:
            while status["state"] in ESTIMATE_OPEN:
                waited = time.monotonic() - started
                time.sleep(min(max(0.05, POLL_SHARE * waited), 1.0))
                status = self._request("GET", path).json()
        except BaseException:  # the caller leaves: nobody waits for the estimate any more
            with contextlib.suppress(Exception):
                self._request("DELETE", path)
            raise
        if status["state"] != "done":
            raise ClientError(f"estimate {status['id']} {status['state']}: {status['error']}")
        return status["result"]

    def status(self, job_id: str) -> dict:
        return self._request("GET", f"/v1/jobs/{job_id}").json()

    def wait(
        self,
        job_id: str,
        on_progress: Callable[[dict], None] | None = None,
        interval: float = 0.05,
        max_interval: float = 1.0,
    ) -> dict:
        """Poll until the job ends: every ``interval`` seconds at first, then every
        :data:`POLL_SHARE` of the time waited so far, at most every ``max_interval``; the end
        of a short job is seen within a few hundredths of a second, that of a long one within
        a small share of its time, with few requests."""
        started = time.monotonic()
        while True:
            status = self.status(job_id)
            if on_progress:
                on_progress(status)
            if status["state"] in TERMINAL:
                return status
            waited = time.monotonic() - started
            time.sleep(min(max(interval, POLL_SHARE * waited), max_interval))

    def started(self, job_id: str, timeout: float = 3.0) -> dict:
        """The job's status once it has started (its disparity range resolved and its views
        checked, with their warnings) or ended; as it is after ``timeout`` seconds otherwise
        (a long queue)."""
        deadline = time.monotonic() + timeout
        while True:
            status = self.status(job_id)
            done = status["state"] in TERMINAL or status.get("disparity_range") is not None
            if done or time.monotonic() >= deadline:
                return status
            time.sleep(0.05)

    def disparity(self, job_id: str, fmt: str = "pfm") -> bytes:
        return self._request("GET", f"/v1/jobs/{job_id}/disparity", params={"format": fmt}).content

    def preview(self, job_id: str) -> bytes:
        return self._request("GET", f"/v1/jobs/{job_id}/preview.png").content

    def cancel(self, job_id: str) -> dict:
        return self._request("DELETE", f"/v1/jobs/{job_id}").json()


class JobBar:
    """A :class:`shared.progress_bar.LevelBar` fed by the job statuses of :meth:`Client.wait`
    (default: on the ``sys.stderr`` of the call, so stdout stays free for ``--json``); its
    clock counts from the job's submission, so a re-attached ``qhsm wait`` shows the job's
    whole time. It closes itself when the job ends; :meth:`close` on an interruption."""

    def __init__(self, stream: IO[str] | None = None) -> None:
        self.stream = stream
        self._bar: LevelBar | None = None

    def __call__(self, status: dict) -> None:
        from shared.progress_bar import LevelBar
        from workers.records import Progress

        if self._bar is None:
            self._bar = LevelBar(self.stream)
            created = datetime.fromisoformat(status["created_at"])
            self._bar.started -= max(0.0, (datetime.now(UTC) - created).total_seconds())
        progress = Progress.model_validate(status["progress"])
        state = status["state"]
        done = progress.bundles_total if state == "succeeded" else progress.bundles_done
        self._bar.update(
            progress.level, progress.levels, done, progress.bundles_total, state, progress.phase
        )
        if state in TERMINAL:
            self.close()

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()


def progress_bar(stream: IO[str] | None = None) -> JobBar:
    """A :class:`JobBar` for :meth:`Client.wait`'s ``on_progress``."""
    return JobBar(stream)


def scores_text(status: dict) -> str | None:
    """A finished job's metrics as ``RMSE 1.234 px, BPP 5.67 %`` (n/a for a score that is not
    a finite number); None when the job had no ground truth."""
    from api.schemas import Metrics

    if not status.get("metrics"):
        return None
    metrics = Metrics.model_validate(status["metrics"]).model_dump()  # a model made at import

    def text(value: float | None, digits: int) -> str:
        return "n/a" if value is None else f"{value:.{digits}f}"

    return f"RMSE {text(metrics['rmse'], 3)} px, BPP {text(metrics['bpp'], 2)} %"


def write_result(client: Client, job_id: str, output: Path) -> Path:
    """Download the disparity in the format ``output``'s extension names."""
    fmt = output.suffix.lower().lstrip(".")
    if fmt not in ("pfm", "png", "npy"):
        raise ClientError(f"{output}: the output must end in .pfm, .png or .npy")
    output.parent.mkdir(parents=True, exist_ok=True)
    output.write_bytes(client.disparity(job_id, fmt))
    return output


def http_runner(left: Path, right: Path, config, url: str):
    """Entry point ``qhsm.runners:http`` of ``qhsm bench --url``: one scene through the service
    (key from QHSM_API_KEY); returns ``(disparity, levels)``."""
    import io

    import numpy as np

    client = Client(url)
    try:
        params = config.model_dump(mode="json")
        job = client.submit(
            Path(left).read_bytes(), Path(right).read_bytes(), params,
            names=(Path(left).name, Path(right).name),
        )  # fmt: skip
        status = client.wait(job["id"])
        if status["state"] != "succeeded":
            raise ClientError(f"job {job['id']} {status['state']}: {status['error']}")
        disparity = np.load(io.BytesIO(client.disparity(job["id"], "npy")), allow_pickle=False)
        return disparity, status["levels"]
    finally:
        client.close()
