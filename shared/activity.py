"""What a long step of a run is doing, in words, for whoever watches it: a job's status shows
it as the level's ``phase`` while the level is prepared (``level 1/3: embedding a 64-variable
tile shape into Pegasus P16: sublattice m=4, 10 tries``), so that no job waits in "preparing"
without saying why.

A worker opens :func:`reporting` around a step with a callback that stores the text with the
job (``workers.orchestration``); code deep inside the step (the embedding search of
:mod:`shared.solvers.qpu.packing`) calls :func:`report`. Outside such a block (``qhsm match``)
:func:`report` does nothing: the step's own log lines remain.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar

Reporter = Callable[[str], None]

_current: ContextVar[Reporter | None] = ContextVar("qhsm_activity", default=None)


@contextmanager
def reporting(callback: Reporter) -> Iterator[None]:
    """Send every :func:`report` inside the block to ``callback`` (the innermost block wins).

    Parameters
    ----------
    callback : callable
        Given each text as it is reported.
    """
    token = _current.set(callback)
    try:
        yield
    finally:
        _current.reset(token)


def report(text: str) -> None:
    """Tell the open :func:`reporting` block what is being done now (nothing outside one).

    Parameters
    ----------
    text : str
        In words, e.g. ``embedding: cached``.
    """
    callback = _current.get()
    if callback is not None:
        callback(text)
