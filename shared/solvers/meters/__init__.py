"""Meters: how a metered solver's D-Wave time is estimated before a solve and charged after it.

One module per meter (:mod:`~shared.solvers.meters.qpu`: the QPU timing model,
:mod:`~shared.solvers.meters.hybrid`: Leap's hybrid charge), each a :class:`Meter` registered here
under the name ``SolverSpec.meter`` gives. The lookup reads the solver's record when asked, so a
solver registered at any time (``register()``, a ``qhsm.solvers`` entry point) is estimated like
the built-in ones. The offline stand-ins are metered too: they are charged what the model says
the real service would take, so the accounting can be exercised without a token.

Per level and per job the estimates are :mod:`shared.solvers.meters.qpu_time`'s; reserving and
settling the time in Redis is :mod:`workers.quota`'s. All figures are seconds.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from shared.solvers.meters import hybrid, qpu
from shared.solvers.meters.base import BundleCall, LevelLoad, Meter
from shared.solvers.params import schema_defaults
from shared.solvers.registry import UnknownSolverError, spec

if TYPE_CHECKING:
    from shared.solvers.qpu.embedding_cache import EmbeddingSize

__all__ = [
    "BundleCall",
    "LevelLoad",
    "Meter",
    "bundle_seconds",
    "charged_seconds",
    "embeds",
    "is_metered",
    "meter_for",
    "meter_names",
    "meter_of",
    "register_meter",
]

_METERS: dict[str, Meter] = {meter.name: meter for meter in (qpu.METER, hybrid.METER)}


def register_meter(meter: Meter) -> Meter:
    """Add (or replace) a meter under ``meter.name``, for ``SolverSpec.meter`` to name."""
    _METERS[meter.name] = meter
    return meter


def meter_names() -> list[str]:
    """Names of the registered meters."""
    return list(_METERS)


def meter_of(solver_name: str) -> str | None:
    """The name of the meter a job on ``solver_name`` is charged with (``"qpu"``, ``"hybrid"``),
    or None for an unmetered or unknown solver: the registry's ``SolverSpec.meter``."""
    try:
        return spec(solver_name).meter
    except UnknownSolverError:
        return None


def meter_for(solver_name: str) -> Meter | None:
    """The :class:`Meter` of ``solver_name``; None when it is unmetered or unknown.

    Raises
    ------
    KeyError
        When its record names a meter nobody registered.
    """
    name = meter_of(solver_name)
    if name is None:
        return None
    if name not in _METERS:
        raise KeyError(f"solver {solver_name!r}: unknown meter {name!r} (known: {meter_names()})")
    return _METERS[name]


def is_metered(solver_name: str) -> bool:
    """Whether jobs on ``solver_name`` spend (real or simulated) D-Wave time from a budget:
    the QPU and hybrid solvers, their offline stand-ins and any metered plugin; False for
    unknown names."""
    return meter_of(solver_name) is not None


def embeds(solver_name: str) -> bool:
    """Whether ``solver_name``'s estimates read its bundle shapes' QPU embeddings (and its
    bundles are planned on the QPU graph)."""
    meter = meter_for(solver_name)
    return meter is not None and meter.embeds


def bundle_seconds(
    solver_name: str,
    num_variables: int,
    params: dict[str, Any] | None = None,
    *,
    num_qubits: int | None = None,
    embedding: EmbeddingSize | None = None,
    solver: Any = None,
) -> float:
    """Estimated charge of one bundle of ``num_variables`` binary variables; 0 if unmetered.

    Parameters
    ----------
    solver_name : str
        Registry name of the solver.
    num_variables : int
        Binary variables of the bundle's QUBO.
    params : dict, optional
        The bundle's sampler parameters (over the schema's defaults for QPU solvers).
    num_qubits : int, optional
        Qubits of the bundle's embedding (QPU meter; default: assumed from the variables).
    embedding : EmbeddingSize, optional
        The actual embedding's size; its qubits win over ``num_qubits``.
    solver : dwave.cloud solver, optional
        Live solver for the QPU model (None: the offline model).

    Returns
    -------
    float
        Estimated metered seconds of the bundle.
    """
    meter = meter_for(solver_name)
    if meter is None:
        return 0.0
    # what the solver runs with when a parameter is not given (qpu-sim reads fewer than qpu)
    defaults = schema_defaults(spec(solver_name).params)
    return meter.bundle_seconds(
        BundleCall(solver_name, num_variables, params, num_qubits, embedding, solver, defaults)
    )


def charged_seconds(timing: dict[str, float]) -> float:
    """What one solve costs its owner when its meter is not at hand: the hybrid ``charge_time``
    when reported, else the ``qpu_access_time`` (seconds, never negative); 0 when neither.
    (A meter's own :meth:`Meter.charged_seconds` reads only its kind's fields.)

    Parameters
    ----------
    timing : dict of str to float
        ``SolveResult.timing`` of one solve, in seconds.

    Returns
    -------
    float
        Seconds charged, never negative.
    """
    for key in ("charge_time", "qpu_access_time"):
        value = timing.get(key)
        if value is not None:
            return max(0.0, float(value))
    return 0.0
