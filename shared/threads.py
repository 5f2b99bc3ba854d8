"""How many threads each process's native pools may use: OpenCV's, OpenMP's (numba's ``omp``
threading layer and the BLAS numpy links), OpenBLAS's, MKL's and numba's.

Each of them starts one thread per core by default. That is right for one process alone (``qhsm
match``), but a Celery worker runs one pool process per core, and each would then start a thread
per core in every library: on 2 cores, 2 processes x 2 threads x each library, all busy at once.
So every process calls :func:`limit_threads` at start with its share of the cores
(:func:`thread_budget`), and a worker's subprocess gets the same share in its environment
(:func:`thread_environment`) before any library reads it: numba reads ``NUMBA_NUM_THREADS`` once,
at import, and OpenMP and BLAS read theirs when they load. A variable the user has set wins.

Code that runs its own threads around these libraries (a thread pool over row blocks) sizes it
with :func:`threads` so the two do not multiply.
"""

from __future__ import annotations

import os
import sys
import threading
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import Executor, ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any, TypeVar

#: The environment variables the native thread pools read when they start.
THREAD_VARIABLES = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "NUMBA_NUM_THREADS",
)

#: Set by :func:`limit_threads` for the processes it starts: the user's own thread count ("" for
#: none), so that the values it wrote into :data:`THREAD_VARIABLES` are not taken for the user's.
USER_VARIABLE = "QHSM_USER_THREADS"

T = TypeVar("T")
U = TypeVar("U")

_budget: int | None = None
#: Cores of the budget held by :func:`holding_core` tasks now.
_held = 0
_held_lock = threading.Lock()


def cores() -> int:
    """The cores this process may run on (its CPU affinity; the CPU count elsewhere).

    Returns
    -------
    int
        At least 1.
    """
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def _user_threads(environ: Mapping[str, str]) -> int | None:
    """The thread count the user set (``OMP_NUM_THREADS`` first), if any is a positive int."""
    names = (USER_VARIABLE,) if USER_VARIABLE in environ else THREAD_VARIABLES
    for name in names:
        value = environ.get(name, "").strip()
        if value.isdigit() and int(value) > 0:
            return int(value)
    return None


def thread_budget(processes: int = 1, environ: Mapping[str, str] | None = None) -> int:
    """Threads per process when ``processes`` processes share this machine's cores.

    Parameters
    ----------
    processes : int, optional
        Processes that run at the same time (a worker's pool size; 1 for ``qhsm match``).
    environ : mapping, optional
        The environment to read a user's setting from (default: this process's).

    Returns
    -------
    int
        The user's ``OMP_NUM_THREADS`` (or another of :data:`THREAD_VARIABLES`) when set, else
        the cores divided among the processes, at least 1.
    """
    given = _user_threads(os.environ if environ is None else environ)
    if given is not None:
        return given
    return max(1, cores() // max(1, processes))


def thread_environment(threads: int, environ: Mapping[str, str] | None = None) -> dict[str, str]:
    """The variables that give a new process ``threads`` threads per library.

    Parameters
    ----------
    threads : int
        Threads per library.
    environ : mapping, optional
        The environment the process starts from: a count the user set there is kept.

    Returns
    -------
    dict
        Every name of :data:`THREAD_VARIABLES` with its value (the user's when set), and
        :data:`USER_VARIABLE`.
    """
    environ = os.environ if environ is None else environ
    given = _user_threads(environ)
    value = str(given or threads)
    return {**{name: value for name in THREAD_VARIABLES}, USER_VARIABLE: str(given or "")}


def inherited_threads(environ: Mapping[str, str] | None = None) -> int | None:
    """The budget a qhsm parent gave this process in its environment
    (:func:`thread_environment`), if it did.

    Parameters
    ----------
    environ : mapping, optional
        Default: this process's environment.

    Returns
    -------
    int or None
        None when no qhsm process started this one with a budget.
    """
    environ = os.environ if environ is None else environ
    value = environ.get("NUMBA_NUM_THREADS", "").strip()
    if USER_VARIABLE in environ and value.isdigit() and int(value) > 0:
        return int(value)
    return None


def limit_threads(threads: int) -> int:
    """Size this process's thread pools: OpenCV's now, numba's for the calling thread now (when
    it is loaded), and every library's that starts later through the environment.

    Parameters
    ----------
    threads : int
        Threads per library (see :func:`thread_budget`).

    Returns
    -------
    int
        ``threads``, also what :func:`threads` answers from now on.
    """
    global _budget
    import cv2

    threads = max(1, int(threads))
    os.environ.update(thread_environment(threads))
    cv2.setNumThreads(threads)
    numba = sys.modules.get("numba")
    if numba is not None:  # already loaded: its pool size was read at import
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    _budget = threads
    return threads


def threads() -> int:
    """This process's thread budget: what :func:`limit_threads` set, else every core.

    Returns
    -------
    int
        At least 1.
    """
    return _budget if _budget is not None else thread_budget()


def beside(function: Callable[..., T], *args: Any, **kwargs: Any) -> Callable[[], T]:
    """Start ``function(*args, **kwargs)`` in a thread of its own when this process's budget
    (:func:`threads`) has a core to spare, else call it now; the result is a getter that waits
    for it (and raises what it raised). Why: NumPy and OpenCV release the GIL, so independent
    steps of a run (the views' check, the other view's cost volume) take the idle core."""
    if threads() < 2:
        value = function(*args, **kwargs)
        return lambda: value
    pool = ThreadPoolExecutor(1, thread_name_prefix="qhsm-beside")
    future = pool.submit(function, *args, **kwargs)
    pool.shutdown(wait=False)  # the thread ends with the call
    return future.result


def each_beside(function: Callable[..., T], arguments: Sequence[Sequence[Any]]) -> list[T]:
    """``[function(*a) for a in arguments]``: the first call in this thread, the others
    :func:`beside` it (every view's share of a step on the cores the budget has)."""
    later = [beside(function, *args) for args in arguments[1:]]
    return [function(*arguments[0]), *(result() for result in later)]


@contextmanager
def holding_core() -> Iterator[None]:
    """Count the calling thread's task on one of the budget's cores while the block runs (the
    views' grids minimised side by side), for :func:`spare_core`."""
    global _held
    with _held_lock:
        _held += 1
    try:
        yield
    finally:
        with _held_lock:
            _held -= 1


def spare_core() -> bool:
    """Whether the budget has a core that no :func:`holding_core` task holds: a grid
    minimised alone (a 2000 x 2000 pair's views one at a time), or the last of the views still
    running, may then split its work over a second thread."""
    return _held < threads()


def both(first: Callable[[], T], second: Callable[[], U], helper: Executor | None) -> tuple[T, U]:
    """``(first(), second())``, the second on ``helper``'s thread meanwhile when there is one
    (independent steps: the same results either way)."""
    if helper is None:
        return first(), second()
    later = helper.submit(second)
    return first(), later.result()
