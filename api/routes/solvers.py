"""/v1/solvers: the registry, and which queues have workers. Any installed dimod sampler is a
solver too (``dimod:PACKAGE.MODULE.CLASS``, queue ``dimod``), though not listed here."""

from __future__ import annotations

from fastapi import APIRouter

from api.deps import ServicesDep, load_solver, solver_catalog
from api.schemas import SolverInfo

router = APIRouter(prefix="/solvers", tags=["solvers"])

#: What a :class:`SolverInfo` repeats of the registry's ``SolverSpec``, under the same names.
SPEC_FACTS = ("name", "description", "offline", "metered", "uses_qpu_time", "row_solver")


@router.get("", response_model=list[SolverInfo])
def list_solvers(svc: ServicesDep):
    """Every registered solver, whether it can run, and the workers consuming its queue."""
    consumers = svc.queues.consumers()
    infos = []
    for solver in solver_catalog():
        _, availability = load_solver(solver.spec.name)
        record = solver.spec
        workers = None if consumers is None else sorted(consumers.get(record.queue_name, []))
        infos.append(
            SolverInfo(
                **{fact: getattr(record, fact) for fact in SPEC_FACTS},
                available=availability.ok or bool(workers),
                available_here=availability.ok,
                reason=availability.reason,
                queue=record.queue_name,
                workers=workers,
            )
        )
    return infos
