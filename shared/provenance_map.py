"""The provenance map: which stage decided each pixel of the final disparity.

One small code per pixel (uint8, :class:`Stage`). A bundle's level inference gives its pixels
a code as it solves them (each strategy of :mod:`shared.inference`), the level's assembly
places them as it places the labels (:mod:`shared.assembly`; the residual design's
:func:`shared.settle.merge` starts from the host's codes and gives a tile's codes only where
the tile's answer was kept), the level's median marks what it changed, and the finishing step
(:mod:`shared.finishing`) carries the finest level's codes to full resolution and marks what the
left-right check filled and what the final filters moved.

Rule: the finest level decides. A coarser level only narrows the finer level's candidates and
warm-starts it; the finer level's solve decides the label, so its codes replace the coarser
level's everywhere (a coarser level's map is never carried down). Precedence at the end:
:attr:`Stage.FILLED` (the left-right check failed, the pixel was filled from the background)
over :attr:`Stage.FILTERED` (a filter moved the pixel by more than :data:`MOVED`) over the
finest level's own code.
"""

from __future__ import annotations

from enum import IntEnum
from typing import Any

import cv2
import numpy as np


class Stage(IntEnum):
    """What decided a pixel (the provenance map's codes; :data:`LEGEND` says each in words)."""

    FILLED = 0
    CERTIFIED = 1
    HOST = 2
    ROOF_DUALITY = 3
    SOLVER = 4
    REPAIRED = 5
    FILTERED = 6


#: Each code: its name in counts and JSON, its colour in the PNG (RGB hex) and what it means.
LEGEND: dict[Stage, tuple[str, str]] = {
    Stage.FILLED: (
        "#000000",
        "the left-right check failed: filled from the background (the validity map's 0)",
    ),
    Stage.CERTIFIED: (
        "#2ca02c",
        "host, certified: the exact optimum of its sub-problem (a row's dynamic programme, a "
        "host-certified tile) or where dual decomposition's row and column copies agree",
    ),
    Stage.HOST: (
        "#1f77b4",
        "host, not certified: the host's best labels (dual decomposition or TRW-S where the "
        "copies disagree; a solver's tile whose answer was not kept)",
    ),
    Stage.ROOF_DUALITY: (
        "#17becf",
        "roof duality (persistency) fixed every variable of the pixel before sampling",
    ),
    Stage.SOLVER: (
        "#d62728",
        "the sampler's answer (annealer, QPU, hybrid, sa, tabu, ...): in the residual design "
        "only where its tile's answer lowered the level's energy and was kept",
    ),
    Stage.REPAIRED: (
        "#ff7f0e",
        "repaired: the sampler's bits were no valid one-hot / domain-wall code",
    ),
    Stage.FILTERED: (
        "#9467bd",
        "moved by a filter (level median, weighted median, bilateral) by more than half a "
        "label step",
    ),
}

#: A filter "moved" a pixel when it changed its value by more than this (in the map's own
#: units: a level's labels, or full-resolution px): half a label step.
MOVED = 0.5

_PALETTE_BGR = np.array(
    [[int(LEGEND[s][0][i : i + 2], 16) for i in (5, 3, 1)] for s in Stage], dtype=np.uint8
)


def legend() -> list[dict[str, Any]]:
    """The legend as JSON: ``code``, ``name``, ``colour`` (RGB hex) and ``meaning``."""
    return [
        {"code": int(s), "name": s.name.lower(), "colour": LEGEND[s][0], "meaning": LEGEND[s][1]}
        for s in Stage
    ]


def legend_markdown() -> str:
    """The legend as a Markdown table (README and docs/architecture.md carry it; a test keeps
    them in step)."""
    rows = [f"| {int(s)} | `{s.name.lower()}` | {LEGEND[s][0]} | {LEGEND[s][1]} |" for s in Stage]
    return "\n".join(["| code | name | colour | decided by |", "|---|---|---|---|", *rows])


def filled(shape: tuple[int, ...], stage: Stage) -> np.ndarray:
    """A map of ``shape`` all ``stage``."""
    return np.full(shape, int(stage), dtype=np.uint8)


def counts(stages: np.ndarray) -> dict[str, int]:
    """Pixels per stage, by name (every stage, 0 where none): they sum to the map's size."""
    found = np.bincount(stages.ravel(), minlength=len(Stage))
    return {s.name.lower(): int(found[s]) for s in Stage}


def colour(stages: np.ndarray) -> np.ndarray:
    """The map as a BGR image (:data:`LEGEND`'s colours), for ``cv2.imwrite``."""
    return _PALETTE_BGR[stages]


def png(stages: np.ndarray) -> bytes:
    """The colour-coded map as PNG bytes (what ``qhsm match`` writes and the API serves)."""
    return cv2.imencode(".png", colour(stages))[1].tobytes()


def decode(image: np.ndarray) -> np.ndarray:
    """The codes back from a :func:`colour` image (BGR); raises ValueError on another colour."""
    flat = image.reshape(-1, 3).astype(np.int64)
    keys = (flat[:, 0] << 16) | (flat[:, 1] << 8) | flat[:, 2]
    palette = _PALETTE_BGR.astype(np.int64)
    table = (palette[:, 0] << 16) | (palette[:, 1] << 8) | palette[:, 2]
    order = np.argsort(table)
    index = np.searchsorted(table[order], keys).clip(0, len(table) - 1)
    if not np.all(table[order][index] == keys):
        raise ValueError("not a provenance map: a colour outside the legend")
    return order[index].astype(np.uint8).reshape(image.shape[:2])


def moved(stages: np.ndarray, before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """``stages`` with :attr:`Stage.FILTERED` where a filter changed ``before`` into ``after``
    by more than :data:`MOVED` (a new array; :attr:`Stage.FILLED` pixels stay filled)."""
    changed = (np.abs(after - before) > MOVED) & (stages != Stage.FILLED)
    return np.where(changed, np.uint8(Stage.FILTERED), stages)


def upsample(stages: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A level's codes at ``shape`` (nearest neighbour: a full-resolution pixel takes the code
    of the level pixel its disparity was upsampled from)."""
    if stages.shape == shape:
        return stages
    return cv2.resize(stages, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)
