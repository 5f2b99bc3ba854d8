"""/v1/solvers: the registry, and which queues have workers."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends

from api.deps import Services, load_solver, services
from api.schemas import SolverInfo
from shared.solvers import solver_names

router = APIRouter(prefix="/v1/solvers", tags=["solvers"])


@router.get("", response_model=list[SolverInfo])
def list_solvers(svc: Annotated[Services, Depends(services)]):
    """Every registered solver, whether it can run, and the workers consuming its queue."""
    consumers = svc.queues.consumers()
    infos = []
    for name in solver_names():
        solver, availability = load_solver(name)
        workers = None if consumers is None else sorted(consumers.get(name, []))
        infos.append(
            SolverInfo(
                name=name,
                description=solver.description if solver else "",
                available=availability.ok or bool(workers),
                available_here=availability.ok,
                reason=availability.reason,
                offline=bool(solver and solver.offline),
                uses_qpu_time=bool(solver and solver.uses_qpu_time),
                queue=name,
                workers=workers,
            )
        )
    return infos
