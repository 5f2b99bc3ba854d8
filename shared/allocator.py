"""How a one-pair process's C allocator (glibc's malloc) treats the memory the run frees.

By default glibc hands a freed block back to the kernel when it was mapped on its own (blocks
from 128 KiB up, a threshold it raises as such blocks are freed) or when it ends the heap (the
128 KiB trim threshold); the next array of that size is then faulted in page by page again. A
run allocates and frees arrays of a level's size at every iteration of dual decomposition: on
Aloe, ``qhsm match`` took 240 000 page faults and 0.7 s of system time, and with freed blocks
under 32 MiB kept for reuse 170 000 and 0.55 s, 2.11 -> 2.00 s wall (medians of 6 alternated
runs; peak RSS 615 -> 645 MiB; docs/benchmarks.md, "The weighted median on every core, ...,
freed memory kept").
Blocks of 32 MiB and more (a cost volume) are still mapped on their own and returned.

Only for a process that runs one pair and exits (``qhsm match``): a service worker would keep
its largest job's memory between jobs.
"""

from __future__ import annotations

import ctypes
from typing import Final

#: mallopt's parameters (glibc's malloc.h).
M_TRIM_THRESHOLD: Final = -1
M_MMAP_THRESHOLD: Final = -3
#: Blocks from this size up are mapped on their own: the largest threshold glibc accepts on
#: 64-bit systems (its ``DEFAULT_MMAP_THRESHOLD_MAX``), so only volumes-sized arrays are.
MMAP_THRESHOLD: Final = 32 * 1024 * 1024
#: Free memory at the heap's end kept rather than trimmed: all of it (mallopt takes an int).
TRIM_THRESHOLD: Final = 2**31 - 1


def keep_freed_memory() -> bool:
    """Keep freed blocks under :data:`MMAP_THRESHOLD` for the process's next allocations.

    Returns
    -------
    bool
        Whether the allocator took the setting (glibc); elsewhere nothing changes.
    """
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # not glibc (macOS, Windows)
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(
        mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD)
    )
