"""What one pyramid level did (:class:`LevelReport`): declared once here, in a leaf module, and
read by the pipeline (which fills it), the job record (``workers.records.LevelRecord``) and the
API's job status (``api.schemas.LevelTiming``), whose models are derived from it
(:func:`shared.wire.model_of`): a field added here is stored and sent without another edit.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass
class LevelReport:
    """What one level did, for the CLI's ``--json`` and the job status."""

    index: int
    downsample: int
    bin_width: int
    views: int
    height: int  # of one view (the level has ``views`` times as many rows)
    width: int
    candidates: int
    bundles: int
    energy: float
    #: A lower bound on the level's least energy (``grid`` inference with ``exact``), and the
    #: relative gap (energy - bound) / energy: how far from the optimum the level can be.
    lower_bound: float | None
    gap: float | None
    repaired: int
    seconds: float
    solver_seconds: float
    timing: dict[str, float] = field(default_factory=dict)
    #: Once per level from the solver: embeddings computed / reused, qubits, longest chain.
    info: dict[str, Any] = field(default_factory=dict)
    #: A QUBO solver's residual design (:class:`shared.settle.Residual`): pixels the host
    #: certified, tiles and pixels sent, tiles and pixels the solver improved; None otherwise.
    residual: dict[str, float] | None = None
    #: Why the level's minimisation stopped (:class:`shared.inference.Termination`).
    termination: str | None = None
    #: Pixels of the level (every view) per stage that decided them as solved
    #: (:func:`shared.provenance_map.counts`; the final map's are the finest level's).
    provenance_counts: dict[str, int] | None = None
