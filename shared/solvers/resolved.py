"""A solver resolved once for a run: :class:`ResolvedSolver`, everything the pipeline, the API
and the workers ask about the run's solver, answered from its record, its sampler's Protocols
and the run's configuration. :func:`shared.solvers.registry.resolve` builds it, once per job (or
level); the code downstream takes it as an argument instead of looking a name up again.

A leaf beside the registry: it imports neither the registry nor a sampler (the sampler is built
on first use, by the factory the registry hands over), so resolving ``exact`` for its grid
inference imports no dimod.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Literal

from shared.config import AUTO, Inference, MatchConfig
from shared.solvers import params as schemas
from shared.solvers.base import BatchSolver, RowSolver, ShapePlanner
from shared.solvers.records import SolverSpec

#: How a solver's bundles are solved: ``rows``, on the MRF costs of whole rows (a
#: :class:`~shared.solvers.base.RowSolver`); ``batch``, a task's QUBOs at once (a
#: :class:`~shared.solvers.base.BatchSolver`); ``qubo``, one QUBO per call.
Kind = Literal["rows", "batch", "qubo"]


@dataclass(frozen=True, eq=False)
class ResolvedSolver:
    """The run's solver, resolved once: its record, its sampler (built on first use), its kind
    and what the run's configuration makes of it (warm start, certified tiles, bundle width).

    The record's own facts (name, queue, meter, whether it is a row solver: declared there, so
    read without building the sampler) are read from ``spec``; this class adds what is derived.
    ``config`` is None when only a name was resolved (then the run-dependent answers are not
    asked). Pickles without its sampler (a child process builds its own on first use).
    """

    spec: SolverSpec
    config: MatchConfig | None = None
    #: Returns the sampler (the registry's one per process); not pickled with a built sampler.
    factory: Callable[[], Any] | None = field(default=None, repr=False)

    def __getstate__(self) -> dict[str, Any]:
        return {key: value for key, value in self.__dict__.items() if key != "sampler"}

    @cached_property
    def sampler(self) -> Any:
        """The sampler (built on first use; a row solver's is its :class:`RowSolver`)."""
        if self.factory is None:
            raise ValueError(f"{self.spec.name} was resolved without its sampler's factory")
        return self.factory()

    @cached_property
    def kind(self) -> Kind:
        """``rows``, ``batch`` or ``qubo``: from the sampler's Protocols (a row solver's
        without building it)."""
        if self.spec.row_solver:
            return "rows"
        return "batch" if isinstance(self.sampler, BatchSolver) else "qubo"

    @cached_property
    def plans_with_solver(self) -> bool:
        """Whether a level's bundles are planned on the solver itself (a
        :class:`ShapePlanner`: the widest segment that embeds, each shape's embedding), so
        where its credentials are."""
        return not self.spec.row_solver and isinstance(self.sampler, ShapePlanner)

    def _config(self) -> MatchConfig:
        if self.config is None:
            raise ValueError(f"{self.spec.name} was resolved without a configuration")
        return self.config

    @property
    def warm_start(self) -> bool:
        """Whether bundles are warm-started: ``solver_params["warm_start"]`` (kept for old
        clients) or ``MatchConfig.warm_start`` when given, else the solver's default."""
        config = self._config()
        if "warm_start" in config.solver_params:
            return bool(config.solver_params["warm_start"])
        if config.warm_start is not None:
            return config.warm_start
        return self.spec.warm_start_default

    @property
    def solves_grids(self) -> bool:
        """Whether a bundle is a whole view's grid, minimised by dual decomposition: ``grid``
        inference with a row solver (``exact``)."""
        return self._config().inference is Inference.GRID and self.spec.row_solver

    @property
    def certifies_tiles(self) -> bool:
        """Whether a QUBO solver's grid tiles are first settled on the host by dual
        decomposition (``certify_tiles``, ``grid`` inference, not a row solver): the residual
        design (:mod:`shared.settle`)."""
        config = self._config()
        grid = config.inference is Inference.GRID
        return config.certify_tiles and grid and not self.spec.row_solver

    def bundle_width_setting(self) -> int | str | None:
        """The run's ``bundle_width`` with the solver's default filled in: unset is ``auto``
        for a :class:`ShapePlanner` and whole rows (None) otherwise; the row DP always
        solves whole rows. A ``ValueError`` says what to change (also for a bundle height a row
        solver cannot use)."""
        config = self._config()
        width = config.bundle_width
        if self.spec.row_solver:
            if width is not None:
                raise ValueError(
                    f"{self.spec.name} solves whole rows exactly; leave bundle_width unset "
                    "(or pick a QUBO solver such as sa to solve row segments)"
                )
            if config.inference is Inference.ROWS and config.bundle_height != 1:
                raise ValueError(
                    f"{self.spec.name} solves single-row bundles (rows inference) or each view's "
                    f"whole grid (grid inference); bundle_height {config.bundle_height} sets "
                    "the tiles of QUBO solvers: leave it at 1, or pick a QUBO solver such as sa"
                )
            return None
        planner = isinstance(self.sampler, ShapePlanner)
        if width is None:
            return AUTO if planner else None
        if width == AUTO and not planner:
            raise ValueError(
                f"bundle_width auto finds the widest segment that embeds on a QPU graph; "
                f"{self.spec.name} has none: give a width in pixels or leave it unset"
            )
        return width

    def checked_params(self) -> dict[str, Any]:
        """The run's ``solver_params`` checked against the solver's schema
        (``InvalidSolverParamsError`` says why not), as :func:`shared.solvers.params.check`
        returns them."""
        return schemas.check(self.spec.params, self.spec.name, self._config().solver_params)

    def rows(self) -> RowSolver:
        """The sampler as the :class:`RowSolver` it is (``TypeError`` for a QUBO solver)."""
        sampler = self.sampler
        if not isinstance(sampler, RowSolver):
            raise TypeError(f"{self.spec.name} is not a row solver")
        return sampler
