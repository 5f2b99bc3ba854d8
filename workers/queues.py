"""The solver queues a group of workers consumes, from the registry (``SolverSpec.workers``):
``python -m workers.queues cpu`` prints ``exact,sa,...,dimod`` for ``celery worker -Q``, as
docker-compose.yml's worker services run it; without a group it lists every group. A solver
added to the registry (or by an installed ``qhsm.solvers`` plugin) is then consumed without
editing the compose file."""

from __future__ import annotations

import sys

from shared.solvers.registry import worker_groups


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
