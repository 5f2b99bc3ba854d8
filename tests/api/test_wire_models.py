"""The API's wire models are the core's results, not copies that drift (issue 13, item 4), and
the client reads them through the same models."""

from __future__ import annotations

import dataclasses
import io

import pytest
from pydantic import TypeAdapter

from api.client import progress_bar, scores_text
from api.schemas import JobStatus, LevelTiming, Metrics
from shared.disparity_range import RangeEstimate
from shared.metrics import Scores, evaluate
from shared.pipeline import LevelReport
from workers.records import Progress


def test_metrics_are_the_core_scores_with_null_for_non_finite_numbers():
    assert set(Metrics.model_fields) == set(Scores.model_fields)
    for name, field in Scores.model_fields.items():
        assert Metrics.model_fields[name].description == field.description
    assert Metrics(rmse=None, bpp=None, pixels=None).rmse is None
    scores = evaluate([[1.0, 2.0]], [[1.0, 4.0]])
    assert Metrics.model_validate(scores.as_dict()).model_dump() == scores.as_dict()
    assert JobStatus.model_fields["metrics"].annotation == Metrics | None


def test_level_schema_follows_the_core_record():
    """LevelTiming is the JSON form of LevelReport (less the solver's ``info``): a field added
    to the core must be added to the wire form too."""
    core = {field.name for field in dataclasses.fields(LevelReport)} - {"info"}
    assert set(LevelTiming.model_fields) == core


def test_the_disparity_range_is_the_core_estimate():
    assert JobStatus.model_fields["disparity_range"].annotation == RangeEstimate | None
    stored = dataclasses.asdict(RangeEstimate(8, "given"))  # what a job record keeps
    status = JobStatus.model_json_schema()["$defs"]["RangeEstimate"]
    assert status["properties"]["source"]["description"] == "given, auto or auto-fallback"
    assert TypeAdapter(RangeEstimate).validate_python(stored) == RangeEstimate(8, "given")


def test_progress_is_one_model_for_the_store_the_api_and_the_client():
    assert JobStatus.model_fields["progress"].annotation is Progress


def test_scores_text_reads_null_scores():
    assert scores_text({"metrics": None}) is None
    status = {"metrics": {"rmse": 1.23456, "bpp": None, "pixels": 10}}
    assert scores_text(status) == "RMSE 1.235 px, BPP n/a %"


def states(*rows):
    for state, level, done, total in rows:
        progress = {"level": level, "levels": 2, "bundles_done": done, "bundles_total": total}
        yield {"state": state, "progress": progress, "created_at": "2026-01-01T00:00:00Z"}


@pytest.mark.parametrize("final", ["succeeded", "failed"])
def test_progress_bar_redraws_changes_and_ends_on_the_final_state(final):
    stream = io.StringIO()
    show = progress_bar(stream)
    rows = [("queued", 0, 0, 0), ("running", 1, 2, 4), ("running", 1, 2, 4), ("running", 2, 1, 8)]
    for status in states(*rows, (final, 2, 5, 8)):
        show(status)
    lines = stream.getvalue().splitlines()  # not a terminal: a line per change, no redraws
    assert lines[0] == "queued: waiting for a worker"
    done = 8 if final == "succeeded" else 5
    assert lines[-1].startswith(f"{final}: level 2/2: {done}/8 bundles (")
    assert len(lines) == 2 and "0/0" not in stream.getvalue()
    assert stream.getvalue().endswith("\n")  # the next line starts clean


def test_level_fields_are_declared_once_in_the_core():
    """The record and the wire model are derived from LevelReport (issue 30): same fields in
    the same order, the wire's descriptions only for fields that exist."""
    from api.schemas import LEVEL_DOCS
    from workers.records import LevelRecord

    core = [field.name for field in dataclasses.fields(LevelReport)]
    assert list(LevelRecord.model_fields) == core
    assert list(LevelTiming.model_fields) == [name for name in core if name != "info"]
    for name, text in LEVEL_DOCS.items():
        assert LevelTiming.model_fields[name].description == text
    # numbers that are not finite are stored and sent as null
    stored = LevelRecord.of(LevelReport(0, 1, 1, 1, 2, 3, 4, 5, float("inf"), None, None, 0,
                                        1.0, 0.5, {"qpu": float("nan")}))  # fmt: skip
    sent = LevelTiming.model_validate(stored).model_dump()
    assert sent["energy"] is None and sent["timing"] == {"qpu": None} and "info" not in sent


def test_a_derived_model_refuses_docs_for_fields_it_does_not_have():
    from shared.wire import model_of

    with pytest.raises(KeyError, match="bundels"):
        model_of(LevelReport, "Typo", docs={"bundels": "a misspelt field"})


def test_the_status_copies_every_field_it_shares_with_the_record():
    """``record_fields``: what the status sends as stored is read by name, no hand-kept list."""
    from api.schemas import EstimateStatus, record_fields
    from workers.estimates import EstimateRecord
    from workers.records import JobRecord

    shared = set(JobStatus.model_fields) & set(JobRecord.model_fields)
    assert {"levels", "config", "disparity_range", "provenance_counts", "metrics"} <= shared
    record = EstimateRecord(config={"solver": "sa"}, cached=True, error="why")
    fields = record_fields(EstimateStatus, record)
    assert fields == {
        "id": record.id,
        "state": record.state,
        "cached": True,
        "result": None,
        "created_at": record.created_at,
        "finished_at": None,
        "error": "why",
        "stage": None,
        "fraction": None,
    }
    status = EstimateStatus.of(record, None)
    assert status.links == {"self": f"/v1/estimates/{record.id}"} and status.cached
