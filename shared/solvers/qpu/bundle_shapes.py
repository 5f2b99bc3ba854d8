"""Bundle shapes, the unit the QPU embeds: the QUBO structure of every bundle of a shape, the
embedding size a worker recorded for it, and the segment width ``--bundle-width auto`` chose.

A bundle's QUBO graph depends only on its shape (rows, columns, candidates, encoding), never on
its costs, so embeddings are found and recorded per shape; the estimates
(:mod:`shared.solvers.meters.qpu_time`), the QPU adapters (:mod:`shared.solvers.qpu.dwave`) and
the packing of bundles into one call (:mod:`shared.solvers.qpu.packing`) all key them the same
way here.
"""

from __future__ import annotations

import logging
from functools import lru_cache

import numpy as np

from shared.config import AUTO, MatchConfig
from shared.encodings import get_codec
from shared.energy import Costs
from shared.solvers.meters import embeds
from shared.solvers.meters.qpu import MAX_QUBITS, QUBITS_PER_VARIABLE
from shared.solvers.qpu.embedding_cache import EmbeddingCache, EmbeddingSize
from shared.solvers.qpu.structure_keys import structure_digest

log = logging.getLogger(__name__)


def shape_bqm(encoding: str, height: int, width: int, candidates: int):
    """The QUBO of a bundle of this shape with zero costs: the QUBO's graph does not depend on
    the costs (zero terms are kept), so it has the structure of every bundle of the shape.

    Parameters
    ----------
    encoding : str
        Label encoding (``one-hot``, ``domain-wall``, ...), a codec name.
    height, width : int
        Bundle size in pixels (rows, columns).
    candidates : int
        Disparity labels per pixel.

    Returns
    -------
    dimod.BinaryQuadraticModel
        The codec's QUBO of all-zero costs.
    """
    zeros = np.zeros((height, width, candidates))
    costs = Costs(
        candidates=np.zeros((height, width, candidates), dtype=np.int32),
        unary=zeros,
        pair_h=np.zeros((height, max(0, width - 1), candidates, candidates)),
        pair_v=np.zeros((max(0, height - 1), width, candidates, candidates)),
    )
    return get_codec(encoding).encode(costs)


@lru_cache(maxsize=256)
def bundle_digest(encoding: str, height: int, width: int, candidates: int) -> str:
    """Structure digest of every bundle of this shape (:func:`shape_bqm`).

    Parameters
    ----------
    encoding : str
        Codec name of the label encoding.
    height, width : int
        Bundle rows and columns, pixels.
    candidates : int
        Labels per pixel.

    Returns
    -------
    str
        The :func:`~shared.solvers.qpu.structure_keys.structure_digest` (cached per shape).
    """
    return structure_digest(shape_bqm(encoding, height, width, candidates))


def known_embedding(
    cache: EmbeddingCache | None,
    solver_name: str,
    encoding: str,
    shape: tuple[int, int],
    candidates: int,
) -> EmbeddingSize | None:
    """The size of the embedding ``solver_name`` uses for bundles of ``shape`` (rows, width)
    with ``candidates`` labels, if any worker has embedded one; None otherwise (and for
    solvers that do not embed).

    Parameters
    ----------
    cache : EmbeddingCache or None
        Where sizes are looked up; None: none known.
    solver_name : str
        Registry name of the solver.
    encoding : str
        Codec name of the label encoding.
    shape : (int, int)
        Bundle rows and columns, pixels.
    candidates : int
        Labels per pixel.

    Returns
    -------
    EmbeddingSize or None
        The recorded size; None when unknown, too large to embed, not a QPU solver, or the store
        is unreachable.
    """
    if cache is None or not embeds(solver_name):
        return None
    height, width = shape
    if height * width * get_codec(encoding).variables_per_pixel(candidates) > MAX_QUBITS:
        return None  # cannot embed, so never was (and its QUBO may be too big to build here)
    try:
        return cache.known_size(
            solver_name, bundle_digest(str(encoding), height, width, candidates)
        )
    except Exception as error:  # an unreachable store only costs us the better estimate
        log.warning("embedding sizes unavailable (%s); assuming %.1f qubits per variable",
                    error, QUBITS_PER_VARIABLE)  # fmt: skip
        return None


#: Before ``--bundle-width auto`` has run for a level shape, estimates assume segments of about
#: this many QUBO variables (64 domain-wall pixels of 6 labels; P16 embeds them in ~15 s).
AUTO_VARIABLES_GUESS = 320


def auto_width_key(
    solver_name: str, encoding: str, height: int, candidates: int, row_width: int, margin: int
) -> str:
    """Store key of the width ``auto`` chose for this level shape.

    Parameters
    ----------
    solver_name : str
        Registry name of the solver.
    encoding : str
        Codec name of the label encoding.
    height : int
        Bundle height, rows.
    candidates : int
        Labels per pixel.
    row_width : int
        The level's row width, pixels.
    margin : int
        ``bundle_margin``, pixels.

    Returns
    -------
    str
        A key for :meth:`~shared.solvers.qpu.embedding_cache.EmbeddingCache.record_width`.
    """
    return f"{solver_name}-{encoding}-{height}x{row_width}-{candidates}-{margin}"


def segment_width(
    config: MatchConfig,
    height: int,
    row_width: int,
    candidates: int,
    cache: EmbeddingCache | None,
) -> int | None:
    """The segment width the run will use on a level (None: whole rows): the configured one,
    or for ``auto`` (the QPU solvers' default) the width chosen before, else a guess.

    Parameters
    ----------
    config : MatchConfig
        The run's configuration (solver, encoding, bundle width and margin).
    height : int
        Bundle height, rows.
    row_width : int
        The level's row width, pixels.
    candidates : int
        Labels per pixel at the level.
    cache : EmbeddingCache or None
        Where an earlier ``auto`` choice is looked up; None: guess.

    Returns
    -------
    int or None
        Segment width in pixels; None for whole rows (also when the width is not below
        ``row_width``).
    """
    setting = config.bundle_width
    if setting is None and embeds(config.solver):
        setting = AUTO
    if setting != AUTO:
        return setting if setting is None or setting < row_width else None
    if cache is not None:
        key = auto_width_key(
            config.solver, str(config.encoding), height, candidates, row_width, config.bundle_margin
        )
        try:
            known, width = cache.known_width(key)
        except Exception:  # an unreachable store only costs us the better estimate
            known, width = False, None
        if known:
            return width
    per_pixel = height * get_codec(config.encoding).variables_per_pixel(candidates)
    guess = max(2 * config.bundle_margin + 1, AUTO_VARIABLES_GUESS // per_pixel)
    return guess if guess < row_width else None
