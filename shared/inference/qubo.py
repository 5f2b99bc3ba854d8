"""What the QUBO strategies share: a bundle's costs encoded with the run's codec into a QUBO
(:class:`TileProblem`), sent to the solver (one call a bundle, or the whole share as one problem
for a :class:`~shared.solvers.base.BatchSolver`), decoded and repaired; the bundles' width
(whole rows, or segments: ``auto`` is the widest that embeds) and, for solvers that embed on a QPU
graph, each bundle shape's embedding, planned once per level (:meth:`QuboStrategy.plan`)."""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from shared.assembly import BundleResult
from shared.bundles import Bundle, bundle_seed
from shared.config import AUTO, MatchConfig
from shared.encodings import get_codec
from shared.energy import Costs, mrf_energy
from shared.inference.base import LevelInference, Termination, width_setting
from shared.level_inputs import LevelInputs
from shared.provenance_map import Stage, filled
from shared.solvers.base import BatchSolver, ShapePlanner, SolveResult
from shared.solvers.resolved import ResolvedSolver

if TYPE_CHECKING:
    import dimod

#: Parameters in ``MatchConfig.solver_params`` that steer the pipeline, not the solver.
PIPELINE_PARAMS = {"warm_start"}


@dataclass
class TileProblem:
    """One QUBO bundle as the solver gets it: its costs (with a grid tile's boundary unaries),
    QUBO, seed and warm start."""

    bundle: Bundle
    costs: Costs
    bqm: dimod.BinaryQuadraticModel
    seed: int
    initial: np.ndarray | None


