"""/v1/batches: many stereo pairs in one request, one job per pair under one batch id."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, File, Form, UploadFile

from api import batch_service
from api.batch_service import BatchForm
from api.deps import CallerDep, ParamsForm, Responses
from api.responses import accepted, links, summary_of, upload_route
from api.schemas import Batch, BatchCreated, BatchJob, BatchProgress, JobCreated
from api.uploads import MAX_TAGS

router = APIRouter(prefix="/batches", tags=["batches"])


#: What else a batch upload can be refused with (:func:`~api.responses.upload_route`).
REFUSED: Responses = {
    403: {"description": "QPU budget too small for the pairs so far (the pair is named)"},
    429: {"description": "The batch would exceed the user's active-job cap"},
    422: {"description": "A pair's views, params or ground truth refused (it is named)"},
}


@upload_route(router, "", BatchCreated, REFUSED)
def create_batch(
    caller: CallerDep,
    left: Annotated[list[UploadFile], File(description="Left views, one per pair, in order")],
    right: Annotated[list[UploadFile], File(description="Right views, in the same order")],
    params: ParamsForm = None,
    ground_truth: Annotated[
        list[UploadFile] | None,
        File(
            description="Ground truths: one per pair in order, or any number that pairs "
            "names by index"
        ),
    ] = None,
    calib: Annotated[
        list[UploadFile] | None,
        File(description="Calibration files (calib.txt, KITTI's): one per pair, or by index"),
    ] = None,
    pairs: Annotated[
        str | None,
        Form(
            description="JSON list, one object per pair: name, ground_truth (index), gt_scale, "
            "gt_border, calib (index), max_disparity (over params')"
        ),
    ] = None,
    tags: Annotated[
        str | None,
        Form(
            max_length=MAX_TAGS * 41,
            description="Comma-separated tags of every job of the batch (GET /v1/jobs?tag=)",
        ),
    ] = None,
):
    """Queue one job per pair with shared options and tags, all or none: a pair refused (its
    views, params, ground truth, memory, QPU budget with the pairs before it, the active-job
    cap) is named in the 4xx and no job is created. Poll the ``Location`` it answers with."""
    form = BatchForm(left, right, params, ground_truth, calib, pairs, tags)
    svc, principal, users = caller
    batch, records = batch_service.submit_batch(form, principal.name, svc, users)
    body = BatchCreated(
        id=batch.id,
        jobs=[
            JobCreated(id=r.id, state=r.state, links=links(r), warnings=r.warnings) for r in records
        ],
        links={"self": f"/v1/batches/{batch.id}"},
    )
    return accepted(body, body.links["self"])


@router.get(
    "/{batch_id}",
    response_model=Batch,
    responses={404: {"description": "No such batch (or it expired, or is someone else's)"}},
)
def get_batch(batch_id: str, caller: CallerDep):
    """The batch's jobs in the order of its pairs, with their states, and its progress (jobs by
    state). Only its owner and admins see it."""
    batch, records = batch_service.find_batch(batch_id, caller.svc, caller.principal)
    return Batch(
        id=batch.id,
        owner=batch.owner,
        created_at=batch.created_at,
        tags=batch.tags,
        jobs=[
            BatchJob(
                pair=index,
                name=entry.name,
                id=entry.id,
                job=None if record is None else summary_of(record, caller.users),
            )
            for index, (entry, record) in enumerate(zip(batch.jobs, records, strict=True))
        ],
        progress=BatchProgress(**batch_service.progress_of(records)),
    )
