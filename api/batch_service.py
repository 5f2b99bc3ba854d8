"""The batch service: many pairs admitted as one request (``POST /v1/batches``), one job each
under one batch id, all or nothing, and the batch's jobs and progress (``GET /v1/batches/{id}``).

Admission: the active-job cap for the whole batch (before any upload is read), then every pair
through the job service's checks (:func:`api.job_service.admit`: params, solver, views, memory,
ground truth; a metered pair is written `pricing` and priced by its job); the first refusal is
answered with its status, naming the pair (``pair 3 (name): ...``) and nothing is created.
Then every job is written, the batch saved and the jobs started.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from api import job_service
from api.auth import Principal
from api.deps import Services
from api.errors import (
    DOMAIN_ERRORS,
    BatchNotFoundError,
    BatchPairError,
    Refusal,
    ServiceError,
    refusal_of,
)
from api.job_service import JobForm
from api.uploads import (
    GT_SCALE_RANGE,
    MAX_GT_BORDER,
    MAX_LABEL,
    Upload,
    cameras_of,
    display_name,
    one_line,
    parse_config,
    parse_tags,
)
from api.users import UserStore
from workers.batches import BatchEntry, BatchRecord, BatchStore, new_batch_id
from workers.records import ACTIVE, GroundTruth, JobRecord, now
from workers.store import ActiveJobsCapError


class PairSpec(BaseModel):
    """What one pair of a batch adds to the shared options (the ``pairs`` form field)."""

    model_config = ConfigDict(extra="forbid")

    name: str | None = Field(
        None, max_length=MAX_LABEL, description="The pair's name (the job's label)"
    )
    ground_truth: int | None = Field(
        None, ge=0, description="Index of its file among the ground_truth uploads"
    )
    gt_scale: float | None = Field(
        None, ge=GT_SCALE_RANGE[0], le=GT_SCALE_RANGE[1], allow_inf_nan=False
    )
    gt_border: int = Field(GroundTruth.model_fields["border"].default, ge=0, le=MAX_GT_BORDER)
    calib: int | None = Field(None, ge=0, description="Index of its file among the calib uploads")
    max_disparity: int | str | None = Field(
        None, description="The pair's range (an int or 'auto'), over the shared params'"
    )


@dataclass(frozen=True)
class BatchForm:
    """A batch as submitted: the form fields of ``POST /v1/batches``."""

    left: Sequence[Upload]
    right: Sequence[Upload]
    params: str | None = None
    ground_truth: Sequence[Upload] | None = None
    calib: Sequence[Upload] | None = None
    pairs: str | None = None  # JSON list of PairSpec
    tags: str | None = None


def refused(index: int, name: str, error: Exception) -> BatchPairError:
    status, detail = refusal_of(error)
    return BatchPairError(
        Refusal(status), f"pair {index} ({name}): {detail}; no job of the batch was created"
    )


def pair_specs(form: BatchForm, limit: int) -> list[PairSpec]:
    """The pairs' own fields, checked against the uploads (``ServiceError`` saying which)."""
    count = len(form.left)
    if count != len(form.right):
        raise ServiceError(
            Refusal.INVALID,
            f"left and right: {count} left views but {len(form.right)} right views; send "
            "them in pairs, in the same order",
        )
    if not 1 <= count <= limit:
        raise ServiceError(
            Refusal.INVALID,
            f"a batch has 1 to {limit} pairs (QHSM_MAX_BATCH_PAIRS), not {count}; split it",
        )
    truths, calibs = form.ground_truth or [], form.calib or []
    if form.pairs is None:
        for what, files in (("ground_truth", truths), ("calib", calibs)):
            if files and len(files) != count:
                raise ServiceError(
                    Refusal.INVALID,
                    f"{what}: {len(files)} files for {count} pairs; send one per pair, or say "
                    'which pair has which in pairs (e.g. [{"ground_truth": 0}, {}])',
                )
        return [
            PairSpec(ground_truth=i if truths else None, calib=i if calibs else None)
            for i in range(count)
        ]
    try:
        raw = json.loads(form.pairs)
    except json.JSONDecodeError as error:
        raise ServiceError(Refusal.MALFORMED, f"pairs: not JSON ({error})") from None
    if not isinstance(raw, list) or len(raw) != count:
        raise ServiceError(
            Refusal.INVALID, f"pairs: a JSON list with one object per pair ({count}), in order"
        )
    specs = []
    for index, item in enumerate(raw):
        try:
            spec = PairSpec.model_validate(item)
        except ValidationError as error:
            first = error.errors()[0]
            where = ".".join(str(part) for part in first["loc"])
            raise ServiceError(
                Refusal.INVALID, f"pairs[{index}]{'.' + where if where else ''}: {first['msg']}"
            ) from None
        for what, files, at in (
            ("ground_truth", truths, spec.ground_truth),
            ("calib", calibs, spec.calib),
        ):
            if at is not None and at >= len(files):
                raise ServiceError(
                    Refusal.INVALID,
                    f"pairs[{index}].{what}: file {at} asked for, {len(files)} {what} sent",
                )
        specs.append(spec)
    return specs


def pair_params(params: str | None, spec: PairSpec) -> str | None:
    """The shared params with the pair's range, when it has one."""
    if spec.max_disparity is None:
        return params
    parse_config(params)  # the shared params' own errors first
    return json.dumps({**json.loads(params or "{}"), "max_disparity": spec.max_disparity})


