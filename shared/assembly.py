"""Putting a level back together: bundle results (labels, energy, solver report) into one label
map, row segments stitched where each pixel lies farthest from a cut, and a per-level summary of
the embeddings used. Every level inference's ``assemble`` (:mod:`shared.inference`) starts from
:func:`assemble`, in process and in the service's fan-in alike."""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np

from shared.bundles import owned_columns
from shared.config import MatchConfig
from shared.energy import mrf_energy
from shared.level_inputs import LevelInputs
from shared.provenance_map import Stage


@dataclass
class BundleResult:
    """Labels (rows, columns) of one bundle with its MRF energy and the solver's report.
    ``col_stop`` None means the row's end (whole-row bundles)."""

    row_start: int
    row_stop: int
    labels: np.ndarray
    energy: float
    repaired: int
    wall_time: float
    timing: dict[str, float] = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    col_start: int = 0
    col_stop: int | None = None
    #: A lower bound on the bundle's least energy (dual decomposition), when the solver has one.
    lower_bound: float | None = None
    #: What decided each pixel (:class:`shared.provenance_map.Stage` codes, uint8, the labels'
    #: shape); None: not recorded (taken as :attr:`Stage.HOST`).
    stages: np.ndarray | None = None

    @property
    def columns(self) -> tuple[int, int]:
        return self.col_start, self.col_start + self.labels.shape[1]


@dataclass
class LevelSolution:
    """All bundles of a level put back together."""

    labels: np.ndarray
    energy: float
    repaired: int
    bundles: int
    solver_seconds: float
    timing: dict[str, float] = field(default_factory=dict)
    #: What the bundles' solver reports once per level (embeddings computed / reused, ...).
    info: dict = field(default_factory=dict)
    #: The sum of the bundles' lower bounds, when every bundle has one.
    lower_bound: float | None = None
    #: The residual design's counts (:class:`shared.settle.Residual`), None without it.
    residual: dict | None = None
    #: Why the level's minimisation stopped (:class:`shared.inference.base.Termination`).
    termination: str | None = None
    #: What decided each pixel of the level (:class:`shared.provenance_map.Stage`, uint8).
    stages: np.ndarray | None = None


def assemble(
    inputs: LevelInputs, results: list[BundleResult], config: MatchConfig | None = None
) -> LevelSolution:
    """Put bundle results back into one label map; every pixel must be covered exactly once.

    Row segments are stitched (:func:`shared.bundles.owned_columns`: each pixel from the segment
    in which it lies farthest from a cut). The level's energy is the sum of the bundles' own;
    for stitched rows it is that of the stitched labels, which need ``config`` for the costs
    (grid tiles price the level on the whole grid themselves:
    :class:`shared.inference.qubo_tiles.QuboTiles`).

    Parameters
    ----------
    inputs : LevelInputs
        The level.
    results : list of BundleResult
        Every bundle's result, in any order.
    config : MatchConfig, optional
        Needed to price stitched rows.

    Returns
    -------
    LevelSolution

    Raises
    ------
    ValueError
        If a pixel is covered by no bundle or by several (other than segments of one row).
    """
    height, width = inputs.shape
    labels = np.full((height, width), -1, dtype=np.int32)
    stages = np.full((height, width), int(Stage.HOST), dtype=np.uint8)
    covered = np.zeros((height, width), dtype=np.int32)
    timing: dict[str, float] = {}
    # sums independent of arrival order
    results = sorted(results, key=lambda r: (r.row_start, r.col_start))
    groups: dict[tuple[int, int], list[BundleResult]] = {}
    for result in results:
        groups.setdefault((result.row_start, result.row_stop), []).append(result)
        for key, value in result.timing.items():
            timing[key] = timing.get(key, 0.0) + float(value)
    energy = 0.0
    for (start, stop), group in groups.items():
        spans = [r.columns for r in group]
        owned = owned_columns(spans) if _tiles(spans, width) else spans
        for result, (first, _), (own_first, own_last) in zip(group, spans, owned, strict=True):
            labels[start:stop, own_first:own_last] = result.labels[
                :, own_first - first : own_last - first
            ]
            if result.stages is not None:
                stages[start:stop, own_first:own_last] = result.stages[
                    :, own_first - first : own_last - first
                ]
            covered[start:stop, own_first:own_last] += 1
        if len(group) == 1:
            energy += group[0].energy
        elif config is not None:
            energy += mrf_energy(inputs.costs(config, start, stop), labels[start:stop])
        else:
            energy = float("nan")
    if not np.all(covered == 1):
        missing = sorted({int(y) for y in np.flatnonzero((covered == 0).any(axis=1))})
        doubled = sorted({int(y) for y in np.flatnonzero((covered > 1).any(axis=1))})
        raise ValueError(
            f"level {inputs.plan.index}: rows missing {missing[:10]}, rows solved twice "
            f"{doubled[:10]} (counting rows with any such pixel)"
        )
    bounds = [r.lower_bound for r in results]
    return LevelSolution(
        labels=labels,
        lower_bound=None if None in bounds else float(sum(b for b in bounds if b is not None)),
        energy=float(energy),
        repaired=int(sum(r.repaired for r in results)),
        bundles=len(results),
        solver_seconds=float(sum(r.wall_time for r in results)),
        timing=timing,
        info=embedding_summary(results, inputs.prepared),
        stages=stages,
    )


def _tiles(spans: list[tuple[int, int]], width: int) -> bool:
    """Whether sorted column spans are the overlapping segments of one whole row."""
    return (
        spans[0][0] == 0
        and spans[-1][1] == width
        and all(b[0] <= a[1] and a[0] < b[0] for a, b in pairwise(spans))
    )


def embedding_summary(results: list[BundleResult], prepared: dict | None = None) -> dict:
    """Per level: minor embeddings computed (while preparing the level, including the widths
    ``auto`` tried, and by the bundles) vs reused by bundles (from memory or the shared store),
    and the qubits and longest chain of the embeddings used; for the metered solvers, the
    bundles and variables that roof duality left for the solver (``bundles_sent``,
    ``variables_sent`` of ``variables``). Empty for solvers that do neither.

    Parameters
    ----------
    results : list of BundleResult
        The level's bundle results.
    prepared : dict, optional
        What the level inference's ``plan`` recorded (``LevelInputs.prepared``).

    Returns
    -------
    dict
        ``prepared`` plus embedding counts, bundle shapes, qubits and longest chain.
    """
    prepared = dict(prepared or {})
    reduced = [r.info for r in results if "residual_variables" in r.info]
    if reduced:  # the metered solvers' classical step: what reached the solver
        prepared.update(
            bundles_sent=sum(1 for info in reduced if info["residual_variables"]),
            variables=sum(int(info["variables"]) for info in reduced),
            variables_sent=sum(int(info["residual_variables"]) for info in reduced),
        )
    embedded = [r.info for r in results if "embedding_cache" in r.info]
    if not embedded:
        return prepared
    computed = sum(1 for info in embedded if info["embedding_cache"] == "computed")
    shapes = {(r.row_stop - r.row_start, r.labels.shape[1]) for r in results}
    return {
        **prepared,
        "embeddings_computed": computed + prepared.get("embeddings_computed", 0),
        "embeddings_reused": len(embedded) - computed,
        "bundle_shapes": sorted(f"{h}x{w}" for h, w in shapes),
        "qubits": max(int(info.get("qubits", 0)) for info in embedded),
        "longest_chain": max(int(info.get("longest_chain", 0)) for info in embedded),
    }
