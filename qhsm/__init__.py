"""qhsm's Python API: match a stereo pair, score a map, talk to the service.

>>> import qhsm
>>> left, right = qhsm.load_pair("left.png", "right.png")   # colour kept, as the CLI reads
>>> result = qhsm.match(left, right, qhsm.MatchConfig(max_disparity=16))
>>> qhsm.evaluate(result.disparity, "gt.pfm")["bad_2"]

``match`` runs what ``qhsm match`` runs (the same views, config and solvers, in this process);
``evaluate`` is ``qhsm eval --json``; ``Client`` (:class:`api.client.Client`, imported on first
use so that matching needs nothing of the service) submits jobs to ``qhsm serve``.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ParamSpec

import numpy as np

from shared.config import MatchConfig
from shared.ground_truth import Evaluation, evaluate_ground_truth
from shared.images import load_pair, save_disparity
from shared.pipeline import MatchResult
from shared.provenance import provenance, qhsm_version

if TYPE_CHECKING:
    from api.client import Client

__all__ = ["Client", "MatchConfig", "Result", "evaluate", "load_pair", "match"]
__version__ = qhsm_version()

PathOrArray = str | Path | np.ndarray
P = ParamSpec("P")


@dataclass
class Result(MatchResult):
    """A :class:`shared.pipeline.MatchResult` (``disparity``, ``levels``, ``seconds``,
    ``disparity_range``, the maps ``validity``, ``confidence`` and ``provenance_map``: which
    stage decided each pixel, :mod:`shared.provenance_map`) with what produced the run
    (``provenance``: version, preset, solver, full config)."""

    provenance: dict[str, Any] = field(default_factory=dict)

    def summary(self) -> dict:
        """The run without its map, JSON-friendly, as ``qhsm match --json`` prints it."""
        return {**super().summary(), "provenance": self.provenance}

    def save(self, path: str | Path) -> Path:
        """Write the map (.pfm, .png x256 or .npy, as ``qhsm match -o``)."""
        return save_disparity(self.disparity, path)


def match(
    left: PathOrArray,
    right: PathOrArray,
    config: MatchConfig | None = None,
    *,
    processes: int = 0,
    force: bool = False,
    **options: Any,
) -> Result:
    """Match a rectified pair in this process.

    ``left`` / ``right``: files (read by :func:`load_pair`) or float32 views in [0, 1], gray or
    BGR. ``config`` or ``options`` (``MatchConfig`` fields: ``max_disparity=16``,
    ``solver="sa"``, ``preset="paper"``, ...); the default is ``qhsm match``'s. ``processes``:
    local processes for QUBO solvers' bundles (0: one per core). Views that fail their check
    (swapped, not rectified, identical) raise :class:`shared.disparity_range.ViewsRefusedError`
    with the reason unless ``force``.
    """
    from shared.pipeline import run_pipeline
    from shared.process_pool import ProcessPoolLevelSolver

    if config is None:
        config = MatchConfig(**options)
    elif options:
        config = MatchConfig(**{**config.model_dump(exclude_unset=True), **options})
    if not isinstance(left, np.ndarray) or not isinstance(right, np.ndarray):
        left, right = load_pair(left, right)  # type: ignore[arg-type]
    with ProcessPoolLevelSolver(processes) as solve_level:
        result = run_pipeline(left, right, config, solve_level, force=force)
    return Result(**vars(result), provenance=provenance(config))


def _reporting(score: Callable[P, Evaluation]) -> Callable[P, dict[str, Any]]:
    """``score`` answering its evaluation's :meth:`~shared.ground_truth.Evaluation.report`: the
    facade takes the very parameters of the function it wraps (one signature, one place)."""

    def evaluate(*args: P.args, **kwargs: P.kwargs) -> dict[str, Any]:
        """Score a map (a file or an array) against a ground truth: ``qhsm eval --json``'s dict
        (rmse, avgerr, bad_0_5, bad_1, bad_2, bad_4, d1, bpp at ``threshold``, ``regions``, the
        scale and its source); the parameters are
        :func:`shared.ground_truth.evaluate_ground_truth`'s.

        A ground-truth file's scale comes from its format or scene folder when not given (with
        a warning when a given one contradicts it); an array holds disparities times ``scale``
        (1).
        """
        return score(*args, **kwargs).report()

    signature = inspect.signature(score).replace(return_annotation="dict[str, Any]")
    evaluate.__signature__ = signature  # type: ignore[attr-defined]  # what help() shows
    evaluate.__qualname__ = "evaluate"
    return evaluate


evaluate = _reporting(evaluate_ground_truth)


def __getattr__(name: str) -> Any:
    """``qhsm.Client``, imported on first use (the service's HTTP client)."""
    if name == "Client":
        from api.client import Client

        return Client
    raise AttributeError(f"module 'qhsm' has no attribute {name!r}")
