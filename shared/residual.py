"""What the exact classical steps leave of a job's bundles, measured before the job runs, so that
its estimate is what the metered solvers will charge.

A metered solver's level is settled on the host first (``certify_tiles``, :mod:`shared.settle`:
only 4x4 tiles around the pixels its dual decomposition leaves unsettled are sent) and roof
duality fixes what it proves of those tiles (:func:`shared.solvers.composites.reduce`), sending
only the rest; how much is left depends on the bundles' costs, so no formula in the image size
gives it. :func:`survey` runs the pyramid with the ``exact`` solver (a stand-in for the coarser
levels' maps, which decide a level's candidates and the tiles' boundaries; milliseconds per level)
and applies both steps to an evenly spread sample of each level's bundles, cut as the metered
solver will cut them. Classical work only: nothing is sent anywhere.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from shared.config import MatchConfig

#: Bundles per level the survey reduces at most (evenly spread): a few seconds on Tsukuba.
SURVEY_BUNDLES = 160

#: Told ``(levels surveyed, levels)`` after each level (a pricing job's progress).
LevelProgress = Callable[[int, int], object]


def _no_progress(done: int, total: int) -> None:
    return None


@dataclass(frozen=True)
class LevelResidual:
    """One level's bundles after roof duality, as measured on a sample of them.

    ``sent_share``: share of bundles with anything left (the others are solved on the host
    and charged nothing); ``variables_share``: share of all the level's variables left;
    ``sent_variables_share``: share of a sent bundle's variables left (what its embedding
    keeps).
    """

    sampled: int
    sent_share: float
    variables_share: float
    sent_variables_share: float
    #: With the residual design (:mod:`shared.settle`): the 4x4 tiles the host leaves to send
    #: (the shares are then of all the level's tiles); None: the level's own bundles.
    tiles: int | None = None
    #: With the residual design: the level's pixels the host certified (rows and columns agree).
    certified: int | None = None

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def _probe(inputs, config: MatchConfig, width: int | None, limit: int) -> LevelResidual:
    """The exact classical steps on an evenly spread sample of at most ``limit`` of the level's
    bundles: with ``certify_tiles`` only the tiles the host leaves unsettled (:mod:`shared.settle`),
    roof duality fixing what it proves of them."""
    from shared import settle
    from shared.inference import inference_for, settles
    from shared.inference.qubo import QuboStrategy

    inference = inference_for(config)
    assert isinstance(inference, QuboStrategy)  # a metered solver's
    share = 1.0  # of the level's bundles the sampled ones stand for
    if settles(config):  # the host settles the level; only tiles around the rest go
        saved = inputs.initial_labels, inputs.prepared
        inputs.prepared = {}
        certified = settle.prepare(inputs, config).certified
        bundles = settle.tiles(inputs)
        share = len(bundles) / settle.tiles_of(inputs.view_height, inputs.shape[1], inputs.views)
        try:
            found = _reduced(inputs, inference, config, bundles, limit) if bundles else None
        finally:
            inputs.initial_labels, inputs.prepared = saved
        if found is None:
            return LevelResidual(0, 0.0, 0.0, 1.0, tiles=0, certified=certified)
        return LevelResidual(
            sampled=found.sampled,
            sent_share=found.sent_share * share,
            variables_share=found.variables_share * share,
            sent_variables_share=found.sent_variables_share,
            tiles=len(bundles),
            certified=certified,
        )
    bundles = inputs.bundles(config.bundle_height, width, config.bundle_margin)
    return _reduced(inputs, inference, config, bundles, limit)


def _reduced(inputs, inference, config: MatchConfig, bundles: list, limit: int) -> LevelResidual:
    """Roof duality on an evenly spread sample of at most ``limit`` of ``bundles``, encoded as
    ``inference`` (a ``QuboStrategy``) sends them."""
    from shared.encodings import get_codec
    from shared.solvers.composites import reduce

    picked = np.unique(np.linspace(0, len(bundles) - 1, min(limit, len(bundles))).astype(int))
    preprocess = config.solver_params.get("preprocess", "roof-duality")
    codec = get_codec(config.encoding)
    variables, left, sent, sent_variables, sent_left = 0, 0, 0, 0, 0
    for problem in inference.problems(inputs, config, [bundles[i] for i in picked]):
        height, columns, labels = problem.costs.unary.shape
        n = height * columns * codec.variables_per_pixel(labels)
        m = int(reduce(problem.bqm, preprocess).free.size)
        variables, left = variables + n, left + m
        if m:
            sent, sent_variables, sent_left = sent + 1, sent_variables + n, sent_left + m
    return LevelResidual(
        sampled=len(picked),
        sent_share=sent / max(len(picked), 1),
        variables_share=left / max(variables, 1),
        sent_variables_share=sent_left / max(sent_variables, 1),
    )


def survey(
    left: np.ndarray,
    right: np.ndarray,
    config: MatchConfig,
    max_disparity: int,
    widths: list[int | None],
    limit: int = SURVEY_BUNDLES,
    progress: LevelProgress = _no_progress,
) -> list[LevelResidual]:
    """Per level, what roof duality leaves of the bundles ``config``'s metered solver will send.

    Parameters
    ----------
    left, right : numpy.ndarray
        The pair, float32 in [0, 1], as ``run_pipeline`` takes it.
    config : MatchConfig
        The job's configuration (its solver is the metered one).
    max_disparity : int
        The job's resolved maximum disparity.
    widths : list of int or None
        Each level's segment width (None: whole rows), as the estimate assumes it.
    limit : int
        Bundles reduced per level at most.
    progress : callable, optional
        Told ``(levels surveyed, len(widths))`` after each level is surveyed and solved.

    Returns
    -------
    list of LevelResidual
        One per level, coarsest first.
    """
    from shared.inference import solve_level_in_process
    from shared.pipeline import run_pipeline

    exact = config.model_copy(
        update={
            "solver": "exact",
            "bundle_width": None,
            "solver_params": {},
            "max_disparity": max_disparity,
        }
    )
    found: list[LevelResidual] = []

    def solve_level(inputs, cfg):
        found.append(_probe(inputs, config, widths[len(found)], limit))
        solved = solve_level_in_process(inputs, cfg)
        progress(len(found), len(widths))
        return solved

    run_pipeline(left, right, exact, solve_level)
    return found


def level_widths(
    config: MatchConfig, shape: tuple[int, int], max_disparity: int, cache=None
) -> list[int | None]:
    """Each level's segment width as the estimate assumes it (None: whole rows), coarsest
    first, for images of ``shape`` (height, width); ``cache`` is where ``auto`` widths chosen
    before are looked up."""
    from shared.pyramid import level_shape, plan
    from shared.solvers.qpu.bundle_shapes import segment_width

    return [
        segment_width(
            config,
            config.bundle_height,
            level_shape(shape, level.downsample)[1],
            level.candidates,
            cache,
        )
        for level in plan(config, max_disparity)
    ]


def job_residual(
    config: MatchConfig,
    left,
    right,
    max_disparity: int,
    cache=None,
    progress: LevelProgress = _no_progress,
) -> list[LevelResidual] | None:
    """What the exact classical steps (the host's settling, roof duality) leave of a metered job's
    bundles, per level (None for an unmetered solver, or with neither step):
    :func:`shared.residual.survey` on the pair.

    Parameters
    ----------
    config : MatchConfig
        The job's configuration.
    left, right : numpy.ndarray
        The pair, float32 in [0, 1].
    max_disparity : int
        The resolved maximum disparity.
    cache : EmbeddingCache, optional
        Where ``auto`` widths chosen before are looked up.
    progress : callable, optional
        Told ``(levels surveyed, levels)`` after each level (not called without a survey).

    Returns
    -------
    list of LevelResidual or None
    """
    from shared.inference import settles
    from shared.solvers.meters import is_metered

    classical = config.solver_params.get("preprocess") != "none" or settles(config)
    if not is_metered(config.solver) or not classical:
        return None
    widths = level_widths(config, left.shape[:2], max_disparity, cache)
    return survey(left, right, config, max_disparity, widths, progress=progress)
