"""The one registry of solvers: one :class:`SolverSpec` per solver declares everything the rest
of the code asks about it (factory, parameter schema, metering, offline stand-in, worker queue,
row solver, warm-start default, recommended encoding). The CLI, the API's validation, the quota,
the worker queues and the docs all read it. Samplers are built lazily, so importing the registry
does not import Ocean or Gurobi.

Two ways to add solvers without editing this file:

* ``dimod:PACKAGE.MODULE.CLASS``: any installed ``dimod.Sampler`` class, run through the same
  composites as the built-in samplers (:mod:`shared.solvers.plugins`), on the ``dimod`` queue;
* the ``qhsm.solvers`` entry-point group: a package names a :class:`SolverSpec` (or a sampler
  factory, registered under the entry point's name) in its metadata.
"""

from __future__ import annotations

import contextlib
import logging
import sys
from collections.abc import Callable
from dataclasses import replace
from functools import partial
from importlib import import_module, metadata
from typing import Any

from shared.config import MatchConfig
from shared.solvers import params as schemas
from shared.solvers.base import RowSolver
from shared.solvers.errors import UnknownSolverError
from shared.solvers.records import (
    CPU_WORKERS,
    DIMOD_PREFIX,
    DIMOD_QUEUE,
    ENTRY_POINT_GROUP,
    SolverSpec,
)
from shared.solvers.resolved import ResolvedSolver

__all__ = ["ResolvedSolver", "SolverSpec", "UnknownSolverError", "resolve"]

log = logging.getLogger(__name__)


def _spec(name: str, factory: str, description: str, params, **capabilities) -> SolverSpec:
    return SolverSpec(name, f"shared.solvers.{factory}", description, params, **capabilities)


_LOCAL = {"warm_start_default": True, "encoding": "domain-wall"}
_BUILTIN = [
    _spec(
        "exact",
        "exact:ExactSolver",
        (
            "Grid inference (the default): each view's grid MRF by dual decomposition into "
            "row and column chains, certified within dual_gap; rows inference: the exact MAP of "
            "single-row bundles (dynamic programming)"
        ),
        schemas.NoParams,
        row_solver=True,
    ),
    _spec(
        "sa",
        "anneal:simulated_annealing",
        "Simulated annealing (dwave-samplers) after roof-duality fixing, classical CPU",
        schemas.AnnealParams,
        **_LOCAL,
    ),
    _spec(
        "tabu",
        "anneal:tabu",
        "Tabu search (dwave-samplers), classical CPU",
        schemas.TabuParams,
        **_LOCAL,
    ),
    _spec(
        "steepest-descent",
        "anneal:steepest_descent",
        "Steepest descent (dwave-samplers): local minimum, baseline / polisher",
        schemas.DescentParams,
        **_LOCAL,
    ),
    _spec(
        "gurobi",
        "gurobi:GurobiSampler",
        "Gurobi MIQP on the QUBO (exact up to MIPGap / TimeLimit)",
        schemas.GurobiParams,
        workers="gurobi",
    ),
    _spec(
        "qpu",
        "qpu.dwave:QPUSolver",
        "D-Wave QPU (Leap) with a cached fixed embedding",
        schemas.QPUParams,
        meter="qpu",
        encoding="domain-wall",
        workers="qpu",
    ),
    _spec(
        "qpu-sim",
        "qpu.dwave:SimulatedQPUSolver",
        "Offline simulator of the qpu path (MockDWaveSampler, Pegasus P16)",
        schemas.SimulatedQPUParams,
        meter="qpu",
        offline=True,
        encoding="domain-wall",
    ),
    _spec(
        "hybrid",
        "hybrid:LeapHybridSolver",
        "D-Wave Leap hybrid BQM solver (cloud)",
        schemas.LeapHybridParams,
        meter="hybrid",
        encoding="domain-wall",
        workers="hybrid",
    ),
    _spec(
        "hybrid-sim",
        "hybrid:KerberosSolver",
        "Offline stand-in for hybrid: dwave-hybrid Kerberos with MockDWaveSampler",
        schemas.KerberosParams,
        meter="hybrid",
        offline=True,
        encoding="domain-wall",
    ),
]
_SPECS: dict[str, SolverSpec] = {spec.name: spec for spec in _BUILTIN}
_INSTANCES: dict[str, Any] = {}
_scanned_path: tuple[str, ...] | None = None


