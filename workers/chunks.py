"""A level's bundles grouped into Celery tasks, and a solved bundle as it travels back (JSON in
the job store, for the level's fan-in): ``workers.orchestration`` and the watchdog share them."""

from __future__ import annotations

import base64
import zlib

import numpy as np

from shared.assembly import BundleResult
from shared.config import MatchConfig, Settings
from shared.inference import inference_for
from shared.level_inputs import LevelInputs
from shared.solvers.meters import meter_for
from shared.solvers.qpu.packing import MAX_COPIES

#: Bundles as JSON-friendly lists: [row_start, row_stop] (whole rows, from older tasks) or
#: [row_start, row_stop, col_start, col_stop].
RowRanges = list[list[int]]
#: The solver's report fields a bundle carries back for the level's summary (and a grid's
#: termination: ``shared.inference.grid_views.termination``).
BUNDLE_INFO = ("embedding_cache", "qubits", "longest_chain", "dual_iterations", "disagreeing")


def task_chunks(inputs: LevelInputs, config: MatchConfig, rows_per_task: int) -> list[RowRanges]:
    """The level's planned bundles (both views' with the left-right check; row segments with
    a ``bundle_width``) grouped so each task covers about ``rows_per_task`` rows.

    Metered solvers send a task's bundles as few problems as they can (``solve_batch``): the
    QPU solvers get :data:`QPU_BUNDLES_PER_TASK` bundles a task (packed a shape's disjoint
    embeddings at a time into one QPU call), the hybrid solvers the whole level (one problem:
    Leap bills its minimum time per problem, so splitting the level would multiply the bill). A
    retried task re-sends its own bundles only.
    """
    bundles = [bundle.as_list() for bundle in inference_for(config).planned(inputs, config)]
    return group_bundles(bundles, config, rows_per_task)


def is_planned(inputs: LevelInputs) -> bool:
    """Whether the level's bundles were planned (``LevelInference.plan`` recorded their
    width)."""
    return "bundle_width" in inputs.prepared


def group_bundles(bundles: RowRanges, config: MatchConfig, rows_per_task: int) -> list[RowRanges]:
    """Bundles grouped into tasks (see ``task_chunks``; the watchdog regroups unsolved ones):
    about ``rows_per_task`` rows each, all segments of a row in the same task."""
    segments = max(1, sum(1 for bundle in bundles if bundle[0] == bundles[0][0])) if bundles else 1
    height = bundles[0][1] - bundles[0][0] if bundles else 1  # a whole view for grids
    per_task = max(1, rows_per_task // height) * segments
    meter = meter_for(config.solver)
    if meter is not None and meter.one_task_per_level:
        per_task = max(1, len(bundles))
    elif meter is not None:
        per_task = QPU_BUNDLES_PER_TASK
    return [bundles[i : i + per_task] for i in range(0, len(bundles), per_task)]


#: Bundles of a QPU solver's task: several QPU calls of a shape's disjoint copies each (the
#: estimate assumes full calls; a task's last call may carry fewer, <= 1 call in 8 here).
QPU_BUNDLES_PER_TASK = 8 * MAX_COPIES


def rows_per_task(settings: Settings, solver: str) -> int:
    return settings.solver_rows_per_task.get(solver, settings.rows_per_task)


def encode_bundle(result: BundleResult) -> dict:
    """A bundle result as JSON: labels travel as base64 uint8 (candidate indices are < 256),
    the provenance codes as base64 zlib-compressed uint8 (a whole view's are nearly uniform)."""
    first, last = result.columns
    stages = None
    if result.stages is not None:
        packed = zlib.compress(result.stages.astype(np.uint8).tobytes())
        stages = base64.b64encode(packed).decode("ascii")
    return {
        "rows": [result.row_start, result.row_stop],
        "columns": [first, last],
        "labels": base64.b64encode(result.labels.astype(np.uint8).tobytes()).decode("ascii"),
        "energy": result.energy,
        "repaired": result.repaired,
        "wall_time": result.wall_time,
        "timing": {key: float(value) for key, value in result.timing.items()},
        "info": {key: result.info[key] for key in BUNDLE_INFO if key in result.info},
        "lower_bound": result.lower_bound,
        "stages": stages,
    }


def decode_bundle(data: dict, width: int) -> BundleResult:
    """A bundle result from :func:`encode_bundle` (``width``: the level's, for whole rows)."""
    start, stop = data["rows"]
    first, last = data.get("columns", [0, width])
    labels = np.frombuffer(base64.b64decode(data["labels"]), dtype=np.uint8)
    stages = None
    if data.get("stages"):  # absent from bundles solved by an earlier version
        raw = zlib.decompress(base64.b64decode(data["stages"]))
        stages = np.frombuffer(raw, dtype=np.uint8).reshape(stop - start, last - first).copy()
    return BundleResult(
        row_start=start,
        row_stop=stop,
        labels=labels.reshape(stop - start, last - first).astype(np.int32),
        energy=data["energy"],
        repaired=data["repaired"],
        wall_time=data["wall_time"],
        timing=data["timing"],
        info=data.get("info", {}),
        col_start=first,
        col_stop=last,
        lower_bound=data.get("lower_bound"),
        stages=stages,
    )
