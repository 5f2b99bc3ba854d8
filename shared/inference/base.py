"""What every level inference is: a :class:`LevelInference` cuts a level's MRF into bundles,
solves them and puts the level back together (its labels, energy, bound and why it stopped).

Each strategy is one module of :mod:`shared.inference`, chosen by the one table of
:mod:`shared.inference.table` from the run's configuration and the solver's facts. The
in-process loop (:mod:`shared.inference.level`), the process pool and the service's tasks (plan
on the control or the solver's queue, bundles as Celery jobs, the fan-in) all go through it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import replace

from shared.assembly import BundleResult, LevelSolution, assemble
from shared.bundles import Bundle
from shared.config import MatchConfig
from shared.level_inputs import BundleSpec, LevelInputs
from shared.solvers.resolved import ResolvedSolver

BundleProgress = Callable[[int, int], None]
"""``(units done, units total)`` within a level: bundles (rows for a row solver)."""


class LevelInference:
    """How one level's MRF is cut into bundles and minimised: the interface and its defaults in
    one class. A strategy subclasses it and writes :meth:`width_setting`, :meth:`plan` and
    :meth:`_solve`; the other methods are defaults it may override.

    ``plan`` runs once per level where the level is planned (in process, the service's control
    worker, or the solver's queue when ``plans_with_solver``), ``solve`` wherever bundles are
    solved (any process, any share of them), ``assemble`` once per level on all the results.
    """

    #: The strategy's name (logs, tests).
    name = ""
    #: Planning asks the sampler (its QPU graph: the widest segment that embeds, each shape's
    #: embedding): a service plans the level on the solver's queue, where its credentials are.
    plans_with_solver = False
    #: The level's bundles may be spread over worker processes (False: the strategy is
    #: vectorised over the level already, or sends the level as one problem).
    splits = False
    #: Its bundles are whole rows (a row solver's chains or grids): a row segment is refused.
    whole_rows = False
    #: It reads the coarser level's labels (``LevelInputs.initial_labels``: warm starts, a
    #: tile's fixed neighbours); the pipeline builds them only for a strategy that does.
    reads_initial_labels = True
    #: ``LevelSolution.termination`` of the level (:class:`Termination`).
    termination: str | None = None

    def width_setting(self, config: MatchConfig) -> int | str | None:
        """The run's ``bundle_width`` with the default filled in (None: whole rows), or a
        ``ValueError`` saying what to change."""
        raise NotImplementedError

    def prepare(self, inputs: LevelInputs, config: MatchConfig) -> str | None:
        """The host's work on the level before it is planned and its inputs are kept (the
        service's control worker): what it did, for the log, or None when there is none."""
        return None

    def plan(self, inputs: LevelInputs, config: MatchConfig) -> list[Bundle]:
        """Every bundle of the level; records the plan in ``inputs.prepared``."""
        raise NotImplementedError

    def planned(self, inputs: LevelInputs, config: MatchConfig) -> list[Bundle]:
        """The bundles :meth:`plan` chose, read back from ``inputs.prepared``."""
        return inputs.planned_bundles(config)

    def bundle_config(self, inputs: LevelInputs, config: MatchConfig) -> MatchConfig:
        """The configuration a bundle is solved and estimated with."""
        return config

    def solve(
        self,
        inputs: LevelInputs,
        config: MatchConfig,
        bundles: Sequence[BundleSpec],
        progress: BundleProgress | None = None,
    ) -> list[BundleResult]:
        """The given bundles (any share of the level), one result each in the given order: the
        strategy's :meth:`_solve` of them as :class:`Bundle` (none given: nothing to do),
        progress reported as it goes; a ``ValueError`` when a strategy of :attr:`whole_rows`
        is given a segment."""
        if not bundles:
            return []
        items = [inputs.as_bundle(spec) for spec in bundles]
        width = inputs.shape[1]
        if self.whole_rows and any(b.col_start != 0 or b.col_stop != width for b in items):
            raise ValueError(f"{config.solver} solves whole rows only, not row segments")
        results: list[BundleResult] = []
        for done in self._solve(inputs, config, items):
            results.extend(done)
            if progress is not None:
                progress(len(results), len(items))
        return results

    def _solve(
        self, inputs: LevelInputs, config: MatchConfig, items: list[Bundle]
    ) -> Iterator[list[BundleResult]]:
        """:meth:`solve`'s work on at least one bundle: their results in the given order, a
        list at a time as they are done (progress is reported after each)."""
        raise NotImplementedError

    def assemble(
        self, inputs: LevelInputs, results: list[BundleResult], config: MatchConfig
    ) -> LevelSolution:
        """The level from every bundle's result: labels, energy, bound and termination."""
        solution = assemble(inputs, results, config)
        solution.termination = self.termination
        return solution


class Termination:
    """Why a level's minimisation stopped (``LevelSolution.termination``)."""

    #: Every bundle's labels are proven optimal (a row's chain by dynamic programming, a view's
    #: grid whose row and column chains agree).
    OPTIMAL = "optimal"
    #: A grid stopped once its relative gap to the bound reached ``dual_gap``.
    GAP = "gap"
    #: A grid stopped at ``dual_iterations`` with its chains still disagreeing.
    ITERATIONS = "iterations"
    #: The QUBO solver's answers (its reads), decoded and repaired.
    SAMPLED = "sampled"
    #: The host settled every pixel of the level: nothing was sent.
    SETTLED = "settled"


def width_setting(solver: ResolvedSolver, config: MatchConfig) -> int | str | None:
    """``solver``'s :meth:`~shared.solvers.resolved.ResolvedSolver.bundle_width_setting` for
    ``config`` (the run's, or a bundle's): the ``bundle_width`` with the solver's default filled
    in, or a ``ValueError`` saying what to change."""
    if config is not solver.config:
        solver = replace(solver, config=config)
    return solver.bundle_width_setting()
