"""Process lifetime and limits: children die with the process that started them (Linux
parent-death signal), so nothing ``qhsm serve`` or a Celery worker starts outlives it, even after
SIGKILL; a task's memory is capped at its process's budget so one task cannot take the
machine's."""

from __future__ import annotations

import contextlib
import ctypes
import os
import resource
import signal
from collections.abc import Iterator

PR_SET_PDEATHSIG = 1


def die_with_parent(signum: int = signal.SIGKILL) -> None:
    """Ask Linux to send ``signum`` to this process when its parent (thread) dies.

    Used as ``preexec_fn`` and in Celery pool processes; a no-op where prctl is missing."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, int(signum), 0, 0, 0)
    except (OSError, AttributeError):
        return


def kill_now(pid: int) -> None:
    """SIGKILL ``pid``; one that has already exited is fine.

    Parameters
    ----------
    pid : int
        The process to kill (a worker's pool process, a stale redis-server)."""
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGKILL)


def resident_and_virtual() -> tuple[int, int] | None:
    """This process's resident memory and address space, bytes (Linux ``/proc``; None
    elsewhere)."""
    try:
        with open("/proc/self/statm", encoding="ascii") as statm:
            size, resident = (int(value) for value in statm.read().split()[:2])
    except (OSError, ValueError):
        return None
    page = os.sysconf("SC_PAGE_SIZE")
    return resident * page, size * page


@contextlib.contextmanager
def memory_budget(megabytes: int | None) -> Iterator[None]:
    """Within the block, this process may grow to about ``megabytes`` MiB resident: its
    address space (``RLIMIT_AS``) is capped at what it has mapped now plus what the budget
    leaves of its resident memory (what numba, thread stacks and allocator arenas reserve
    without using is already counted), so an allocation beyond raises ``MemoryError`` here
    (caught by the task, which fails its job with a message) instead of taking the machine's
    memory; a ``dimod:`` sampler's C code runs under it too. The limit is restored after.

    Parameters
    ----------
    megabytes : int or None
        The process's budget (``shared.memory.worker_budget_mb``); None or 0: no limit."""
    sizes = resident_and_virtual()
    if not megabytes or sizes is None:
        yield
        return
    resident, virtual = sizes
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    ceiling = virtual + max(megabytes * 2**20 - resident, MIN_ROOM)
    for bound in (soft, hard):
        if bound != resource.RLIM_INFINITY:
            ceiling = min(ceiling, bound)
    resource.setrlimit(resource.RLIMIT_AS, (ceiling, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


#: Address space a budgeted block may always add (a process already at its budget still
#: reads its task's messages and fails the job), bytes.
MIN_ROOM = 64 * 2**20


def lower_priority(increment: int) -> None:
    """Make this process ``increment`` nicer (once: later calls change nothing), so that on a
    shared machine solver work yields the CPU to orchestration and the API.

    Parameters
    ----------
    increment : int
        Niceness to add; 0 leaves the priority as it is."""
    global _lowered
    if increment and not _lowered:
        with contextlib.suppress(OSError):
            os.nice(increment)
        _lowered = True


_lowered = False
