"""What produced a result: the qhsm version, the preset, the solver and the full configuration.

Every result carries it (``qhsm match --json`` and the ``.json`` sidecar beside the map, the
job record and status, the Python API's result), so a map found on disk months later says how
to make it again.
"""

from __future__ import annotations

from typing import Any

import shared
from shared.config import MatchConfig


def qhsm_version() -> str:
    """qhsm's version: ``shared.__version__``, which pyproject.toml reads at install (the one
    place it is written). Not ``importlib.metadata``: importing it costs ``qhsm match`` 12 ms
    and a distribution lookup 4 ms more."""
    return shared.__version__


def provenance(config: MatchConfig) -> dict[str, Any]:
    """``version``, ``preset``, ``solver`` and the full ``config`` (every option, the preset's
    included), JSON-friendly."""
    return {
        "version": qhsm_version(),
        "preset": config.preset.value,
        "solver": config.solver,
        "config": config.model_dump(mode="json"),
    }
