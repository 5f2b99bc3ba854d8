"""A ``solve_level`` over local worker processes (``qhsm match --processes``, the benchmarks):
the same bundles and seeds as :func:`shared.inference.solve_level_in_process`, so the same
result."""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from functools import partial
from multiprocessing import get_context
from multiprocessing.pool import Pool

from shared.assembly import BundleResult, LevelSolution
from shared.config import MatchConfig
from shared.inference import BundleProgress, inference_for, solve_bundles, solve_level_in_process
from shared.level_inputs import LevelInputs
from shared.threads import limit_threads, thread_budget


class ProcessPoolLevelSolver:
    """A ``solve_level`` that spreads a level's bundles over local worker processes.

    Bundles are independent and seeded by position, so the result equals the sequential one.
    A level whose inference does not split (``LevelInference.splits``: the exact DP's,
    vectorised over rows already; a batch solver's, one problem a level) runs in this process;
    the pool is started by the first level that needs it (never for them: idle children cost a
    second of CPU to start). Use as a context manager so the pool lives across levels. The
    children ignore Ctrl-C (SIGINT reaches the whole process group): the parent terminates them
    when it leaves the block on an exception.
    """

    def __init__(self, processes: int | None = None) -> None:
        self.processes = processes or os.cpu_count() or 1
        self._pool: Pool | None = None

    def __enter__(self) -> ProcessPoolLevelSolver:
        return self

    def _started(self) -> Pool:
        """The pool, started on first use."""
        if self._pool is None:
            # spawn, not fork: forking a process that already runs threads (OpenBLAS, OpenCV,
            # an HTTP client) can deadlock the children. Solvers come from the registry's
            # importable factories, so every child sees the same adapters.
            with _sigint_ignored():  # inherited from birth: no child prints a traceback
                budget = (thread_budget(self.processes),)  # each child its share of the cores
                self._pool = get_context("spawn").Pool(self.processes, limit_threads, budget)
        return self._pool

    def __exit__(self, exc_type: type[BaseException] | None, *exc_info: object) -> None:
        if self._pool is not None:
            if exc_type is None:
                self._pool.close()
            else:  # interrupted or failed: what the children solve now is not wanted
                self._pool.terminate()
            self._pool.join()
            self._pool = None

    def __call__(
        self, inputs: LevelInputs, config: MatchConfig, progress: BundleProgress | None = None
    ) -> LevelSolution:
        inference = inference_for(config)
        if self.processes <= 1 or not inference.splits:
            return solve_level_in_process(inputs, config, progress)
        pool = self._started()
        bundles = inference.plan(inputs, config)
        count = self.processes * 4
        # consecutive bundles stay together: segments of one row then share its costs
        size = -(-len(bundles) // count)
        chunks = [bundles[i : i + size] for i in range(0, len(bundles), size)]
        # the children build costs per bundle; the in-process volume cache is not worth sending
        solve = partial(solve_bundles, replace(inputs, volumes=None), config)
        results: list[BundleResult] = []
        if progress is not None:
            progress(0, len(bundles))
        for chunk_results in pool.imap(solve, chunks):  # in order, as they finish
            results.extend(chunk_results)
            if progress is not None:
                progress(len(results), len(bundles))
        return inference.assemble(inputs, results, config)


@contextmanager
def _sigint_ignored() -> Iterator[None]:
    """SIGINT ignored while the pool's children start: they inherit that and keep it (Python
    leaves an ignored SIGINT alone), so Ctrl-C is the parent's alone, which terminates them."""
    if threading.current_thread() is not threading.main_thread():
        yield  # signal dispositions can only be changed from the main thread
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
