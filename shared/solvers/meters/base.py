"""What every meter (a way D-Wave time is charged) says: the estimate of one call, of a level's
bundles as they reach the solver, and the charge read from a solve's timing. One subclass per
kind, one module each (:mod:`~shared.solvers.meters.qpu`, :mod:`~shared.solvers.meters.hybrid`);
:mod:`shared.solvers.meters` looks them up by ``SolverSpec.meter``."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from shared.solvers.qpu.embedding_cache import EmbeddingSize
    from shared.solvers.resolved import ResolvedSolver


@dataclass(frozen=True)
class LevelLoad:
    """What of a level (or of one task's batch) reaches the metered solver, as the estimates
    plan it (:mod:`shared.solvers.meters.qpu_time`)."""

    #: Bundles of the level (the batch).
    bundles: int
    #: Bundles expected to be sent (the rest the host solves).
    sent: int
    #: Binary variables of the largest bundle.
    variables: int
    #: Share of a sent bundle's variables (and qubits) left after the host's reductions.
    kept: float = 1.0
    #: Share of all the level's variables sent.
    variables_share: float = 1.0
    #: Qubits of the bundle shape's embedding when known (None: assumed from the variables).
    qubits: int | None = None
    #: Bundles one call can carry (a shape's disjoint embeddings on the QPU graph).
    together: int = 1


@dataclass(frozen=True)
class BundleCall:
    """One call as a meter estimates it."""

    solver_name: str
    #: Binary variables of the bundle's QUBO.
    num_variables: int
    #: The bundle's sampler parameters (over the schema's defaults for QPU solvers).
    params: dict[str, Any] | None = None
    #: Qubits of the bundle's embedding (default: assumed from the variables).
    num_qubits: int | None = None
    #: The actual embedding's size when known; its qubits win over ``num_qubits``.
    embedding: EmbeddingSize | None = None
    #: A live service object whose own timing data replaces the offline model (None: offline).
    solver: Any = None
    #: The solver's parameters when not given (its schema's defaults), under ``params``.
    defaults: dict[str, Any] = field(default_factory=dict)


class Meter(ABC):
    """One way a metered solver's time is estimated before and charged after a solve."""

    #: The name ``SolverSpec.meter`` gives.
    name: str
    #: Its estimates read the bundle shape's QPU embedding, so bundles are planned on the QPU
    #: graph (``--bundle-width auto`` by default) and embedding sizes are looked up.
    embeds: bool = False
    #: A level's bundles go to the solver as one task (the service bills a minimum per problem,
    #: so splitting the level would multiply the bill).
    one_task_per_level: bool = False
    #: The ``SolveResult.timing`` fields (seconds) that hold the charge, first present wins.
    charge_keys: tuple[str, ...] = ()

    @abstractmethod
    def bundle_seconds(self, call: BundleCall) -> float:
        """Estimated charge of one call (:class:`BundleCall`)."""

    @abstractmethod
    def level_seconds(
        self, solver: ResolvedSolver, params: dict[str, Any], load: LevelLoad, live: Any = None
    ) -> tuple[float, int | None]:
        """Estimated charge of what ``load`` sends to ``solver`` (the job's, resolved), and the
        qubits a bundle is assumed to use (None when the meter has no qubits); ``live``: as
        :meth:`timing_source` gives it."""

    def charged_seconds(self, timing: dict[str, float]) -> float:
        """What one solve costs its owner: the first of :attr:`charge_keys` reported (seconds,
        never negative); 0 when none is."""
        for key in self.charge_keys:
            value = timing.get(key)
            if value is not None:
                return max(0.0, float(value))
        return 0.0

    def timing_source(self, solver: ResolvedSolver) -> Any:
        """The live service object whose timing data the estimates of ``solver`` use, or None
        (the offline model)."""
        return None
