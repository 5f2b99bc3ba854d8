"""The job service layer (issue 21): the service speaks no HTTP, its refusals are answered in
one place, the routes declare their dependencies with the aliases of ``api/deps.py``, and the
wire models that are not the core's types follow them."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from api.app import create_app
from api.errors import (
    DOMAIN_ERRORS,
    AdmissionError,
    ExpiredError,
    JobNotFoundError,
    JobStateError,
    Refusal,
    refusal_of,
)
from api.schemas import Estimate, JobUsage, LevelEstimate, UserUsage
from api.uploads import UploadError
from shared.ground_truth import ScaleNotInferredError
from shared.solvers import InvalidSolverParamsError, UnknownSolverError
from shared.solvers.meters.qpu_time import JobEstimate
from shared.solvers.meters.qpu_time import LevelEstimate as CoreLevelEstimate
from workers.pricing import Priced
from workers.quota import QuotaExceededError
from workers.quota.ledger import JobUsage as LedgerJobUsage
from workers.quota.ledger import QuotaStatus
from workers.quota.ledger import UserUsage as LedgerUserUsage
from workers.store import ActiveJobsCapError

API = Path(__file__).resolve().parents[2] / "api"


def imported_modules(path: Path) -> set[str]:
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module:
            found.add(node.module)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
    return found


@pytest.mark.parametrize("module", ["job_service.py", "errors.py", "uploads.py"])
def test_the_service_speaks_no_http(module):
    imported = imported_modules(API / module)
    assert not {name for name in imported if name.split(".")[0] in ("fastapi", "starlette")}


def test_routes_declare_dependencies_with_the_shared_aliases():
    for path in sorted((API / "routes").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Subscript) and ast.unparse(node.value) == "Annotated":
                assert "Depends(" not in ast.unparse(node), f"{path.name}: {ast.unparse(node)}"


def test_every_domain_error_has_the_one_handler():
    handlers = create_app().exception_handlers
    assert {handlers[error] for error in DOMAIN_ERRORS} == {handlers[DOMAIN_ERRORS[0]]}


@pytest.mark.parametrize(
    ("error", "status", "detail"),
    [
        (UploadError(Refusal.TOO_LARGE, "left: too big"), 413, "left: too big"),
        (AdmissionError(Refusal.INVALID, "params: no"), 422, "params: no"),
        (JobNotFoundError("j1", 60), 404, "no job 'j1': it never existed or its results "
                                           "expired (results are kept 60 s)"),
        (JobStateError("job j1 is queued: wait"), 409, "job j1 is queued: wait"),
        (ExpiredError("j1", "result"), 410, "the result of job j1 has expired"),
        (InvalidSolverParamsError("num_reads: 0"), 422, "params: num_reads: 0"),
        (ScaleNotInferredError("send it"), 422, "gt_scale: send it"),
    ],
)  # fmt: skip
def test_refusals_keep_their_status_and_text(error, status, detail):
    assert refusal_of(error) == (status, detail)


def test_core_refusals_keep_their_status_and_text():
    quota = QuotaExceededError("ada", 0.5, 2.0, "this job (3 bundles)")
    assert refusal_of(quota) == (403, str(quota))
    status, detail = refusal_of(ActiveJobsCapError("ada", 2, 2))
    assert status == 429 and detail.startswith("user 'ada' already has 2 jobs queued or running")
    assert "QHSM_MAX_ACTIVE_JOBS_PER_USER=2" in detail and "DELETE /v1/jobs/{id}" in detail
    unknown = UnknownSolverError("nope")
    assert refusal_of(unknown) == (422, f"params: {unknown}")
    with pytest.raises(TypeError):
        refusal_of(ValueError("a bug, not a refusal"))


def test_the_estimate_is_the_core_estimate_on_the_wire():
    level = CoreLevelEstimate(index=0, shape=(4, 6), bundles=3, variables_per_bundle=8, seconds=0.5)
    job = JobEstimate(solver="qpu-sim", seconds=0.5, bundles=3, levels=[level])
    assert set(LevelEstimate.model_fields) == set(level.as_dict())
    assert set(Estimate.model_fields) == {
        *job.as_dict(),
        "max_disparity",
        "remaining_seconds",
        "fits",
        "memory_mb",  # issue 29: the job's peak memory and a worker's budget
        "memory_budget_mb",
    }
    # what a pricing worker computed (workers.pricing.Priced.result) against the budget left
    priced = Priced(job, 16, None, 300).result()
    wire = Estimate.of(priced, float("inf"), memory_budget_mb=200).model_dump()
    assert wire == {
        **job.as_dict(), "max_disparity": 16, "remaining_seconds": None, "fits": True,
        "memory_mb": 300, "memory_budget_mb": 200,
    }  # fmt: skip
    assert not Estimate.of(priced, 0.25).fits
    assert Estimate.of(priced, 1.0).remaining_seconds == 1.0


def test_usage_is_the_ledger_usage_on_the_wire():
    usage = LedgerUserUsage(QuotaStatus("ada", 3.0, 0.75, 0.0), [LedgerJobUsage("j1", 0.75, 2)])
    assert set(UserUsage.model_fields) == set(usage.as_dict())
    assert set(JobUsage.model_fields) == set(usage.as_dict()["jobs"][0])
    assert UserUsage.of(usage).model_dump() == usage.as_dict()
