"""What a metered bundle is expected to cost, in seconds: the amount reserved before it is sent.

The figures come from :mod:`shared.solvers.qpu_time` (the same model ``qhsm estimate`` uses),
with the actual embedding of a bundle's shape once any worker has embedded one and, with a
D-Wave token, the live solver's own timing data.
"""

from __future__ import annotations

from shared.solvers.registry import uses_warm_start

_live_solvers: dict[str, object | None] = {}


def live_timing_solver(solver_name: str):
    """The cloud solver behind a QPU adapter, or None offline. Looked up once per process.

    Parameters
    ----------
    solver_name : str
        A registered solver name.

    Returns
    -------
    object or None
        A solver with its own ``problem_timing_data`` and ``estimate_qpu_access_time``.
    """
    if solver_name not in _live_solvers:
        cloud = None
        try:
            from shared.solvers import get_solver

            adapter = get_solver(solver_name)
            if not getattr(adapter, "simulated", True) and callable(
                getattr(adapter, "sampler", None)
            ):
                cloud = getattr(adapter.sampler(), "solver", None)
        except Exception:  # no token or no network: the offline model will do
            cloud = None
        if not callable(getattr(cloud, "estimate_qpu_access_time", None)):
            cloud = None
        _live_solvers[solver_name] = cloud
    return _live_solvers[solver_name]


def bundle_estimate(inputs, config, start: int, stop: int, columns: int | None = None) -> float:
    """Estimated charge of the bundle of rows [start, stop) of a level (no BQM is built).

    Parameters
    ----------
    inputs
        The level's inputs (``shared.bundles``), for its candidate labels.
    config
        The job's ``MatchConfig`` (solver, encoding, solver parameters).
    start, stop : int
        The bundle's rows.
    columns : int or None
        Width of a row segment; None: whole rows.

    Returns
    -------
    float
        Seconds to reserve.
    """
    from shared.encodings import get_codec
    from shared.solvers.embedding_cache import default_cache
    from shared.solvers.qpu_time import (
        bundle_seconds,
        known_embedding,
        meter_of,
        sampler_params,
    )

    width, labels = inputs.candidates.shape[1], inputs.candidates.shape[2]
    width = width if columns is None else columns
    variables = (stop - start) * width * get_codec(config.encoding).variables_per_pixel(labels)
    params = sampler_params(config.solver_params, warm=uses_warm_start(config))
    if meter_of(config.solver) != "qpu":
        return bundle_seconds(config.solver, variables, params)
    embedding = known_embedding(
        default_cache(), config.solver, config.encoding, (stop - start, width), labels
    )
    live = live_timing_solver(config.solver)
    return bundle_seconds(config.solver, variables, params, embedding=embedding, solver=live)


def batch_estimate(inputs, config, bundles: list) -> float:
    """Estimated charge of bundles sent as one batch, before roof duality (an upper bound):
    the hybrid solvers' blocks of their size; the QPU solvers' bundles one call each.

    Parameters
    ----------
    inputs
        The level's inputs.
    config
        The job's ``MatchConfig``.
    bundles : list of Bundle
        The batch.

    Returns
    -------
    float
        Seconds to reserve.
    """
    from shared.encodings import get_codec
    from shared.solvers.qpu_time import hybrid_level_seconds, meter_of, sampler_params

    if meter_of(config.solver) != "hybrid":  # QPU: packed calls, as the job's estimate counts
        return sum(_packed_estimate(inputs, config, group) for group in _by_shape(bundles))
    per_pixel = get_codec(config.encoding).variables_per_pixel(inputs.candidates.shape[2])
    variables = sum((b.row_stop - b.row_start) * (b.col_stop - b.col_start) for b in bundles)
    params = sampler_params(config.solver_params, warm=uses_warm_start(config))
    return hybrid_level_seconds(variables * per_pixel, params)


def _by_shape(bundles: list) -> list[list]:
    groups: dict[tuple[int, int], list] = {}
    for bundle in bundles:
        groups.setdefault(bundle.shape, []).append(bundle)
    return list(groups.values())


def _packed_estimate(inputs, config, bundles: list) -> float:
    """Bundles of one shape sent as calls of the shape's known disjoint copies (else one each),
    before roof duality (an upper bound)."""
    from shared.encodings import get_codec
    from shared.solvers.embedding_cache import default_cache
    from shared.solvers.packing import packed_copies
    from shared.solvers.qpu_time import (
        MAX_QUBITS,
        assumed_qubits,
        bundle_seconds,
        known_embedding,
        sampler_params,
    )

    height, width = bundles[0].shape
    labels = inputs.candidates.shape[2]
    variables = height * width * get_codec(config.encoding).variables_per_pixel(labels)
    cache = default_cache()
    together = min(len(bundles), packed_copies(cache, config, (height, width), labels))
    size = known_embedding(cache, config.solver, config.encoding, (height, width), labels)
    qubits = size.qubits if size else assumed_qubits(variables)
    params = sampler_params(config.solver_params, warm=uses_warm_start(config))
    live = live_timing_solver(config.solver)
    each = bundle_seconds(config.solver, variables, params,
                          num_qubits=min(MAX_QUBITS, together * qubits), solver=live)  # fmt: skip
    return -(-len(bundles) // together) * each
