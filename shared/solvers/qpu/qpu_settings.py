"""What a QPU call is sent with besides the problem: the chain strength and, for a warm start,
the reverse anneal. The adapter (:mod:`shared.solvers.qpu.dwave`), the packed calls
(:mod:`shared.solvers.qpu.packing`) and the estimates (:mod:`shared.solvers.meters.qpu_time`)
read them here, so an estimate prices the call that is made.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import dimod

#: The paper's chain-strength prefactor for uniform torque compensation.
CHAIN_STRENGTH_PREFACTOR = 1.414
#: Reverse anneal used for warm starts on the QPU: back to s = 0.45, pause, forward again (us).
WARM_START_SCHEDULE = [[0.0, 1.0], [5.0, 0.45], [15.0, 0.45], [20.0, 1.0]]


def chain_strength(bqm: dimod.BinaryQuadraticModel) -> float:
    """Uniform torque compensation with prefactor 1.414 (Ocean's default rule, paper's value).

    Parameters
    ----------
    bqm : dimod.BinaryQuadraticModel
        The logical problem before embedding.

    Returns
    -------
    float
        Chain coupling strength, in the units of the BQM's biases.
    """
    from dwave.embedding.chain_strength import uniform_torque_compensation

    return float(uniform_torque_compensation(bqm, prefactor=CHAIN_STRENGTH_PREFACTOR))


def reverse_anneal(
    params: dict[str, Any], initial_state: Any, *, given_win: bool = False
) -> dict[str, Any]:
    """Make ``params`` a warm start from ``initial_state``, in place: a reverse anneal (the given
    ``anneal_schedule``, else :data:`WARM_START_SCHEDULE`), re-initialised per read, with no
    ``annealing_time`` (the schedule sets the anneal's length; SAPI refuses both).

    Parameters
    ----------
    params : dict
        The call's sampler parameters.
    initial_state : Any
        The state the anneal starts from (SAPI's ``initial_state``).
    given_win : bool, optional
        Keep an ``initial_state`` or ``reinitialize_state`` already in ``params`` (the estimate
        prices what the job asked for); by default the warm start's replace them.

    Returns
    -------
    dict
        ``params``.
    """
    warm = {
        "initial_state": initial_state,
        "anneal_schedule": params.get("anneal_schedule", WARM_START_SCHEDULE),
        "reinitialize_state": True,
    }
    for key, value in warm.items():
        if not given_win or key not in params:
            params[key] = value
    params.pop("annealing_time", None)
    return params
