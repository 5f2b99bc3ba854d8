"""The base class of every registered QUBO solver: a ``dimod.Sampler`` with our additions (see
:mod:`shared.solvers.base` for the contract). Its own module so that what needs no QUBO
(``exact``'s grid inference, the CLI's start) does not import dimod.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import dimod

from shared.config import Settings, get_settings
from shared.solvers.base import (
    Availability,
    SolverError,
    SolveResult,
    bad_parameters,
    solve,
)
from shared.solvers.canonical import Canonical
from shared.solvers.records import SolverSpec


def _declared(capability: str) -> property:
    """A sampler attribute read from its record, where it is declared once (``AttributeError``
    for a sampler built without one)."""

    def read(self: Sampler) -> Any:
        if self.spec is None:
            raise AttributeError(f"{self.name or type(self).__name__}: built without a record")
        return getattr(self.spec, capability)

    return property(read, doc=f"The record's {capability}")


class Sampler(dimod.Sampler):
    """What every registered QUBO solver adds to ``dimod.Sampler``: its name, whether it can
    run here, how its errors read, its record (:attr:`spec`, handed over by whoever builds it:
    the sampler knows no registry), and ``sample`` with the record's default parameters under
    the given ones (subclasses implement :meth:`run`)."""

    name: str = ""
    #: What is declared about it (schema, description, offline...): set by
    #: :func:`shared.solvers.registry.build`; None for a sampler built by hand.
    spec: SolverSpec | None = None
    #: The service settings handed over by whoever builds it (a worker's context); None: read
    #: from the environment when asked (:attr:`settings`).
    _settings: Settings | None = None

    @property
    def settings(self) -> Settings:
        """The settings it runs with (token, endpoint, embedding limits, licence): the ones
        handed over, else the environment's now (a test's patched environment is seen). An
        adapter reads them here only and hands the values on as parameters
        (:mod:`shared.solvers.qpu.leap`, ``packing.copies``, the embedding cache's timeout)."""
        return self._settings if self._settings is not None else get_settings()

    @settings.setter
    def settings(self, settings: Settings | None) -> None:
        self._settings = settings

    def available(self) -> Availability:
        return Availability(True, "always available (CPU)")

    def translate(self, error: Exception) -> SolverError | None:
        """Our error for one the sampler raised (None: let it through unchanged).

        Parameters
        ----------
        error : Exception
            What the sampler raised.

        Returns
        -------
        SolverError or None
            A ``SolverError`` naming the solver for ``TypeError`` and ``ValueError`` (bad
            parameters); None for anything else.
        """
        return bad_parameters(self.name, error)

    @contextmanager
    def translating(self) -> Iterator[None]:
        """Errors raised inside as ours (:meth:`translate`; ours, and those it leaves alone, pass
        unchanged): for the sampler's own calls to its solver (building it, planning, a batch)."""
        try:
            yield
        except SolverError:
            raise
        except Exception as error:
            mapped = self.translate(error)
            if mapped is None:
                raise
            raise mapped from None

    description = _declared("description")
    offline = _declared("offline")
    uses_qpu_time = _declared("uses_qpu_time")
    warm_start_default = _declared("warm_start_default")

    @property
    def defaults(self) -> dict[str, Any]:
        """Default parameters: those its record's schema states (none without a record)."""
        from shared.solvers.params import schema_defaults

        return {} if self.spec is None else schema_defaults(self.spec.params)

    def sample(
        self,
        bqm: dimod.BinaryQuadraticModel,
        *,
        seed: int | None = None,
        initial_states: Any = None,
        **params: Any,
    ) -> dimod.SampleSet:
        """Sample ``bqm``; ``initial_states`` samples-like, in the BQM's vartype. :meth:`run`
        sees it BINARY on the variables 0..n-1 (:class:`~shared.solvers.canonical.Canonical`),
        and the answer is in ``bqm``'s vartype and labels; an empty BQM is not run.

        Parameters
        ----------
        bqm : dimod.BinaryQuadraticModel
            The problem: any vartype, any hashable labels.
        seed : int, optional
            Random seed, passed to :meth:`run`.
        initial_states : samples-like, optional
            Warm start; None for a cold start.
        **params
            Solver parameters, over :attr:`defaults`.

        Returns
        -------
        dimod.SampleSet
            What :meth:`run` returns, in ``bqm``'s vartype and labels.
        """
        params = {**self.defaults, **params}
        form = Canonical.of(bqm)
        sampleset = form.solved()
        if sampleset is None:
            states = form.states(initial_states)
            sampleset = self.run(form.bqm, params, seed=seed, initial_states=states)
        return form.restore(sampleset)

    def run(
        self, bqm: dimod.BinaryQuadraticModel, params: dict[str, Any], *, seed, initial_states
    ) -> dimod.SampleSet:
        """The sampling itself, with the defaults filled in.

        Parameters
        ----------
        bqm : dimod.BinaryQuadraticModel
            The problem to sample: BINARY, on the variables 0..n-1, not empty.
        params : dict
            Defaults merged with the call's parameters.
        seed : int or None
            The call's seed.
        initial_states : samples-like or None
            The call's warm start, BINARY, on 0..n-1.

        Returns
        -------
        dimod.SampleSet
            Samples with ``info["timing"]`` in seconds.

        Raises
        ------
        NotImplementedError
            Always here; subclasses implement it.
        """
        raise NotImplementedError

    def solve(self, bqm: dimod.BinaryQuadraticModel, **kwargs: Any) -> SolveResult:
        """:func:`solve` with this sampler (``seed``, ``initial_state`` and parameters).

        Parameters
        ----------
        bqm : dimod.BinaryQuadraticModel
            The bundle's QUBO on the variables 0..n-1.
        **kwargs
            ``seed``, ``initial_state`` and solver parameters, as :func:`solve` takes them.

        Returns
        -------
        SolveResult
            The best sample and its timing.
        """
        return solve(self, bqm, **kwargs)
