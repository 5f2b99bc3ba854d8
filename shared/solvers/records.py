"""What is declared about a solver (:class:`SolverSpec`) and the names the registry reserves: a
leaf module, so that the registry, the plugin loader and the sampler base class can all read a
record without importing one another."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from shared.solvers import params as schemas

#: Entry-point group through which packages register named solvers.
ENTRY_POINT_GROUP = "qhsm.solvers"
#: Prefix of solver names that name an installed dimod sampler class.
DIMOD_PREFIX = "dimod:"
#: The Celery queue of every ``dimod:`` solver.
DIMOD_QUEUE = "dimod"
#: The group of workers that runs what needs nothing but CPUs (and the ``dimod`` queue).
CPU_WORKERS = "cpu"


@dataclass(frozen=True)
class SolverSpec:
    """Everything declared about one solver, once.

    ``factory`` is ``"module:attribute"`` of a zero-argument callable (or the callable itself)
    returning the sampler. ``meter`` names the meter a job on it is charged to its owner's
    budget with (:mod:`shared.solvers.meters`: ``"qpu"``, the QPU timing model, ``"hybrid"``,
    Leap's hybrid charge, or one a plugin registered; None: not metered);
    ``offline`` marks a stand-in for a cloud service (charged what the real one would take).
    """

    name: str
    factory: str | Callable[[], Any]
    description: str = ""
    params: type[schemas.SolverParams] = schemas.NoParams
    meter: str | None = None
    offline: bool = False
    #: The Celery queue its bundles go to (None: the solver's name).
    queue: str | None = None
    #: The group of workers that consumes its queue, where what it needs is (a licence, the
    #: D-Wave token): docker-compose.yml's ``worker-<group>`` service, ``python -m
    #: workers.queues <group>``.
    workers: str = CPU_WORKERS
    #: Works on the MRF costs of whole rows instead of a QUBO (shared.inference.row_chains
    #: hands it rows).
    row_solver: bool = False
    #: Whether bundles start from the best guess at hand unless the config says otherwise:
    #: local searches refine one far more cheaply than they find a minimum from scratch.
    warm_start_default: bool = False
    #: Label encoding to use when none is asked for (None: no preference, the preset decides).
    encoding: str | None = None

    @property
    def metered(self) -> bool:
        """Jobs on it spend (real or simulated) D-Wave time from a budget."""
        return self.meter is not None

    @property
    def uses_qpu_time(self) -> bool:
        """It spends real D-Wave time (needs the token; the stand-ins do not)."""
        return self.metered and not self.offline

    @property
    def queue_name(self) -> str:
        return self.queue or self.name