def register(
    spec: SolverSpec | str,
    factory: str | Callable[[], Any] | None = None,
    params: type[schemas.SolverParams] = schemas.NoParams,
    **capabilities: Any,
) -> SolverSpec:
    """Add a solver: a :class:`SolverSpec`, or its name, factory, schema and capabilities.

    Parameters
    ----------
    spec
        The solver's record, or its name (then ``factory`` is required).
    factory
        ``"module:attribute"`` of a zero-argument callable returning the sampler, or the
        callable.
    params
        The schema of its ``solver_params``.
    **capabilities
        Further :class:`SolverSpec` fields (``meter``, ``offline``, ``queue``, ...).

    Returns
    -------
    SolverSpec
        The registered record.
    """
    if not isinstance(spec, SolverSpec):
        if factory is None:
            raise TypeError("register(name, factory, ...) needs a factory")
        spec = SolverSpec(spec, factory, params=params, **capabilities)
    _SPECS[spec.name] = spec
    _INSTANCES.pop(spec.name, None)
    return spec


def load_entry_points() -> None:
    """Register the solvers that installed packages declare in the ``qhsm.solvers`` group.

    Scanned again whenever ``sys.path`` changed since the last scan (tests add a folder with
    a ``*.dist-info``); a name registered already is kept, and a broken entry point is logged,
    not raised, so one bad plugin cannot take the service down.
    """
    global _scanned_path
    path = tuple(sys.path)
    if path == _scanned_path:
        return
    _scanned_path = path
    for entry in metadata.entry_points(group=ENTRY_POINT_GROUP):
        if entry.name in _SPECS:
            continue
        try:
            target = entry.load()
        except Exception as error:
            log.warning("solver plugin %s (%s) failed to load: %s", entry.name, entry.value, error)
            continue
        if isinstance(target, SolverSpec):
            register(replace(target, name=entry.name))
        else:
            register(entry.name, target)


def solver_names() -> list[str]:
    """Names of the registered solvers (``dimod:`` names are accepted besides these)."""
    load_entry_points()
    return list(_SPECS)


def spec(name: str) -> SolverSpec:
    """The record of solver ``name``; ``UnknownSolverError`` lists the valid names.

    Parameters
    ----------
    name
        A registered name or ``dimod:PACKAGE.MODULE.CLASS``.

    Returns
    -------
    SolverSpec
        What is declared about the solver.
    """
    if name not in _SPECS:
        load_entry_points()
    if name in _SPECS:
        return _SPECS[name]
    if name.startswith(DIMOD_PREFIX):
        from shared.solvers.plugins import dimod_spec

        try:
            return dimod_spec(name)
        except ValueError as error:
            raise UnknownSolverError(name, f"{name!r}: {error}") from None
    raise UnknownSolverError(
        name,
        f"unknown solver {name!r}; known solvers: {', '.join(solver_names())}, or "
        f"{DIMOD_PREFIX}PACKAGE.MODULE.CLASS for an installed dimod.Sampler",
    )


def get_solver(name: str) -> Any:
    """The sampler registered under ``name`` (built once per process).

    Parameters
    ----------
    name
        As for :func:`spec`.

    Returns
    -------
    Any
        A ``dimod.Sampler`` for every QUBO solver (``exact`` is also a row solver).
    """
    if name not in _INSTANCES:
        _INSTANCES[name] = build(name)
    return _INSTANCES[name]


