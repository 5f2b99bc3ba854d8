"""A job record's state changes, without Redis: each is a pure method of ``JobRecord``, and no
sequence of them leaves the transition table (``workers.records.TRANSITIONS``); the typed
``levels`` and ``disparity_range`` read and write the JSON the untyped dicts did."""

from __future__ import annotations

import dataclasses
import json
from datetime import UTC, datetime, timedelta

from hypothesis import settings as settings_
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, rule

from api.schemas import JobStatus, LevelTiming
from shared.config import MatchConfig
from shared.disparity_range import RangeEstimate
from shared.pipeline import LevelReport
from workers.records import (
    ACTIVE,
    TRANSITIONS,
    JobRecord,
    JobState,
    LevelRecord,
    allowed,
)

T0 = datetime(2026, 1, 1, tzinfo=UTC)
STORED_LEVEL = {
    "index": 0, "downsample": 1, "bin_width": 4, "views": 2, "height": 6, "width": 8,
    "candidates": 5, "bundles": 4, "energy": 12.5, "lower_bound": 12.0, "gap": 0.04,
    "repaired": 0, "seconds": 0.25, "solver_seconds": 0.125, "timing": {"qpu": 0.5},
    "info": {"embeddings": 1}, "residual": None, "termination": "gap",
    "provenance_counts": None,
}  # fmt: skip
STORED_RANGE = {"max_disparity": 8, "source": "auto", "confirmed": 0.75, "note": "", "warning": ""}


def record(state: JobState = JobState.QUEUED, **fields) -> JobRecord:
    return JobRecord(
        id="0" * 32, state=state, config=MatchConfig(), width=8, height=6, created_at=T0, **fields
    )


def level(index: int) -> LevelRecord:
    return LevelRecord.model_validate({**STORED_LEVEL, "index": index})


def test_final_states_are_never_left_and_every_state_is_in_the_table():
    assert set(TRANSITIONS) == set(JobState)
    for state in JobState:
        assert allowed(state, state)
        assert (not TRANSITIONS[state]) == state.terminal
    assert not allowed(JobState.QUEUED, JobState.SUCCEEDED)  # a job runs before it succeeds


def test_a_change_that_no_longer_applies_is_none_not_an_error():
    running = record(JobState.RUNNING, level=2)
    assert running.started(T0) is None  # started already (a redelivered start)
    assert running.restarted(T0, level=1) is None  # moved on since the watchdog looked
    assert running.with_level(1, level(1)) is None  # level 0 not assembled yet
    assert record().succeeded(T0, None) is None  # never ran
    failed = running.failed(T0, "x" * 10_000)
    assert failed is not None and failed.finished_at == T0 and len(failed.error) < 2100
    assert failed.cancelled(T0) is None and failed.failed(T0, "again") is None


def test_a_pricing_job_is_queued_once_with_its_estimate_or_ends():
    """Issue 29: a metered job waits in ``pricing`` (stages shown) until its pricing worker
    queues it with its levels' estimate (its start not sent yet); it never runs before."""
    from shared.disparity_range import RangeEstimate

    pricing = record(JobState.PRICING, warnings=["scale inferred"])
    assert not allowed(JobState.PRICING, JobState.RUNNING)
    assert pricing.started(T0) is None  # only queued by its pricing
    surveying = pricing.pricing_at("surveying the levels", 0.0)
    assert surveying is not None and surveying.pricing_stage == "surveying the levels"
    assert surveying.pricing_at("surveying the levels", 0.0) is None  # nothing to write
    halfway = surveying.pricing_at("surveying the levels", 0.5)
    assert halfway is not None and halfway.pricing_fraction == 0.5
    surveying = halfway
    found = RangeEstimate(max_disparity=12, source="auto", warning="views look swapped")
    queued = surveying.priced(T0, [0.5, 1.5], found, 3, 120)
    assert queued is not None and queued.state is JobState.QUEUED and not queued.dispatched
    assert queued.estimate_seconds == [0.5, 1.5] and queued.levels_total == 3
    assert queued.disparity_range == found and queued.memory_mb == 120
    assert queued.warnings == ["views look swapped", "scale inferred"]
    assert queued.pricing_stage is None and queued.pricing_fraction is None
    assert queued.pricing_at("admitting", 1.0) is None
    assert queued.priced(T0, [1.0], None, 1, 1) is None  # priced once
    assert pricing.cancelled(T0).state is JobState.CANCELLED
    assert pricing.failed(T0, "refused: not enough QPU budget").state is JobState.FAILED


