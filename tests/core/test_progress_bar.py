"""The progress shown while a run or a job goes on: elapsed time and ETA per level, the time in
all, and words instead of an empty 0/0 before a level's bundles are known."""

from __future__ import annotations

import io
import re

from shared.activity import report, reporting
from shared.progress_bar import LevelBar, describe


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def _job(bar: LevelBar) -> None:
    """What a job's status goes through: queued, preparing, three levels, succeeded."""
    bar.update(0, 3, 0, 0, "queued")
    bar.update(0, 3, 0, 0, "running")
    for level in (1, 2, 3):
        for done in range(0, 577, 96):
            bar.update(level, 3, done, 576)
    bar.update(3, 3, 576, 576, "succeeded")
    bar.close()


def test_a_terminal_gets_a_bar_with_elapsed_time_and_eta_per_level():
    screen = Terminal()
    _job(LevelBar(screen))
    frames = screen.getvalue().split("\r")
    assert any(frame.startswith("queued: waiting for a worker [00:00") for frame in frames)
    assert any(frame.startswith("level 1/3: preparing [") for frame in frames)
    bars = [frame for frame in frames if "bundles [" in frame]
    assert bars and all(" this level, " in frame and " in all]" in frame for frame in bars)
    eta = re.compile(r"\d+/576 bundles \[\d\d:\d\d<\d\d:\d\d this level")  # elapsed < ETA
    assert any(eta.search(frame) for frame in bars)
    assert frames[-1].strip().startswith("succeeded: level 3/3 |")
    assert "0/0" not in screen.getvalue()


def test_a_log_gets_one_line_per_level_and_state():
    log = io.StringIO()
    _job(LevelBar(log))
    lines = log.getvalue().splitlines()
    assert lines[:2] == ["queued: waiting for a worker", "level 1/3: preparing"]
    assert [line.split(" (")[0] for line in lines[2:]] == [
        "level 1/3: 576 bundles done",
        "level 2/3: 576 bundles done",
        "level 3/3: 576 bundles done",
        "succeeded: level 3/3: 576/576 bundles",
    ]
    assert all(line.endswith(" in all)") for line in lines[2:])


def test_the_words_for_each_state():
    assert describe(2, 3, 576) == "level 2/3"
    assert describe(0, 3, 0) == "level 1/3: preparing"
    assert describe(0, 0, 0) == "level 1/?: preparing"  # a job's range is not estimated yet
    assert describe(1, 3, 0, "queued") == "queued: waiting for a worker"
    assert describe(0, 0, 0, "pricing").startswith("pricing: ")  # a metered job before queued
    assert describe(2, 3, 576, "cancelled") == "cancelled: level 2/3"


def test_a_level_being_prepared_says_what_it_is_doing():
    phase = "embedding a 64-variable tile shape into Pegasus P16: sublattice m=4 (2/4), 10 tries"
    assert describe(1, 3, 0, phase=phase) == f"level 1/3: {phase}"
    assert describe(1, 3, 576, phase=phase) == "level 1/3"  # bundles known: the bar says it
    log = io.StringIO()
    bar = LevelBar(log)
    bar.update(2, 3, 0, 0)
    with reporting(bar.show_phase):  # what qhsm match does around the pipeline
        report("embedding a 64-variable tile shape: cached")
    report("outside any block: nowhere")
    bar.close()
    assert log.getvalue().splitlines() == [
        "level 2/3: preparing",
        "level 2/3: embedding a 64-variable tile shape: cached",
    ]
