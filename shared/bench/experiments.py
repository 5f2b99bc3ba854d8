"""What ``qhsm bench`` runs: the experiments, their variants, the options and the paper's figures.

Nothing here runs or scores anything; :mod:`shared.bench.runner` turns these definitions into
runs. See :mod:`shared.bench` for the experiments themselves.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from shared.config import (
    AUTO,
    DataTerm,
    Inference,
    MatchConfig,
    Preset,
    PyramidKind,
    Regularizer,
    accurate_levels,
    paper_levels,
)
from shared.datasets import Scene

EXPERIMENTS = ("accurate", "solvers", "ablations", "baselines")
#: The paper's solver table (Gurobi, SA, hybrid, QPU) plus the exact row DP.
DEFAULT_SOLVERS = ("exact", "gurobi", "sa", "hybrid", "qpu")
#: The paper's ablations: MatchConfig changes relative to the full method.
ABLATIONS: dict[str, dict[str, Any]] = {
    "full": {},
    "no-regularizer": {"regularizer": Regularizer.NONE},
    "linear-regularizer": {"regularizer": Regularizer.LINEAR},
    "no-bilateral": {"bilateral": False},
    "no-median-no-bilateral": {"median": False, "bilateral": False},
}
#: The accurate preset's ablations: each of its steps switched back to the paper's choice.
ACCURATE_ABLATIONS: dict[str, dict[str, Any]] = {
    "accurate": {},
    "no-lr-check": {"lr_check": False},
    "no-weighted-median": {"weighted_median": False},
    "image-pyramid": {
        "pyramid": PyramidKind.IMAGE,
        "levels": [
            accurate_levels()[0].model_copy(
                update={"downsample": level.downsample, "candidates": level.candidates}
            )
            for level in paper_levels()
        ],
    },
    "squared-difference": {"data_term": DataTerm.SQUARED},
    "ad-census": {"data_term": DataTerm.AD_CENSUS},
    "rows": {"inference": Inference.ROWS},
    "one-slope": {"levels": [accurate_levels()[0].model_copy(update={"coarse_slope": None})]},
}
BASELINES = ("heidari", "sgbm")


@dataclass(frozen=True)
class PaperFigure:
    rmse: float | None
    bpp: float | None


#: Figures from the paper's table that we know; everything else is "n/a" (never guessed).
#: Protocol: all pixels with known ground truth outside the border (Tsukuba 18 px, Venus 10 px).
PAPER_FIGURES: dict[tuple[str, str], PaperFigure] = {
    ("gurobi", "tsukuba"): PaperFigure(1.53, 12.93),
    ("gurobi", "venus"): PaperFigure(0.96, 8.16),
    ("sa", "tsukuba"): PaperFigure(1.87, None),
}


class BenchError(ValueError):
    """A user-facing problem with the bench's arguments or environment."""


@dataclass
class Variant:
    """One configuration run on every scene: a pipeline config, or a baseline method."""

    experiment: str
    name: str
    method: str  # "pipeline", "heidari" or "sgbm"
    solver: str | None = None
    overrides: dict[str, Any] = field(default_factory=dict)
    preset: Preset = Preset.PAPER

    @property
    def key(self) -> str:
        return f"{self.experiment}/{self.name}"


@dataclass
class BenchOptions:
    """Everything ``qhsm bench`` was asked to do."""

    dataset: Path
    out: Path
    scenes: list[str] | None = None
    solvers: list[str] = field(default_factory=lambda: list(DEFAULT_SOLVERS))
    experiments: list[str] = field(default_factory=lambda: list(EXPERIMENTS))
    ablation_solver: str = "exact"
    url: str | None = None
    bundle_height: int = 1
    encoding: str | None = None  # None: the solver's recommended one, else the preset's
    seed: int = 0
    solver_params: dict[str, dict[str, Any]] = field(default_factory=dict)
    processes: int = 0
    scale: float | None = None
    border: int | None = None
    max_disparity: int | str | None = None  # None: each scene's protocol; "auto": estimated


