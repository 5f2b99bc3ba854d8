"""What the QUBO strategies share: a bundle's costs encoded with the run's codec into a QUBO
(:class:`TileProblem`), sent to the solver (one call a bundle, or the whole share as one problem
for a :class:`~shared.solvers.base.BatchSolver`), decoded and repaired; the bundles' width
(whole rows, or segments: ``auto`` is the widest that embeds) and, for solvers that embed on a QPU
graph, each bundle shape's embedding, planned once per level (:meth:`QuboStrategy.plan`)."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from shared.assembly import BundleResult
from shared.bundles import Bundle, bundle_seed
from shared.config import AUTO, MatchConfig
from shared.encodings import get_codec
from shared.energy import Costs, mrf_energy
from shared.grid import DualResult
from shared.inference.base import BundleProgress, Strategy, Termination
from shared.level_inputs import BundleSpec, LevelInputs
from shared.solvers.base import BatchSolver, ShapePlanner, SolveResult

if TYPE_CHECKING:
    import dimod

#: Parameters in ``MatchConfig.solver_params`` that steer the pipeline, not the solver.
PIPELINE_PARAMS = {"warm_start"}


@dataclass
class TileProblem:
    """One QUBO bundle as the solver gets it: its costs (with a grid tile's boundary unaries),
    QUBO, seed and warm start; with ``certify_tiles`` on a tile the host's dual decomposition of
    it too, and then ``bqm`` is None when that certified the optimum (nothing to send)."""

    bundle: Bundle
    costs: Costs
    bqm: dimod.BinaryQuadraticModel | None
    seed: int
    initial: np.ndarray | None
    dual: DualResult | None = None
    #: Host seconds the dual decomposition took.
    dual_seconds: float = 0.0


class QuboStrategy(Strategy):
    """A QUBO solver's level: :meth:`problems` (the strategy's own) sent to ``sampler()``.

    Parameters
    ----------
    sampler : callable
        The run's sampler, built on first use (planning a level asks it only for solvers that
        embed on a QPU graph).
    warm : bool
        Whether bundles are warm-started (``uses_warm_start``).
    """

    termination = Termination.SAMPLED

    def __init__(self, sampler: Callable[[], Any], warm: bool) -> None:
        self._sampler = sampler
        self.warm = warm

    @property
    def sampler(self) -> Any:
        return self._sampler()

    @property
    def plans_with_solver(self) -> bool:  # type: ignore[override]
        return isinstance(self.sampler, ShapePlanner)

    @property
    def splits(self) -> bool:  # type: ignore[override]
        # a batch solver sends the level as one problem (split, it would be billed per part)
        return not isinstance(self.sampler, BatchSolver)

    def problems(
        self, inputs: LevelInputs, config: MatchConfig, items: Sequence[Bundle]
    ) -> Iterator[TileProblem]:
        """Each bundle as the solver gets it, one at a time."""
        raise NotImplementedError

    def width_setting(self, config: MatchConfig) -> int | str | None:
        """Unset is ``auto`` for solvers that embed on a QPU graph (they offer
        ``widest_bundle``) and whole rows (None) otherwise."""
        width = config.bundle_width
        planner = isinstance(self.sampler, ShapePlanner)
        if width is None:
            return AUTO if planner else None
        if width == AUTO and not planner:
            raise ValueError(
                f"bundle_width auto finds the widest segment that embeds on a QPU graph; "
                f"{config.solver} has none: give a width in pixels or leave it unset"
            )
        return width

    def level_width(self, inputs: LevelInputs, config: MatchConfig) -> int | None:
        """The segment width of this level's bundles (None: whole rows); ``auto`` asks the
        solver for the widest segment that embeds (searched once per shape and target, then
        cached)."""
        width = self.width_setting(config)
        if width == AUTO:
            return self.sampler.widest_bundle(
                encoding=config.encoding,
                candidates=inputs.candidates.shape[2],
                height=config.bundle_height,
                row_width=inputs.shape[1],
                margin=config.bundle_margin,
            )
        if width is None:
            return None
        pixels = int(width)
        return None if pixels >= inputs.shape[1] else pixels

    def plan(self, inputs: LevelInputs, config: MatchConfig) -> list[Bundle]:
        """Bundles of ``bundle_height`` rows and :meth:`level_width`; a solver that embeds on a
        QPU graph embeds each bundle shape here, once, before the bundles fan out."""
        solver = self.sampler
        started = time.perf_counter()
        before = solver.cache.computed if isinstance(solver, ShapePlanner) else 0
        width = self.level_width(inputs, config)
        height = config.bundle_height
        bundles = inputs.bundles(height, width, config.bundle_margin)
        inputs.prepared = {"bundle_width": width, "bundle_height": height}
        if isinstance(solver, ShapePlanner):
            shapes = sorted({bundle.shape for bundle in bundles})
            labels = inputs.candidates.shape[2]
            solver.embed_shapes(encoding=config.encoding, candidates=labels, shapes=shapes)
            inputs.prepared = {
                "bundle_width": bundles[0].shape[1],
                "bundle_height": height,
                "embeddings_computed": solver.cache.computed - before,
                "preparation_seconds": time.perf_counter() - started,
            }
        return bundles

    def solve(
        self,
        inputs: LevelInputs,
        config: MatchConfig,
        bundles: Sequence[BundleSpec],
        progress: BundleProgress | None = None,
    ) -> list[BundleResult]:
        """The bundles' :meth:`problems` sent to the solver, in order."""
        if not bundles:
            return []
        items = [inputs.as_bundle(spec) for spec in bundles]
        problems = self.problems(inputs, config, items)
        return sample(self.sampler, problems, config, len(items), progress)

    def warm_start(
        self, inputs: LevelInputs, row_costs: Costs, bundle: Bundle, dual: DualResult | None
    ) -> np.ndarray | None:
        """A bundle's starting labels when the run warm-starts: the host's dual decomposition's
        labels, else the coarser estimate (:meth:`LevelInputs.starting_labels`)."""
        if not self.warm:
            return None
        if dual is not None:
            return dual.labels
        start, stop, first, last = bundle.as_list()
        return inputs.starting_labels(row_costs, start, stop)[:, first:last]


