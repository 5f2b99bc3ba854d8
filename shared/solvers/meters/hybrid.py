"""The ``hybrid`` meter: what Leap's hybrid BQM solver bills (``charge_time``).

It charges about its run time, which is the requested ``time_limit`` or, when unset, the
solver's minimum for the problem size (the ``minimum_time_limit`` property: a piecewise-linear
curve in the number of variables). Offline we use the curve Leap's
``hybrid_binary_quadratic_model_version2`` reports (3 s up to 1024 variables, 10 s at 4096, 40 s
at 10000, ...). ``hybrid`` is charged what Leap reports; the offline ``hybrid-sim`` reports (and
is charged) :func:`hybrid_charge_seconds` of its size. A level's bundles reach the solver joined
into blocks of at most :data:`HYBRID_MAX_VARIABLES` (:mod:`shared.solvers.hybrid`): Leap bills
its minimum per problem, so one block per level costs what one row did.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from shared.solvers.meters.base import BundleCall, LevelLoad, Meter

if TYPE_CHECKING:
    from shared.solvers.resolved import ResolvedSolver

#: ``minimum_time_limit`` of hybrid_binary_quadratic_model_version2: [variables, seconds] pairs.
HYBRID_MINIMUM_TIME_LIMIT: list[list[float]] = [
    [1, 3.0],
    [1024, 3.0],
    [4096, 10.0],
    [10000, 40.0],
    [30000, 200.0],
    [100000, 600.0],
    [1000000, 600.0],
]

#: Variables of one hybrid problem at most (Leap's hybrid BQM solver's
#: ``maximum_number_of_variables``): a level's bundles are joined into blocks of this size.
HYBRID_MAX_VARIABLES = 1_000_000


def hybrid_charge_seconds(
    num_variables: int,
    params: dict[str, Any] | None = None,
    minimum_time_limit: list[list[float]] | None = None,
) -> float:
    """Estimated charge of one hybrid BQM problem: ``time_limit`` if given, never below the
    solver's minimum for ``num_variables`` (LeapHybridSampler.min_time_limit's interpolation).

    Parameters
    ----------
    num_variables : int
        Binary variables of the problem.
    params : dict, optional
        Solver parameters; only ``time_limit`` (seconds) is read.
    minimum_time_limit : list of [variables, seconds], optional
        The solver's ``minimum_time_limit`` curve; default :data:`HYBRID_MINIMUM_TIME_LIMIT`.

    Returns
    -------
    float
        Estimated ``charge_time``, seconds.
    """
    params = params or {}
    curve = np.asarray(minimum_time_limit or HYBRID_MINIMUM_TIME_LIMIT, dtype=float)
    minimum = float(np.interp(num_variables, curve[:, 0], curve[:, 1]))
    requested = params.get("time_limit")
    return max(minimum, float(requested)) if requested is not None else minimum


def hybrid_level_seconds(variables: float, params: dict[str, Any] | None = None) -> float:
    """Charge of ``variables`` sent to the hybrid solver as blocks of at most
    :data:`HYBRID_MAX_VARIABLES` (``shared.solvers.hybrid``: a level's rests, joined).

    Parameters
    ----------
    variables : float
        Variables left of the level's bundles (0: nothing is sent).
    params : dict, optional
        Solver parameters (``time_limit``).

    Returns
    -------
    float
        Seconds: the blocks' charges, the variables shared evenly between them.
    """
    if variables <= 0:
        return 0.0
    count = int(np.ceil(variables / HYBRID_MAX_VARIABLES))
    return count * hybrid_charge_seconds(max(1, round(variables / count)), params)


class HybridChargeMeter(Meter):
    """Leap's hybrid charge per problem; a level's variables joined into blocks."""

    name = "hybrid"
    one_task_per_level = True
    charge_keys = ("charge_time", "qpu_access_time")

    def bundle_seconds(self, call: BundleCall) -> float:
        return hybrid_charge_seconds(call.num_variables, call.params)

    def level_seconds(
        self, solver: ResolvedSolver, params: dict[str, Any], load: LevelLoad, live: Any = None
    ) -> tuple[float, int | None]:
        variables = load.bundles * load.variables * load.variables_share
        return hybrid_level_seconds(variables, params), None


METER = HybridChargeMeter()
