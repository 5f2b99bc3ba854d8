"""The progress of a run on stderr: the bundles of the level in hand, with the level's elapsed
time and ETA and the run's elapsed time, e.g.::

    level 2/3 |██████▌      | 300/576 bundles [00:12<00:10 this level, 00:31 in all]

``qhsm match`` feeds it from the pipeline's progress callback, ``qhsm submit`` / ``wait`` /
``demo`` from the job status they poll. Before a level's bundles are known (a job waiting for a
worker, a level being prepared: e.g. the embedding search of a QPU solver) it says what is going
on and the time so far instead of an empty ``0/0``. On a stream that is not a terminal (a log
file, CI) it writes one line per change of level or state instead of redrawing a bar.
"""

from __future__ import annotations

import sys
import time
from typing import IO

from tqdm import tqdm

#: With the level's bundles known.
BAR_FORMAT = "{desc} |{bar}| {n}/{total} bundles [{elapsed}<{remaining} this level{postfix}]"
#: Before they are (queued, preparing).
WAIT_FORMAT = "{desc} [{elapsed}{postfix}]"
#: Redraw at most this often for the clocks alone (bundles done redraw as tqdm sees fit).
REDRAW_SECONDS = 0.5
#: Job states during which the bar is live; any other is shown in front of the last level.
LIVE = ("pricing", "queued", "running")
#: Live states before the job's levels run (no bundles to count yet).
WAITING = ("pricing", "queued")


def clock(seconds: float) -> str:
    """``mm:ss`` (``h:mm:ss`` from an hour), as tqdm writes times.

    Parameters
    ----------
    seconds : float
        A duration.

    Returns
    -------
    str
    """
    return tqdm.format_interval(seconds)


def describe(
    level: int, levels: int, total: int, state: str = "running", phase: str | None = None
) -> str:
    """What the run is doing, in words: ``level 2/3``, ``level 1/3: preparing``, ``level 1/3:
    embedding ... : cached``, ``queued: waiting for a worker``, ``succeeded: level 3/3``.

    Parameters
    ----------
    level, levels : int
        The 1-based level in hand (0: none yet) and the run's levels.
    total : int
        The level's bundles; 0 while it is prepared.
    state : str, default "running"
        A job's state.
    phase : str, optional
        What preparing the level is doing (a job status's ``phase``), shown for "preparing".

    Returns
    -------
    str
    """
    if state == "queued":
        return "queued: waiting for a worker"
    if state == "pricing":
        return "pricing: a worker estimates its QPU time for the budget check"
    # levels 0: not known yet (a job's range is estimated when it starts)
    text = f"level {max(level, 1)}/{levels or '?'}" + ("" if total else f": {phase or 'preparing'}")
    return text if state in LIVE else f"{state}: {text}"


class LevelBar:
    """A tqdm bar over the bundles of the level in hand, restarted at every level (so its rate
    and ETA are the level's own), with the run's elapsed time after it.

    Parameters
    ----------
    stream : file, optional
        Where it draws; default: ``sys.stderr`` at the time of the call (so stdout stays free
        for ``--json``).
    leave : bool, default True
        Keep the last state drawn when closed; False: clear it (a summary or an error line
        follows in its place).
    """

    def __init__(self, stream: IO[str] | None = None, leave: bool = True) -> None:
        self.stream = stream or sys.stderr
        self.leave = leave
        self.started = time.monotonic()
        self.interactive = bool(getattr(self.stream, "isatty", lambda: False)())
        self._bar: tqdm | None = None
        self._shown: tuple[int, int] | None = None  # the level and its bundles drawn
        self._line = ""  # the last line written (not a terminal)
        self._drawn = 0.0
        self._level = (0, 0)  # the level in hand and the run's levels, as last updated

    def update(
        self,
        level: int,
        levels: int,
        done: int,
        total: int,
        state: str = "running",
        phase: str | None = None,
    ) -> None:
        """Show that ``done`` of the ``total`` bundles of level ``level`` (1-based) of
        ``levels`` are solved; ``total`` 0: the level is being prepared (not fanned out yet).

        Parameters
        ----------
        level, levels, done, total : int
            As the pipeline's progress callback and a job's progress give them.
        state : str, default "running"
            A job's state (``queued``, ``running``, ``succeeded``, ...); any but a live one is
            shown in front.
        phase : str, optional
            What preparing the level is doing (shown while ``total`` is 0).
        """
        total = 0 if state in WAITING else total
        self._level = (level, levels)
        text = describe(level, levels, total, state, phase)
        now = time.monotonic()
        in_all = f"{clock(now - self.started)} in all"
        if not self.interactive:
            self._log(text, state, done, total, in_all)
            return
        shown, self._shown = self._shown, (level, total)
        if self._bar is None:
            self._bar = tqdm(
                file=self.stream,
                desc=text,
                postfix=in_all,
                total=total or None,
                bar_format=BAR_FORMAT if total else WAIT_FORMAT,
                dynamic_ncols=True,
                leave=self.leave,
            )
            redraw = True
        else:
            redraw = shown != self._shown or text != self._bar.desc
            self._bar.set_description_str(text, refresh=False)
            if shown != self._shown or done < self._bar.n:  # a new level: its own rate and ETA
                self._bar.bar_format = BAR_FORMAT if total else WAIT_FORMAT
                self._bar.reset(total=total or None)
        self._bar.set_postfix_str(in_all, refresh=False)
        if total and done != self._bar.n:
            self._bar.update(done - self._bar.n)  # feeds tqdm's rate, hence the ETA
            redraw = redraw or done == total
        if redraw or now - self._drawn >= REDRAW_SECONDS:
            self._bar.refresh()
            self._drawn = now

    def _log(self, text: str, state: str, done: int, total: int, in_all: str) -> None:
        """One line per level finished, or change of state (queued, preparing, the end)."""
        if state not in LIVE:
            line = f"{text}: {done}/{total} bundles ({in_all})"
        elif total and done < total:
            return
        else:
            line = f"{text}: {total} bundles done ({in_all})" if total else text
        if line != self._line:
            self._line = line
            print(line, file=self.stream, flush=True)

    def show_phase(self, phase: str) -> None:
        """Say what preparing the level in hand is doing (a :func:`shared.activity.reporting`
        callback: e.g. its embedding search).

        Parameters
        ----------
        phase : str
        """
        self.update(*self._level, 0, 0, phase=phase)

    def write(self, line: str) -> None:
        """Print a line above the bar (a warning, a note).

        Parameters
        ----------
        line : str
        """
        tqdm.write(line, file=self.stream)

    def close(self) -> None:
        """Leave the bar as last drawn and move to the next line (or clear it: ``leave``)."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
