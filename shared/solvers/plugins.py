"""``dimod:PACKAGE.MODULE.CLASS``: any installed ``dimod.Sampler`` class as a solver.

The class is imported by name and run through the same composites as the built-in samplers:
:class:`~shared.solvers.composites.SolverComposite` (seed and warm starts when the sampler takes
them) around :class:`~shared.solvers.composites.RoofDualityComposite`. Its bundles go to the
``dimod`` Celery queue; its parameters must be among those the class declares (checked when a
bundle runs), their values are the sampler's to check, and the task time limits bound them.
"""

from __future__ import annotations

from functools import cache
from importlib import import_module

import dimod

from shared.solvers import params as schemas
from shared.solvers.composites import RoofDualityComposite, SolverComposite
from shared.solvers.registry import DIMOD_PREFIX, DIMOD_QUEUE, SolverSpec

HELP = (
    "name an installed dimod.Sampler class as dimod:PACKAGE.MODULE.CLASS, e.g. "
    "dimod:dwave.samplers.SteepestDescentSolver (pip install the package that provides it on "
    "the API and on the workers of the dimod queue)"
)


def sampler_class(name: str) -> type[dimod.Sampler]:
    """The class a ``dimod:`` solver name points at.

    Parameters
    ----------
    name
        ``dimod:PACKAGE.MODULE.CLASS``.

    Returns
    -------
    type
        A ``dimod.Sampler`` subclass.

    Raises
    ------
    ValueError
        Saying why not (malformed name, module or class missing, not a dimod sampler).
    """
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


@cache
def dimod_spec(name: str) -> SolverSpec:
    """The registry record of a ``dimod:`` solver name.

    Parameters
    ----------
    name
        The solver name as a job or ``--solver`` gives it; :func:`sampler_class`'s
        ``ValueError`` is passed on.

    Returns
    -------
    SolverSpec
        Its factory puts the class inside the composites; its parameters have no schema (the
        sampler declares them); its queue is ``dimod``.
    """
    cls = sampler_class(name)

    def factory() -> SolverComposite:
        return SolverComposite(RoofDualityComposite(cls()))

    return SolverSpec(
        name=name,
        factory=factory,
        description=f"dimod sampler {cls.__module__}.{cls.__qualname__} after roof duality",
        params=schemas.AnyParams,
        queue=DIMOD_QUEUE,
        encoding="domain-wall",
    )