class QuboStrategy(LevelInference):
    """A QUBO solver's level: :meth:`problems` (the strategy's own) sent to ``sampler()``.

    Parameters
    ----------
    solver : ResolvedSolver
        The run's solver, resolved with its configuration: its sampler is built on first use
        (planning a level asks it only for solvers that embed on a QPU graph); whether bundles
        are warm-started and the bundles' width are its answers.
    """

    termination = Termination.SAMPLED

    def __init__(self, solver: ResolvedSolver) -> None:
        self.solver = solver
        self.warm = solver.warm_start

    @property
    def sampler(self) -> Any:
        return self.solver.sampler

    @property
    def plans_with_solver(self) -> bool:  # type: ignore[override]
        return self.solver.plans_with_solver

    @property
    def splits(self) -> bool:  # type: ignore[override]
        # a batch solver sends the level as one problem (split, it would be billed per part)
        return self.solver.kind == "qubo"

    def problems(
        self, inputs: LevelInputs, config: MatchConfig, items: Sequence[Bundle]
    ) -> Iterator[TileProblem]:
        """Each bundle as the solver gets it, one at a time."""
        raise NotImplementedError

    def width_setting(self, config: MatchConfig) -> int | str | None:
        """The solver's :meth:`~shared.solvers.resolved.ResolvedSolver.bundle_width_setting`
        for ``config``: unset is ``auto`` for solvers that embed on a QPU graph (they offer
        ``widest_bundle``) and whole rows (None) otherwise."""
        return width_setting(self.solver, config)

    def level_width(self, inputs: LevelInputs, config: MatchConfig) -> int | None:
        """The segment width of this level's bundles (None: whole rows); ``auto`` asks the
        solver for the widest segment that embeds (searched once per shape and target, then
        cached)."""
        width = self.width_setting(config)
        if width == AUTO:
            return self.sampler.widest_bundle(
                encoding=config.encoding,
                candidates=inputs.count,
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
            labels = inputs.count
            solver.embed_shapes(encoding=config.encoding, candidates=labels, shapes=shapes)
            inputs.prepared = {
                "bundle_width": bundles[0].shape[1],
                "bundle_height": height,
                "embeddings_computed": solver.cache.computed - before,
                "preparation_seconds": time.perf_counter() - started,
            }
        return bundles

    def _solve(
        self, inputs: LevelInputs, config: MatchConfig, items: list[Bundle]
    ) -> Iterator[list[BundleResult]]:
        """The bundles' :meth:`problems` sent to the solver, in order."""
        codec = get_codec(config.encoding)
        params = {k: v for k, v in config.solver_params.items() if k not in PIPELINE_PARAMS}
        for problem, outcome in answers(self.sampler, self.problems(inputs, config, items), params):
            yield [bundle_result(problem, outcome, codec)]

    def warm_start(
        self, inputs: LevelInputs, row_costs: Costs, bundle: Bundle
    ) -> np.ndarray | None:
        """A bundle's starting labels when the run warm-starts: the coarser estimate
        (:meth:`LevelInputs.starting_labels`)."""
        if not self.warm:
            return None
        start, stop, first, last = bundle.as_list()
        return inputs.starting_labels(row_costs, start, stop)[:, first:last]


def encoded(
    inputs: LevelInputs,
    config: MatchConfig,
    bundle: Bundle,
    costs: Costs,
    start: np.ndarray | None,
) -> TileProblem:
    """A bundle's :class:`TileProblem` from its costs and starting labels (None: no warm start)."""
    seed = bundle_seed(config.seed, inputs.plan.index, bundle.row_start, bundle.col_start)
    codec = get_codec(config.encoding)
    initial = None if start is None else codec.encode_labels(start, costs.num_labels)
    bqm = codec.encode(costs, config.rectifier)
    return TileProblem(bundle, costs, bqm, seed, initial)


def answers(
    solver: Any, problems: Iterable[TileProblem], params: dict[str, Any]
) -> Iterator[tuple[TileProblem, SolveResult]]:
    """Each problem with the solver's answer: sent one at a time as they are built, or all in
    one call to a batch solver (one problem for many bundles: hybrid's level)."""
    if isinstance(solver, BatchSolver):
        given = list(problems)
        outcomes = solver.solve_batch([(p.bqm, p.seed, p.initial) for p in given], **params)
        yield from zip(given, outcomes, strict=True)
        return
    for problem in problems:
        outcome = solver.solve(
            problem.bqm, seed=problem.seed, initial_state=problem.initial, **params
        )
        yield problem, outcome


def bundle_result(problem: TileProblem, outcome: SolveResult, codec: Any) -> BundleResult:
    """A bundle's result from the solver's ``outcome``: its decoded labels, their energy and
    their provenance codes (:func:`sampler_stages`)."""
    start, stop, first, last = problem.bundle.as_list()
    decoded = codec.decode(problem.costs, outcome.sample)
    per_pixel = codec.variables_per_pixel(problem.costs.num_labels)
    stages = sampler_stages(
        decoded.invalid, outcome.info.get("fixed_variables"), per_pixel, decoded.labels
    )
    info = {k: v for k, v in outcome.info.items() if k != "fixed_variables"}
    return BundleResult(
        row_start=start,
        row_stop=stop,
        labels=decoded.labels,
        energy=mrf_energy(problem.costs, decoded.labels),
        repaired=decoded.repaired,
        wall_time=outcome.wall_time,
        timing=outcome.timing,
        info=info,
        col_start=first,
        col_stop=last,
        stages=stages,
    )


def sampler_stages(
    invalid: np.ndarray | None, fixed: list[int] | None, per_pixel: int, labels: np.ndarray
) -> np.ndarray:
    """A sampled bundle's provenance codes: :attr:`Stage.SOLVER`, :attr:`Stage.ROOF_DUALITY`
    where roof duality fixed every variable of the pixel (``fixed``: the bundle's variables it
    fixed, pixel-major as the codecs number them, ``per_pixel`` a pixel), and
    :attr:`Stage.REPAIRED` where the bits were no valid code (``invalid``)."""
    stages = filled(labels.shape, Stage.SOLVER)
    if fixed:
        mask = np.zeros(labels.size * per_pixel, dtype=bool)
        mask[np.asarray(fixed, dtype=np.int64)] = True
        whole = mask.reshape(labels.size, per_pixel).all(axis=1).reshape(labels.shape)
        stages[whole] = Stage.ROOF_DUALITY
    if invalid is not None:
        stages[invalid] = Stage.REPAIRED
    return stages
