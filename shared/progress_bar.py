"""The progress bar of a run, on stderr: the bundles of the level in hand, with the level's
elapsed time and ETA and the run's elapsed time, e.g.::

    level 2/3 |██████▌      | 300/576 bundles [00:12<00:10 this level, 00:31 in all]

``qhsm match`` feeds it from the pipeline's progress callback, ``qhsm submit`` / ``wait`` /
``demo`` from the job status they poll. Before a level's bundles are known (a job waiting for a
worker, a level being prepared: e.g. the embedding search of a QPU solver) it shows what is
going on and the time so far instead of an empty ``0/0``.
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


def clock(seconds: float) -> str:
    """``mm:ss`` (``h:mm:ss`` from an hour), as tqdm writes times."""
    return tqdm.format_interval(seconds)


class LevelBar:
    """A tqdm bar over the bundles of the level in hand, restarted at every level (so its rate
    and ETA are the level's own), with the run's elapsed time after it.

    Parameters
    ----------
    stream : file, optional
        Where it draws; default: ``sys.stderr`` at the time of the call (so stdout stays free
        for ``--json``).
    started : float, optional
        ``time.monotonic()`` when the run started (default: now).
    leave : bool, default True
        Keep the last state drawn when closed; False: clear it (a summary or an error line
        follows in its place).
    """

    def __init__(
        self, stream: IO[str] | None = None, started: float | None = None, leave: bool = True
    ) -> None:
        self.stream = stream or sys.stderr
        self.started = time.monotonic() if started is None else started
        self.leave = leave
        self._bar: tqdm | None = None
        self._shown: tuple[int, bool, int] | None = None  # level, bundles known, total
        self._drawn = 0.0

    def update(
        self, level: int, levels: int, done: int, total: int, state: str = "running"
    ) -> None:
        """Show that ``done`` of the ``total`` bundles of level ``level`` (1-based) of
        ``levels`` are solved; ``total`` 0: the level is being prepared (not fanned out yet).
        ``state`` is a job's (``queued``, ``running``, ``succeeded``, ...); any but running
        is shown in front."""
        known = total > 0 and state != "queued"
        if state == "queued":
            text = "queued: waiting for a worker"
        elif known:
            text = f"level {level}/{levels}"
        else:
            text = f"level {max(level, 1)}/{levels}: preparing"
        if state not in ("queued", "running"):
            text = f"{state}: {text}"
        shown, self._shown = self._shown, (level, known, total)
        now = time.monotonic()
        in_all = f"{clock(now - self.started)} in all"
        if self._bar is None:
            self._bar = tqdm(
                file=self.stream,
                desc=text,
                postfix=in_all,
                total=total if known else None,
                bar_format=BAR_FORMAT if known else WAIT_FORMAT,
                dynamic_ncols=True,
                leave=self.leave,
            )
            changed = True
        else:
            changed = shown != self._shown or text != self._bar.desc
            if shown != self._shown or done < self._bar.n:
                # a new level (or its bundles now known): the level's own rate and ETA
                self._bar.reset(total=total if known else None)
                self._bar.bar_format = BAR_FORMAT if known else WAIT_FORMAT
        self._bar.set_description_str(text, refresh=False)
        self._bar.set_postfix_str(in_all, refresh=False)
        if known and done != self._bar.n:
            self._bar.update(done - self._bar.n)  # feeds tqdm's rate, hence the ETA
            changed = changed or done == total
        if changed or now - self._drawn >= REDRAW_SECONDS:
            self._bar.refresh()
            self._drawn = now

    def write(self, line: str) -> None:
        """Print a line above the bar (a warning, a note)."""
        tqdm.write(line, file=self.stream)

    def close(self) -> None:
        """Leave the bar as last drawn and move to the next line (or clear it: ``leave``)."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