def build(name: str) -> Any:
    """A new sampler of solver ``name`` (as for :func:`spec`), named so, from its record's
    factory: :func:`get_solver` keeps one per process; tests build their own to keep a mocked
    cloud out of the kept one."""
    record = spec(name)
    factory = record.factory
    if isinstance(factory, str):
        module_name, attribute = factory.split(":")
        factory = getattr(import_module(module_name), attribute)
    solver = factory()
    if isinstance(solver, RowSolver) != record.row_solver:
        raise TypeError(
            f"solver {name!r}: its record says row_solver={record.row_solver}, its sampler "
            f"{type(solver).__name__} {'is' if isinstance(solver, RowSolver) else 'is not'} "
            "a RowSolver (solve_rows)"
        )
    with contextlib.suppress(AttributeError):  # a read-only name is the sampler's own
        solver.name = name
    with contextlib.suppress(AttributeError):  # the sampler's facts: its record, handed over
        solver.spec = record
    return solver


def resolve(config: MatchConfig | str) -> ResolvedSolver:
    """The run's solver, resolved once: its record, its sampler (built on first use, one per
    process) and what ``config`` makes of it; pass it along instead of the name.

    Parameters
    ----------
    config
        The run's configuration, or a solver name (then the run-dependent answers are not
        available).

    Returns
    -------
    ResolvedSolver

    Raises
    ------
    UnknownSolverError
        For a name that is neither registered nor an allowed ``dimod:`` class.
    """
    if isinstance(config, str):
        return ResolvedSolver(spec(config), None, partial(_sampler, config))
    return ResolvedSolver(spec(config.solver), config, partial(_sampler, config.solver))


def is_row_solver(name: str) -> bool:
    """``resolve(name).spec.row_solver``: whether the solver works on the MRF costs of whole rows
    (``exact``), read from its record without building the sampler."""
    return resolve(name).spec.row_solver


def uses_warm_start(config: MatchConfig) -> bool:
    """``resolve(config).warm_start``: whether the run's bundles are warm-started."""
    return resolve(config).warm_start


def _sampler(name: str) -> Any:
    """:func:`get_solver`, looked up when called (a test may stand in for it)."""
    return get_solver(name)


def params_schema(name: str) -> type[schemas.SolverParams]:
    """The pydantic model bounding ``name``'s ``solver_params``.

    Parameters
    ----------
    name : str
        A registered name or ``dimod:PACKAGE.MODULE.CLASS``.

    Returns
    -------
    type of SolverParams
        The record's schema.

    Raises
    ------
    UnknownSolverError
        From :func:`spec`, for a name that is neither registered nor a loadable ``dimod:`` class.
    """
    return spec(name).params


def check_params(name: str, params: dict[str, Any]) -> dict[str, Any]:
    """``params`` checked against the solver's schema (``InvalidSolverParamsError`` says why not).

    Parameters
    ----------
    name : str
        Solver name whose schema applies.
    params : dict
        The job's ``solver_params``.

    Returns
    -------
    dict
        The parameters as :func:`shared.solvers.params.check` returns them.

    Raises
    ------
    InvalidSolverParamsError
        When they do not fit the schema.
    """
    return schemas.check(params_schema(name), name, params)


def recommended_encoding(name: str) -> str | None:
    """The label encoding to use with ``name`` when none is asked for (``qhsm bench``); None:
    no preference (the preset decides).

    Parameters
    ----------
    name : str
        Solver name.

    Returns
    -------
    str or None
        The record's ``encoding``.
    """
    return spec(name).encoding


def queue_names() -> list[str]:
    """Every solver queue a worker may consume (the registered solvers' and ``dimod``)."""
    queues = dict.fromkeys(spec(name).queue_name for name in solver_names())
    return [*queues, DIMOD_QUEUE]


def worker_groups() -> dict[str, list[str]]:
    """The solver queues each group of workers consumes (``SolverSpec.workers`` -> the queues
    of its solvers, in registry order); the ``dimod`` queue is the CPU workers'."""
    groups: dict[str, list[str]] = {CPU_WORKERS: []}
    for name in solver_names():
        record = spec(name)
        queues = groups.setdefault(record.workers, [])
        if record.queue_name not in queues:
            queues.append(record.queue_name)
    groups[CPU_WORKERS].append(DIMOD_QUEUE)
    return groups