class JobLifecycle(RuleBasedStateMachine):
    """Random sequences of every change, applied as the store applies them (None: unchanged)."""

    def __init__(self) -> None:
        super().__init__()
        self.record = record()
        self.clock = T0
        self.moves: list[tuple[JobState, JobState]] = []

    def apply(self, change, *args) -> None:
        self.clock += timedelta(seconds=1)
        before = self.record
        after = change(before.model_copy(deep=True), *args)
        if after is None:
            return
        assert allowed(before.state, after.state), (before.state, after.state)
        self.moves.append((before.state, after.state))
        self.record = JobRecord.model_validate_json(after.model_dump_json())  # as stored

    @rule()
    def start(self) -> None:
        self.apply(JobRecord.started, self.clock)

    @rule(top=st.integers(1, 64), levels=st.integers(1, 4))
    def resolve_range(self, top: int, levels: int) -> None:
        self.apply(JobRecord.with_range, RangeEstimate(top, "given"), levels)

    @rule(total=st.integers(0, 9), here=st.booleans())
    def advance(self, total: int, here: bool) -> None:
        self.apply(JobRecord.at_level, len(self.record.levels), total, here)

    @rule(skew=st.integers(-1, 1))
    def assemble(self, skew: int) -> None:
        index = max(0, len(self.record.levels) + skew)
        self.apply(JobRecord.with_level, index, level(index))

    @rule()
    def succeed(self) -> None:
        self.apply(JobRecord.succeeded, self.clock, {"rmse": float("nan")}, "")

    @rule(message=st.text(max_size=5))
    def fail(self, message: str) -> None:
        self.apply(JobRecord.failed, self.clock, message)

    @rule()
    def cancel(self) -> None:
        self.apply(JobRecord.cancelled, self.clock)

    @rule(stale=st.booleans())
    def restart(self, stale: bool) -> None:
        self.apply(JobRecord.restarted, self.clock, self.record.level + int(stale))

    @rule(to=st.sampled_from(JobState), limit=st.sampled_from([None, ACTIVE, {JobState.QUEUED}]))
    def move(self, to: JobState, limit) -> None:
        self.apply(JobRecord.moved, to, self.clock, limit)

    @invariant()
    def consistent(self) -> None:
        current = self.record
        assert (current.finished_at is not None) == current.state.terminal
        if current.state is not JobState.QUEUED:
            assert current.started_at is not None or current.state.terminal
        assert [entry.index for entry in current.levels] == list(range(len(current.levels)))
        if current.state is JobState.QUEUED:
            assert current.level == 0 and not current.levels
        if current.metrics is not None:
            assert current.metrics == {"rmse": None}  # non-finite scores stored as null
        assert not any(before.terminal for before, _ in self.moves)  # a final state is the last


JobLifecycle.TestCase.settings = settings_(max_examples=60, stateful_step_count=25, deadline=None)
TestJobLifecycle = JobLifecycle.TestCase


def test_levels_and_range_are_typed_and_keep_the_stored_json():
    stored = record(JobState.RUNNING).model_dump(mode="json")
    stored |= {"levels": [{**STORED_LEVEL, "added_later": 3}], "disparity_range": STORED_RANGE}
    loaded = JobRecord.model_validate_json(json.dumps(stored))
    assert loaded.disparity_range == RangeEstimate(8, "auto", 0.75)
    assert loaded.levels[0].bundles == 4 and loaded.levels[0].added_later == 3  # kept
    assert json.loads(loaded.model_dump_json()) == stored


def test_a_level_record_is_the_core_report_with_null_for_non_finite_numbers():
    fields = {field.name for field in dataclasses.fields(LevelReport)}
    assert set(LevelRecord.model_fields) == fields
    report = LevelReport(**{**STORED_LEVEL, "energy": float("inf"), "gap": float("nan")})
    stored = LevelRecord.of(report)
    assert stored.energy is None and stored.gap is None and stored.info == {"embeddings": 1}


def test_the_job_status_reads_the_typed_levels_as_it_read_the_dicts():
    typed = record(JobState.RUNNING, levels=[level(0)], disparity_range=STORED_RANGE)
    as_dicts = typed.model_dump(mode="json")
    status = {"progress": {"level": 1, "levels": 1, "bundles_done": 0, "bundles_total": 0},
              "usage": {}, "links": {"self": "/", "disparity": "/", "preview": "/"}}  # fmt: skip
    common = {"solver": typed.config.solver, **status}
    new = JobStatus.model_validate({**typed.__dict__, **common}).model_dump_json()
    old = JobStatus.model_validate({**as_dicts, **common}).model_dump_json()
    assert new == old
    assert "info" not in json.loads(new)["levels"][0]
    assert LevelTiming.model_validate(level(0)).bundles == 4