def check_room(owner: str, names: list[str], svc: Services) -> None:
    """The whole batch must fit the owner's active-job cap: refused naming the first pair that
    does not, before any upload is read."""
    cap = svc.settings.max_active_jobs_per_user
    if not cap:
        return
    active = svc.store.active_jobs(owner)
    if active + len(names) > cap:
        first = max(cap - active, 0)
        before = f" and the batch's first {first} pairs would reach it" if first else ""
        raise BatchPairError(
            Refusal.TOO_MANY,
            f"pair {first} ({names[first]}): user {owner!r} has {active} jobs queued or running"
            f"{before}: {cap} is the limit per user (QHSM_MAX_ACTIVE_JOBS_PER_USER); send at "
            f"most {first} pairs now, or wait for jobs to finish (or cancel some); no job of the "
            "batch was created",
        )


def submit_batch(
    form: BatchForm, owner: str, svc: Services, users: UserStore
) -> tuple[BatchRecord, list[JobRecord]]:
    """Admit every pair of the batch, then write and start them all; nothing is created when
    one is refused."""
    specs = pair_specs(form, svc.settings.max_batch_pairs)
    tags = parse_tags(form.tags)
    names = [
        one_line(spec.name) or display_name(left.filename) or f"pair-{i}"
        for i, (spec, left) in enumerate(zip(specs, form.left, strict=True))
    ]
    check_room(owner, names, svc)
    batch_id = new_batch_id()
    admitted: list[tuple[JobRecord, Any]] = []
    pixels = 0
    for index, spec in enumerate(specs):
        try:
            job = JobForm(
                form.left[index],
                form.right[index],
                pair_params(form.params, spec),
                None if spec.ground_truth is None else (form.ground_truth or [])[spec.ground_truth],
                spec.gt_scale,
                spec.gt_border,
                names[index],
                None if spec.calib is None else cameras_of(None, None, None, _calib(form, spec)),
                ",".join(tags),
            )
            record, arrays = job_service.admit(job, owner, svc, users, batch=batch_id)
            pixels += record.width * record.height
            if pixels > svc.settings.max_batch_pixels:
                raise ServiceError(
                    Refusal.TOO_LARGE,
                    f"the batch's views reach {pixels} pixels with this pair, above "
                    f"QHSM_MAX_BATCH_PIXELS={svc.settings.max_batch_pixels} (the views are held "
                    "until every pair is admitted); send fewer pairs per batch",
                )
            # a metered pair's estimate is its pricing worker's (it is written `pricing`, then
            # queued or failed against the budget): none is known here (issue 29)
        except DOMAIN_ERRORS as error:
            raise refused(index, names[index], error) from None
        admitted.append((record, arrays))
    written: list[JobRecord] = []
    try:
        for index, (record, arrays) in enumerate(admitted):
            try:
                job_service.write(record, arrays, svc)
            except ActiveJobsCapError as error:  # another request took the room meanwhile
                raise refused(index, names[index], error) from None
            written.append(record)
        batch = BatchRecord(
            id=batch_id,
            owner=owner,
            created_at=now(),
            tags=tags,
            jobs=[BatchEntry(name=name, id=r.id) for name, r in zip(names, written, strict=True)],
        )
        batches(svc).save(batch)
    except BaseException:  # nothing of the batch stays: a full disk, Redis gone, the cap
        for record in written:
            with contextlib.suppress(Exception):
                svc.store.discard(record.id)
        raise
    start(written, svc)
    return batch, written


def _calib(form: BatchForm, spec: PairSpec) -> Upload:
    assert spec.calib is not None and form.calib is not None
    return form.calib[spec.calib]


def start(records: list[JobRecord], svc: Services) -> None:
    """Send every job's start; the ones not sent when the broker fails are removed (the error
    is answered; the ones sent run)."""
    for index, record in enumerate(records):
        try:
            job_service.send_first_task(record, svc)  # a metered pair's: its pricing
        except BaseException:
            for unsent in records[index:]:
                with contextlib.suppress(Exception):
                    svc.store.discard(unsent.id)
            raise
        job_service.started(record, svc)


def batches(svc: Services) -> BatchStore:
    return BatchStore(svc.store.redis, svc.settings.key_prefix, svc.settings.result_ttl_seconds)


def find_batch(
    batch_id: str, svc: Services, principal: Principal
) -> tuple[BatchRecord, list[JobRecord | None]]:
    """The batch, if the caller may see it (its owner or an admin), and its jobs' records in
    the order of its pairs (None: expired)."""
    store = batches(svc)
    batch = store.get(batch_id)
    if batch is None or not (principal.admin or batch.owner == principal.name):
        raise BatchNotFoundError(batch_id, svc.settings.result_ttl_seconds)
    records = [svc.store.get(entry.id) for entry in batch.jobs]
    if any(record is not None for record in records):
        store.keep(batch_id)
    return batch, records


def progress_of(records: list[JobRecord | None]) -> dict[str, Any]:
    """The batch's jobs counted by state (``expired``: its record is gone)."""
    by_state: dict[str, int] = {}
    for record in records:
        state = "expired" if record is None else record.state.value
        by_state[state] = by_state.get(state, 0) + 1
    finished = sum(1 for r in records if r is None or r.state not in ACTIVE)
    total = len(records)
    return {
        "total": total,
        "by_state": by_state,
        "finished": finished,
        "fraction": finished / total if total else 1.0,
    }
