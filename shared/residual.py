"""What the exact classical step (roof duality) leaves of a job's bundles, measured before the job
runs, so that its estimate is what the metered solvers will charge.

A metered solver fixes on the host what roof duality proves and sends only the rest
(:func:`shared.solvers.composites.reduce`); how much is left depends on the bundles' costs, so no
formula in the image size gives it. :func:`survey` runs the pyramid with the ``exact`` solver (a
stand-in for the coarser levels' maps, which decide a level's candidates; milliseconds per
level) and applies roof duality to an evenly spread sample of each level's bundles, cut as the
metered solver will cut them. Classical work only: nothing is sent anywhere.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from shared.config import MatchConfig

#: Bundles per level the survey reduces at most (evenly spread): a few seconds on Tsukuba.
SURVEY_BUNDLES = 160


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

    def as_dict(self) -> dict[str, Any]:
        return {
            "sampled": self.sampled,
            "sent_share": self.sent_share,
            "variables_share": self.variables_share,
            "sent_variables_share": self.sent_variables_share,
        }


def _probe(inputs, config: MatchConfig, width: int | None, limit: int) -> LevelResidual:
    """Roof duality on an evenly spread sample of at most ``limit`` of the level's bundles."""
    from shared.encodings import get_codec
    from shared.solvers.composites import reduce

    codec = get_codec(config.encoding)
    bundles = inputs.bundles(config.bundle_height, width, config.bundle_margin)
    picked = np.unique(np.linspace(0, len(bundles) - 1, min(limit, len(bundles))).astype(int))
    variables, left, sent, sent_variables, sent_left = 0, 0, 0, 0, 0
    rows: tuple[int, int] | None = None
    for index in picked:
        start, stop, first, last = bundles[index].as_list()
        if rows != (start, stop):
            row_costs, rows = inputs.costs(config, start, stop), (start, stop)
        reduction = reduce(codec.encode(row_costs.columns(first, last), config.rectifier))
        n, m = reduction.bqm.num_variables, int(reduction.free.size)
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

    Returns
    -------
    list of LevelResidual
        One per level, coarsest first.
    """
    from shared.pipeline import run_pipeline
    from shared.solve import solve_level_in_process

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
        return solve_level_in_process(inputs, cfg)

    run_pipeline(left, right, exact, solve_level)
    return found


def level_widths(
    config: MatchConfig, shape: tuple[int, int], max_disparity: int, cache=None
) -> list[int | None]:
    """Each level's segment width as the estimate assumes it (None: whole rows), coarsest
    first, for images of ``shape`` (height, width); ``cache`` is where ``auto`` widths chosen
    before are looked up."""
    from shared.pyramid import level_shape, plan
    from shared.solvers.bundle_shapes import segment_width

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
    config: MatchConfig, left, right, max_disparity: int, cache=None
) -> list[LevelResidual] | None:
    """What roof duality leaves of a metered job's bundles, per level (None for an unmetered
    solver or ``preprocess="none"``): :func:`shared.residual.survey` on the pair.

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

    Returns
    -------
    list of LevelResidual or None
    """
    from shared.solvers.timing_model import meter_of

    if meter_of(config.solver) is None or config.solver_params.get("preprocess") == "none":
        return None
    widths = level_widths(config, left.shape[:2], max_disparity, cache)
    return survey(left, right, config, max_disparity, widths)
