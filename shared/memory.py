"""Memory as a resource a job is admitted for: the peak memory a job's run is estimated to take
(from its size, disparity range and solver), and the budget one worker process has (its host's
memory shared among the host's worker processes).

The estimate is fitted to measured peaks (docs/benchmarks.md, "Memory of a job: calibration"):
a process's base (Python, numpy, numba, OpenCV), the cost volume cache, and bytes per
pixel-candidate of the largest level a process holds (both views at once while their dual state
fits in ``shared.inference.grid_views.GRID_STATE_BYTES``, one after the other beyond) times a
solver factor.
"""

from __future__ import annotations

import math
import os

from shared.config import MatchConfig
from shared.pyramid import plan
from shared.settings import Settings

#: A process's resident memory before a level is built (interpreter, numpy, numba, OpenCV), MiB.
BASE_MB = 390.0
#: Bytes per pixel-candidate of a level held at once (costs, dual state, labels, images).
BYTES_PER_CANDIDATE = 30.0
#: The in-process cost volume cache (``shared.pipeline``: volumes below 256 MiB are kept):
#: pixels x (range + 1) float32 per view, up to this much, MiB.
VOLUME_CACHE_MB = 256.0
#: Extra factor of solvers that hold more than the host's dual decomposition (QUBO tiles, their
#: samples); ``dimod:`` samplers are unbounded in principle (a tree decomposition grows with the
#: bundle's treewidth): they run under the same runtime limit, this only prices them higher.
SOLVER_FACTOR = {"exact": 1.0}
QUBO_FACTOR = 1.25
DIMOD_FACTOR = 2.0
#: Pixel-candidates whose dual state is held by both views at once (``grids_at_once``).
BOTH_VIEWS_BELOW = 1 * 2**30 / 24


class MemoryBudgetError(ValueError):
    """A job estimated above a worker process's memory budget (the message names both)."""

    def __init__(self, memory: int, budget: int):
        super().__init__(
            f"this job needs about {memory} MiB of memory at its peak, above the limit of "
            f"{budget} MiB per worker process (its share of the host's memory: "
            "QHSM_MEMORY_HOST_FRACTION and QHSM_HOST_WORKER_PROCESSES, or "
            "QHSM_TASK_MEMORY_LIMIT_MB); send a smaller pair or range (max_disparity), or ask "
            "the operator for workers with more memory"
        )
        self.memory, self.budget = memory, budget


def check_fits(memory: int, budget: int | None) -> None:
    """:class:`MemoryBudgetError` when ``memory`` is above ``budget`` (None: no limit)."""
    if budget is not None and memory > budget:
        raise MemoryBudgetError(memory, budget)


def job_memory_mb(config: MatchConfig, height: int, width: int, max_disparity: int) -> int:
    """The estimated peak memory of one worker process running the job, MiB.

    Parameters
    ----------
    config : MatchConfig
        The job's configuration (pyramid, views, solver).
    height, width : int
        The views' size, pixels.
    max_disparity : int
        The resolved range, full-resolution pixels.

    Returns
    -------
    int
        MiB, rounded up.
    """
    levels = plan(config, max_disparity)
    views = 2 if config.lr_check else 1
    held = 0.0
    for level in levels:
        pixels = math.ceil(height / level.downsample) * math.ceil(width / level.downsample)
        one_view = pixels * level.candidates
        # both views while their dual state fits, else one after the other (never less than
        # what fits: the estimate grows with the size)
        held = max(held, one_view, min(one_view * views, BOTH_VIEWS_BELOW))
    solver = config.solver
    factor = SOLVER_FACTOR.get(solver, DIMOD_FACTOR if solver.startswith("dimod:") else QUBO_FACTOR)
    volume = min(height * width * (max_disparity + 1) * 4 * views / 2**20, VOLUME_CACHE_MB)
    return math.ceil(BASE_MB + volume + factor * held * BYTES_PER_CANDIDATE / 2**20)


def host_memory_mb() -> int:
    """This host's physical memory, MiB (cgroup limits are not read: set
    ``QHSM_TASK_MEMORY_LIMIT_MB`` in a container)."""
    return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") // 2**20)


def worker_budget_mb(settings: Settings, processes: int | None = None) -> int | None:
    """The memory one worker process may use, MiB: this host's memory x
    ``memory_host_fraction`` shared among ``processes`` (``host_worker_processes``, else one
    process per core: `qhsm serve`'s CPU worker), and at most ``task_memory_limit_mb`` when set;
    so the sum over a host's processes stays within what it has. None: no limit
    (``task_memory_limit_mb`` 0)."""
    if settings.task_memory_limit_mb == 0:
        return None
    count = processes or settings.host_worker_processes or os.cpu_count() or 1
    derived = int(host_memory_mb() * settings.memory_host_fraction / count)
    if settings.task_memory_limit_mb:
        return min(derived, settings.task_memory_limit_mb)
    return derived