def parse_solver_params(items: Sequence[str]) -> dict[str, dict[str, Any]]:
    """Route ``--param`` items to their solvers.

    Parameters
    ----------
    items
        ``[SOLVER:]KEY=VALUE`` strings; values are parsed as JSON where they can be.

    Returns
    -------
    dict
        ``{solver or "*": {key: value}}``; ``"*"`` holds the items without a solver.
    """
    params: dict[str, dict[str, Any]] = {}
    for item in items:
        assignment, sep, _ = item.partition("=")
        if not sep or not assignment:
            raise BenchError(f"--param expects [SOLVER:]KEY=VALUE, got {item!r}")
        solver, colon, key = assignment.rpartition(":")
        value = item[len(assignment) + 1 :]
        try:
            parsed = json.loads(value)
        except json.JSONDecodeError:
            parsed = value
        params.setdefault(solver if colon else "*", {})[key] = parsed
    return params


def split_names(text: str | None) -> list[str] | None:
    """Split a comma-separated option.

    Parameters
    ----------
    text
        ``"a, b"``, or ``None`` when the option was not given.

    Returns
    -------
    list of str or None
        ``["a", "b"]``; ``None`` stays ``None``.
    """
    if text is None:
        return None
    return [name.strip() for name in text.split(",") if name.strip()]


def variants(options: BenchOptions) -> list[Variant]:
    """The runs each scene gets, in table order.

    Parameters
    ----------
    options
        The experiments, solvers and ablation solver asked for.

    Returns
    -------
    list of Variant
        Every experiment's variants, experiments in :data:`EXPERIMENTS` order.
    """
    unknown = set(options.experiments) - set(EXPERIMENTS)
    if unknown:
        raise BenchError(
            f"unknown experiment {', '.join(sorted(unknown))}; choose from {', '.join(EXPERIMENTS)}"
        )
    chosen: list[Variant] = []
    if "accurate" in options.experiments:
        chosen += [
            Variant("accurate", name, "pipeline", options.ablation_solver, changes, Preset.ACCURATE)
            for name, changes in ACCURATE_ABLATIONS.items()
        ]
    if "solvers" in options.experiments:
        chosen += [Variant("solvers", name, "pipeline", name) for name in options.solvers]
    if "ablations" in options.experiments:
        chosen += [
            Variant("ablations", name, "pipeline", options.ablation_solver, changes)
            for name, changes in ABLATIONS.items()
        ]
    if "baselines" in options.experiments:
        chosen += [Variant("baselines", name, name) for name in BASELINES]
    return chosen


def match_config(
    variant: Variant, scene: Scene, options: BenchOptions, encoding: str | None
) -> MatchConfig:
    """The pipeline configuration of a pipeline variant on one scene.

    Parameters
    ----------
    variant
        A variant with ``method == "pipeline"`` (it has a solver).
    scene
        The scene (its protocol gives the disparity range unless ``auto`` was asked for).
    options
        The bench options (bundle height, seed, solver parameters).
    encoding
        The encoding its runs use (``runner.encoding_for``: the solver's record is read there).

    Returns
    -------
    MatchConfig
        The configuration the runner is given (the variant's overrides win over the options).
    """
    assert variant.solver is not None
    settings: dict[str, Any] = {
        "preset": variant.preset,
        "solver": variant.solver,
        "max_disparity": AUTO if options.max_disparity == AUTO else scene.max_disparity,
        "bundle_height": options.bundle_height,
        "encoding": encoding,
        "seed": options.seed,
        "solver_params": {
            **options.solver_params.get("*", {}),
            **options.solver_params.get(variant.solver, {}),
        },
    }
    return MatchConfig(**{**settings, **variant.overrides})  # the variant's changes win


def paper_figure(variant: Variant, scene: str) -> dict | None:
    """The paper's figure for this run, if known; ``source`` says which of the paper's rows.

    The exact row DP is the optimum of single-row bundles, so it sits beside the paper's Gurobi
    (optimal) figures; the ablations' full method beside its solver's.

    Parameters
    ----------
    variant
        The variant that ran.
    scene
        The scene's name.

    Returns
    -------
    dict or None
        ``{"rmse", "bpp", "source"}``, or None where the paper has no figure for the run.
    """
    if variant.method != "pipeline" or variant.name not in (variant.solver, "full"):
        return None
    solver = "gurobi" if variant.solver == "exact" else variant.solver
    figure = PAPER_FIGURES.get((solver or "", scene))
    if figure is None:
        return None
    return {"rmse": figure.rmse, "bpp": figure.bpp, "source": solver}
