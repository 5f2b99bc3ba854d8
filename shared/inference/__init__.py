"""Level inference: how a level's MRF is cut into bundles, minimised and put back together.

One module per strategy (:class:`~shared.inference.base.LevelInference`), chosen by the one
table of :mod:`shared.inference.table` from the configuration and the solver's facts:

    grid_views     grid inference, row solver (``exact``): a whole view's grid by dual
                   decomposition or TRW-S (``grid_inference``), with a lower bound
    row_chains     rows inference, row solver: each row's chain exactly, blocks of rows at once
    qubo_rows      rows inference, QUBO solver: rows (or segments of them) as QUBOs
    qubo_tiles     grid inference, QUBO solver, no ``certify_tiles``: tiles with their
                   neighbours' starting labels as unaries
    qubo_residual  grid inference, QUBO solver, ``certify_tiles``: the host settles the level,
                   the tiles it leaves go to the solver (:mod:`shared.settle`)

:mod:`shared.inference.level` holds the calls the pipeline, the CLI and the service make.
"""

from shared.inference.base import BundleProgress, LevelInference, Termination
from shared.inference.level import (
    level_bundles,
    solve_bundles,
    solve_level_in_process,
)
from shared.inference.table import inference_for, reads_initial_labels, settles

__all__ = [
    "BundleProgress",
    "LevelInference",
    "Termination",
    "inference_for",
    "level_bundles",
    "reads_initial_labels",
    "settles",
    "solve_bundles",
    "solve_level_in_process",
]
