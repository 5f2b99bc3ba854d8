"""What produced a result: the qhsm version, the preset, the solver and the full configuration.

Every result carries it (``qhsm match --json`` and the ``.json`` sidecar beside the map, the
job record and status, the Python API's result), so a map found on disk months later says how
to make it again.
"""

from __future__ import annotations

from functools import cache
from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as installed_version
from typing import Any

from shared.config import MatchConfig

#: Reported when qhsm runs from a source tree that is not installed.
UNKNOWN_VERSION = "unknown (not installed)"


@cache
def qhsm_version() -> str:
    """The installed qhsm's version (pyproject.toml's, the one place it is written)."""
    try:
        return installed_version("qhsm")
    except PackageNotFoundError:
        return UNKNOWN_VERSION


def provenance(config: MatchConfig) -> dict[str, Any]:
    """``version``, ``preset``, ``solver`` and the full ``config`` (every option, the preset's
    included), JSON-friendly."""
    return {
        "version": qhsm_version(),
        "preset": config.preset.value,
        "solver": config.solver,
        "config": config.model_dump(mode="json"),
    }
