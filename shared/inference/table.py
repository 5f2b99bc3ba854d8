"""The one table that chooses a level's inference from the run's configuration and the solver's
facts; the only module of :mod:`shared.inference` that asks the solver registry.

=========  ==========  =================  ==============================================
inference  row solver  ``certify_tiles``  strategy
=========  ==========  =================  ==============================================
grid       yes         (any)              :class:`~.grid_views.GridViews`
                                          (``grid_inference``: dual decomposition, TRW-S)
rows       yes         (any)              :class:`~.row_chains.RowChains`
grid       no          yes                :class:`~.qubo_residual.ResidualTiles`
grid       no          no                 :class:`~.qubo_tiles.QuboTiles`
rows       no          (any)              :class:`~.qubo_rows.QuboRows`
=========  ==========  =================  ==============================================

A new inference is one module with a :class:`~.base.LevelInference` and one row of
:data:`TABLE` (and its name in ``shared.config.Inference`` when it is a new way to cut a level).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

from shared.config import Inference, MatchConfig
from shared.grid_inference import minimiser
from shared.inference.base import LevelInference
from shared.inference.grid_views import GridViews
from shared.inference.qubo_residual import ResidualTiles
from shared.inference.qubo_rows import QuboRows
from shared.inference.qubo_tiles import QuboTiles
from shared.inference.row_chains import RowChains
from shared.solvers.registry import resolve
from shared.solvers.resolved import ResolvedSolver

#: Matches any value of a key's field.
ANY = None

#: A row's key: (inference, the solver is a row solver, it certifies tiles); ANY matches all.
Key = tuple[Inference, bool, bool | None]


def _run_config(solver: ResolvedSolver) -> MatchConfig:
    if solver.config is None:  # resolved from a name only
        raise ValueError(f"{solver.spec.name} was resolved without a configuration")
    return solver.config


def _grid_views(solver: ResolvedSolver) -> LevelInference:
    config = _run_config(solver)
    return GridViews(f"grid-{config.grid_inference}", minimiser(config), solver)


def _row_chains(solver: ResolvedSolver) -> LevelInference:
    return RowChains(solver)


def _qubo(kind: type[QuboRows | QuboTiles]) -> Callable[[ResolvedSolver], LevelInference]:
    def make(solver: ResolvedSolver) -> LevelInference:
        return kind(solver)

    return make


class Row(NamedTuple):
    """One row of :data:`TABLE`: the key it matches, the strategy's class and how it is made."""

    key: Key
    strategy: type
    make: Callable[[ResolvedSolver], LevelInference]


#: The table: the first row whose key matches the run's is its level inference.
TABLE: list[Row] = [
    Row((Inference.GRID, True, ANY), GridViews, _grid_views),
    Row((Inference.ROWS, True, ANY), RowChains, _row_chains),
    Row((Inference.GRID, False, True), ResidualTiles, _qubo(ResidualTiles)),
    Row((Inference.GRID, False, False), QuboTiles, _qubo(QuboTiles)),
    Row((Inference.ROWS, False, ANY), QuboRows, _qubo(QuboRows)),
]


def _key(solver: ResolvedSolver) -> Key:
    """The run's facts the table is keyed on, from its resolved solver (``row_solver`` from its
    record: no sampler built, so no dimod import for ``exact``)."""
    return (_run_config(solver).inference, solver.spec.row_solver, solver.certifies_tiles)


def row_of(config: MatchConfig | ResolvedSolver) -> Row:
    """The row of :data:`TABLE` that ``config`` (or the run's resolved solver) matches."""
    key = _key(config if isinstance(config, ResolvedSolver) else resolve(config))
    for row in TABLE:
        if all(p is ANY or p == k for p, k in zip(row.key, key, strict=True)):
            return row
    raise LookupError(f"no level inference for {key}")  # the table covers every key


def inference_for(config: MatchConfig | ResolvedSolver) -> LevelInference:
    """The level inference of ``config`` (the sampler is built when first asked).

    Parameters
    ----------
    config : MatchConfig or ResolvedSolver
        The run's configuration, or its solver resolved with it
        (:func:`shared.solvers.registry.resolve`).

    Returns
    -------
    LevelInference
    """
    solver = config if isinstance(config, ResolvedSolver) else resolve(config)
    return row_of(solver).make(solver)


def reads_initial_labels(config: MatchConfig | ResolvedSolver) -> bool:
    """Whether a level's inference reads the coarser level's labels
    (:attr:`~.base.LevelInference.reads_initial_labels`): the pipeline builds them only then."""
    strategy: type[LevelInference] = row_of(config).strategy
    return strategy.reads_initial_labels


def settles(config: MatchConfig | ResolvedSolver) -> bool:
    """Whether a level is settled on the host first (the residual design, :mod:`shared.settle`):
    its bundles are the tiles the host leaves, estimated as such before the job runs. The
    solver's ``certifies_tiles``, which keys :class:`~.qubo_residual.ResidualTiles`' row."""
    return row_of(config).strategy is ResidualTiles
