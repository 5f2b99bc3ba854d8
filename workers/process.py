"""Process lifetime and limits: children die with the process that started them (Linux
parent-death signal), so nothing ``qhsm serve`` or a Celery worker starts outlives it, even after
SIGKILL; a pool process's memory is capped so one task cannot take the machine's."""

from __future__ import annotations

import contextlib
import ctypes
import os
import resource
import signal

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


def limit_memory(megabytes: int | None) -> None:
    """Cap this process's address space (``RLIMIT_AS``) at ``megabytes`` MiB: an allocation
    beyond it raises ``MemoryError`` in this process instead of taking the machine's memory.

    Parameters
    ----------
    megabytes : int or None
        The ceiling; 0 or None leaves the limit as it is."""
    if not megabytes:
        return
    _, hard = resource.getrlimit(resource.RLIMIT_AS)
    ceiling = megabytes * 2**20
    if hard != resource.RLIM_INFINITY:
        ceiling = min(ceiling, hard)
    resource.setrlimit(resource.RLIMIT_AS, (ceiling, hard))


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
