"""A level through its :class:`~shared.inference.base.LevelInference`: the calls the pipeline,
the process pool, the CLI and the service's tasks make, each a line on the strategy
:func:`~shared.inference.table.inference_for` chooses."""

from __future__ import annotations

from collections.abc import Sequence

from shared.assembly import BundleResult, LevelSolution
from shared.bundles import Bundle
from shared.config import MatchConfig
from shared.inference.base import BundleProgress
from shared.inference.table import inference_for
from shared.level_inputs import BundleSpec, LevelInputs


def level_bundles(inputs: LevelInputs, config: MatchConfig) -> list[Bundle]:
    """Every bundle of the level, planned by its inference (``inputs.prepared`` records the
    plan: width, height, embeddings computed; the residual design's host settlement).

    Parameters
    ----------
    inputs : LevelInputs
        The level; its ``prepared`` is set here.
    config : MatchConfig
        The run's configuration.

    Returns
    -------
    list of Bundle
    """
    return inference_for(config).plan(inputs, config)


def solve_bundles(
    inputs: LevelInputs,
    config: MatchConfig,
    bundles: Sequence[BundleSpec],
    progress: BundleProgress | None = None,
) -> list[BundleResult]:
    """Solve the given bundles (:class:`Bundle` or row ranges) of a level with
    ``config.solver``.

    Parameters
    ----------
    inputs : LevelInputs
        The level, as planned by :func:`level_bundles`.
    config : MatchConfig
        The run's configuration.
    bundles : list of Bundle or tuple of int
        The bundles to solve, e.g. one task's share of the level.
    progress : callable, optional
        Called with (bundles solved, bundles given) after each bundle (a row solver: after
        each block of rows).

    Returns
    -------
    list of BundleResult
        One per bundle, in the given order.

    Raises
    ------
    ValueError
        If a row solver is given segments rather than whole rows.
    """
    return inference_for(config).solve(inputs, config, bundles, progress)


def solve_level_in_process(
    inputs: LevelInputs, config: MatchConfig, progress: BundleProgress | None = None
) -> LevelSolution:
    """The in-process ``solve_level``: every bundle of the level, one after another.

    Parameters
    ----------
    inputs : LevelInputs
        The prepared level.
    config : MatchConfig
        The run's configuration (solver, encoding, seed).
    progress : callable, optional
        Called with (bundles solved, bundles of the level) as they are solved.

    Returns
    -------
    LevelSolution
    """
    inference = inference_for(config)
    bundles = inference.plan(inputs, config)
    if progress is not None:
        progress(0, len(bundles))
    results = inference.solve(inputs, config, bundles, progress)
    return inference.assemble(inputs, results, config)
