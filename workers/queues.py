"""The solver queues, from the registry: the workers' one door to it. A task resolves its job's
solver here once (:func:`job_solver`) and hands the :class:`ResolvedSolver` along (the level's
inference, the meter's reservations, the estimates); no other worker module looks a solver up.

The queues a group of workers consumes (``SolverSpec.workers``): ``python -m workers.queues
cpu`` prints ``exact,sa,...,dimod`` for ``celery worker -Q``, as docker-compose.yml's worker
services run it; without a group it lists every group. A solver added to the registry (or by an
installed ``qhsm.solvers`` plugin) is then consumed without editing the compose file."""

from __future__ import annotations

import logging
import sys

from shared.config import MatchConfig
from shared.solvers.records import DIMOD_QUEUE
from shared.solvers.registry import queue_names, resolve, solver_names, worker_groups
from shared.solvers.resolved import ResolvedSolver

log = logging.getLogger(__name__)


def job_solver(config: MatchConfig) -> ResolvedSolver:
    """The job's solver resolved with its configuration (``UnknownSolverError`` for a name no
    longer registered): once per task, then passed along."""
    return resolve(config)


def solver_queue(solver: str) -> str:
    """The Celery queue of solver ``solver``'s bundles."""
    return resolve(solver).spec.queue_name


def solver_queues() -> list[str]:
    """Every solver queue a worker may consume (the registered solvers' and ``dimod``)."""
    return queue_names()


def token_queues() -> set[str]:
    """Queues of solvers that spend real D-Wave time: only their workers get the token."""
    solvers = [resolve(name) for name in solver_names()]
    return {solver.spec.queue_name for solver in solvers if solver.spec.uses_qpu_time}


def local_queues() -> tuple[list[str], list[str]]:
    """Queues of the solvers that run on this machine: (CPU ones, with the dimod queue; those
    that spend QPU time and need the D-Wave token)."""
    cpu: list[str] = [DIMOD_QUEUE]
    dwave: list[str] = []
    for name in solver_names():
        solver = resolve(name)
        try:
            runs_here = solver.sampler.available().ok
        except Exception as error:  # an adapter with a missing dependency
            log.warning("solver %s cannot load here: %s", name, error)
            continue
        if runs_here:
            (dwave if solver.spec.uses_qpu_time else cpu).append(solver.spec.queue_name)
    return cpu, dwave


def main(argv: list[str] | None = None) -> int:
    """Print one group's queues (comma-separated), or every ``group: queues`` line."""
    args = sys.argv[1:] if argv is None else argv
    groups = worker_groups()
    if not args:
        for group, queues in groups.items():
            print(f"{group}: {','.join(queues)}")
        return 0
    if args[0] not in groups:
        print(f"unknown worker group {args[0]!r}; known: {', '.join(groups)}", file=sys.stderr)
        return 2
    print(",".join(groups[args[0]]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
