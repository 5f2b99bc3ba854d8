"""``dimod:PACKAGE.MODULE.CLASS``: an allowed ``dimod.Sampler`` class as a solver.

Only classes on the allowlist can be named: the dwave-samplers and dimod reference samplers
below, plus what the deployment adds in ``Settings.dimod_samplers`` (with bounds for their
parameters). A name that is not on it is refused before anything is imported, so no job can make
the API or a worker import a module of its choice. Each allowed class has a parameter schema,
as the built-in solvers do (checked at submit: 422), and samplers that enumerate every state
(``dimod.ExactSolver``) a largest bundle. An allowed class runs through the same composites as
the built-in samplers: :class:`~shared.solvers.composites.SolverComposite` (seed and warm
starts when the sampler takes them) around
:class:`~shared.solvers.composites.RoofDualityComposite`; its bundles go to the ``dimod``
Celery queue.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from importlib import import_module
from typing import Any

import dimod

from shared.solvers import params as schemas
from shared.solvers.base import SolverError
from shared.solvers.composites import ChildComposite, RoofDualityComposite, SolverComposite
from shared.solvers.records import DIMOD_PREFIX, DIMOD_QUEUE, SolverSpec


@dataclass(frozen=True)
class AllowedSampler:
    """What a deployment allows of one ``dimod:`` class: its parameters' schema and, for
    samplers whose memory grows as 2^n, the most variables a bundle may have."""

    params: type[schemas.SolverParams]
    max_variables: int | None = None


#: Exact enumeration holds every state: 2^24 x 24 bytes is 400 MB.
EXACT_MAX_VARIABLES = 24

#: The dimod samplers a job may name without any setting (class path -> what is allowed).
BUILTIN_SAMPLERS: dict[str, AllowedSampler] = {
    "dwave.samplers.SimulatedAnnealingSampler": AllowedSampler(schemas.DimodAnnealParams),
    "dwave.samplers.SteepestDescentSolver": AllowedSampler(schemas.DescentParams),
    "dwave.samplers.SteepestDescentSampler": AllowedSampler(schemas.DescentParams),
    "dwave.samplers.TabuSampler": AllowedSampler(schemas.TabuParams),
    "dwave.samplers.RandomSampler": AllowedSampler(schemas.ReadsParams),
    "dwave.samplers.TreeDecompositionSolver": AllowedSampler(schemas.ReadsParams),
    "dimod.RandomSampler": AllowedSampler(schemas.ReadsParams),
    "dimod.ExactSolver": AllowedSampler(schemas.NoParams, max_variables=EXACT_MAX_VARIABLES),
}

HELP = (
    "name an allowed dimod.Sampler class as dimod:PACKAGE.MODULE.CLASS, e.g. "
    "dimod:dwave.samplers.SteepestDescentSolver; an operator allows others with "
    "QHSM_DIMOD_SAMPLERS (and installs their package on the API and the dimod workers)"
)


def allowed_samplers() -> dict[str, AllowedSampler]:
    """The built-in list plus the deployment's ``Settings.dimod_samplers`` (which may also give
    a built-in class other bounds).

    Returns
    -------
    dict
        Class path -> :class:`AllowedSampler`.
    """
    from shared.config import get_settings

    added = {
        path: _deployment_entry(path, tuple(sorted(bounds.items())))
        for path, bounds in get_settings().dimod_samplers.items()
    }
    return {**BUILTIN_SAMPLERS, **added}


@cache
def _deployment_entry(path: str, bounds: tuple[tuple[str, tuple[float, float]], ...]):
    """One schema per (class, bounds): the settings are read again at every lookup."""
    return AllowedSampler(schemas.bounds_schema(path, dict(bounds)))


def allowed(name: str) -> AllowedSampler:
    """The allowlist entry of a ``dimod:`` name, or a ``ValueError`` that lists the allowed
    classes; nothing is imported.

    Parameters
    ----------
    name
        ``dimod:PACKAGE.MODULE.CLASS``.

    Returns
    -------
    AllowedSampler
    """
    path = name.removeprefix(DIMOD_PREFIX)
    entries = allowed_samplers()
    if path not in entries:
        raise ValueError(
            f"{path or name!r} is not among the dimod samplers this service allows "
            f"({', '.join(sorted(entries))}); {HELP}"
        )
    return entries[path]


def sampler_class(name: str) -> type[dimod.Sampler]:
    """The class an allowed ``dimod:`` solver name points at.

    Parameters
    ----------
    name
        ``dimod:PACKAGE.MODULE.CLASS``, on the allowlist.

    Returns
    -------
    type
        A ``dimod.Sampler`` subclass.

    Raises
    ------
    ValueError
        Saying why not (not allowed, malformed, module or class missing, not a dimod sampler).
    """
    allowed(name)
    path = name.removeprefix(DIMOD_PREFIX)
    module_name, _, class_name = path.rpartition(".")
    if not module_name or not class_name:
        raise ValueError(f"not of the form dimod:PACKAGE.MODULE.CLASS; {HELP}")
    try:
        target = getattr(import_module(module_name), class_name)
    except ImportError as error:
        raise ValueError(f"cannot import {module_name} ({error}); {HELP}") from None
    except AttributeError:
        raise ValueError(f"{module_name} has no {class_name}; {HELP}") from None
    if not (isinstance(target, type) and issubclass(target, dimod.Sampler)):
        raise ValueError(f"{path} is not a dimod.Sampler subclass; {HELP}")
    return target


class SizeLimit(ChildComposite):
    """Refuses bundles with more than ``max_variables`` variables (after roof duality) before
    the child allocates for them: an exact enumeration would need 2^n states."""

    def __init__(self, child: dimod.Sampler, max_variables: int, name: str) -> None:
        super().__init__(child)
        self.max_variables, self.name = max_variables, name

    def sample(self, bqm, **params: Any) -> dimod.SampleSet:
        if bqm.num_variables > self.max_variables:
            raise SolverError(
                f"{self.name} enumerates every state: at most {self.max_variables} variables "
                f"per bundle, this one has {bqm.num_variables}; use another sampler (or a "
                "smaller image)"
            )
        return self._child.sample(bqm, **params)


@cache
def _spec(name: str, entry: AllowedSampler) -> SolverSpec:
    cls = sampler_class(name)

    def factory() -> SolverComposite:
        child: dimod.Sampler = cls()
        if entry.max_variables is not None:
            child = SizeLimit(child, entry.max_variables, name)
        return SolverComposite(RoofDualityComposite(child))

    return SolverSpec(
        name=name,
        factory=factory,
        description=f"dimod sampler {cls.__module__}.{cls.__qualname__} after roof duality",
        params=entry.params,
        queue=DIMOD_QUEUE,
        encoding="domain-wall",
    )


def dimod_spec(name: str) -> SolverSpec:
    """The registry record of a ``dimod:`` solver name.

    Parameters
    ----------
    name
        The solver name as a job or ``--solver`` gives it; :func:`sampler_class`'s
        ``ValueError`` (not allowed, cannot import) is passed on.

    Returns
    -------
    SolverSpec
        Its factory puts the class inside the composites; its parameters are the allowlist
        entry's schema; its queue is ``dimod``.
    """
    return _spec(name, allowed(name))