def encoded(
    inputs: LevelInputs,
    config: MatchConfig,
    bundle: Bundle,
    costs: Costs,
    start: np.ndarray | None,
    dual: DualResult | None = None,
    dual_seconds: float = 0.0,
) -> TileProblem:
    """A bundle's :class:`TileProblem` from its costs and starting labels (None: no warm start):
    no QUBO when the host's ``dual`` certified its optimum."""
    seed = bundle_seed(config.seed, inputs.index, bundle.row_start, bundle.col_start)
    if dual is not None and dual.disagreeing == 0:
        return TileProblem(bundle, costs, None, seed, None, dual, dual_seconds)
    codec = get_codec(config.encoding)
    initial = None if start is None else codec.encode_labels(start, costs.num_labels)
    bqm = codec.encode(costs, config.rectifier)
    return TileProblem(bundle, costs, bqm, seed, initial, dual, dual_seconds)


def sample(
    solver: Any,
    problems: Iterable[TileProblem],
    config: MatchConfig,
    total: int,
    progress: BundleProgress | None = None,
) -> list[BundleResult]:
    """Each of the ``total`` problems' result, decoded (:func:`bundle_result`) as the solver
    answers (:func:`answers`)."""
    codec = get_codec(config.encoding)
    params = {k: v for k, v in config.solver_params.items() if k not in PIPELINE_PARAMS}
    results = []
    for problem, outcome in answers(solver, problems, params):
        results.append(bundle_result(problem, outcome, codec))
        if progress is not None:
            progress(len(results), total)
    return results


def answers(
    solver: Any, problems: Iterable[TileProblem], params: dict[str, Any]
) -> Iterator[tuple[TileProblem, SolveResult | None]]:
    """Each problem with the solver's answer (None: the host certified it, nothing sent): sent
    one at a time as they are built, or all in one call to a batch solver (one problem for many
    bundles: hybrid's level)."""
    if isinstance(solver, BatchSolver):
        given = list(problems)
        sent = [(p.bqm, p.seed, p.initial) for p in given if p.bqm is not None]
        outcomes = iter(solver.solve_batch(sent, **params) if sent else [])
        for problem in given:
            yield problem, None if problem.bqm is None else next(outcomes)
        return
    for problem in problems:
        if problem.bqm is None:
            yield problem, None
        else:
            yield (
                problem,
                solver.solve(
                    problem.bqm, seed=problem.seed, initial_state=problem.initial, **params
                ),
            )


def bundle_result(problem: TileProblem, outcome: SolveResult | None, codec: Any) -> BundleResult:
    """A bundle's result from the solver's ``outcome`` (None: certified on the host). With a
    host labelling the better of the two by MRF energy is kept, and ``info`` counts the bundle
    as roof duality's reports do (``variables``, ``residual_variables``: what reached the
    solver) plus ``certified``."""
    start, stop, first, last = problem.bundle.as_list()
    dual, costs = problem.dual, problem.costs
    if outcome is None:
        assert dual is not None
        labels, repaired, wall, timing, info = dual.labels, 0, 0.0, {}, {}
    else:
        decoded = codec.decode(costs, outcome.sample)
        labels, repaired, wall = decoded.labels, decoded.repaired, outcome.wall_time
        timing, info = outcome.timing, outcome.info
    energy = mrf_energy(costs, labels)
    if dual is not None:
        variables = costs.shape[0] * costs.shape[1] * codec.variables_per_pixel(costs.num_labels)
        info = {"variables": variables, "residual_variables": variables, **info}
        info["certified"] = outcome is None
        if outcome is None:
            info.update(fixed_fraction=1.0, residual_variables=0)
        else:
            host = mrf_energy(costs, dual.labels)
            info["kept"] = "host" if host < energy else "solver"
            if host < energy:
                labels, energy, repaired = dual.labels, host, 0
    return BundleResult(
        row_start=start,
        row_stop=stop,
        labels=labels,
        energy=energy,
        repaired=repaired,
        wall_time=wall + problem.dual_seconds,
        timing=timing,
        info=info,
        col_start=first,
        col_stop=last,
    )
