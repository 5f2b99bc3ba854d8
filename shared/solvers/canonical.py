"""Any BQM in the one form the solvers' own code takes, and their answer back in the caller's.

The solvers (roof duality, the embedded QPU path, Gurobi, the hybrid blocks) index variables as
array positions and sample QUBOs: a BINARY BQM on the variables 0..n-1, which is what the
pipeline's codecs produce. A dimod sampler must take any BQM, SPIN or BINARY, with any hashable
labels, empty or not, and answer in its vartype and labels. :class:`Canonical` is that
translation, done once in :meth:`shared.solvers.base.Sampler.sample` for every registered
solver, with dimod's own pieces (``relabel_variables_as_integers``, ``change_vartype``,
``relabel_variables``); a pipeline bundle passes through untouched.
"""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass
from typing import Any

import dimod
import numpy as np


@dataclass(frozen=True)
class Canonical:
    """A BQM brought to BINARY on 0..n-1 (``bqm``), with what restores the caller's form:
    its ``vartype`` and ``labels`` (canonical variable -> original label; None: unchanged)."""

    bqm: dimod.BinaryQuadraticModel
    vartype: dimod.Vartype
    labels: dict[int, Hashable] | None

    @classmethod
    def of(cls, bqm: dimod.BinaryQuadraticModel) -> Canonical:
        """The canonical form of ``bqm`` (``bqm`` itself when it is already BINARY on 0..n-1).

        Parameters
        ----------
        bqm : dimod.BinaryQuadraticModel
            Any BQM (any BQM class, vartype and hashable labels).

        Returns
        -------
        Canonical
            A float64 BINARY copy on 0..n-1 and the way back, unless nothing had to change.
        """
        variables = bqm.variables  # a DictBQM's are a KeysView: it is copied
        if bqm.vartype is dimod.BINARY and getattr(variables, "is_range", False):
            return cls(bqm, dimod.BINARY, None)
        binary = dimod.BinaryQuadraticModel(bqm, dtype=np.float64)
        binary.change_vartype(dimod.BINARY, inplace=True)
        _, changed = binary.relabel_variables_as_integers(inplace=True)  # only those that moved
        labels = {i: changed.get(i, i) for i in range(binary.num_variables)} if changed else None
        return cls(binary, bqm.vartype, labels)

    def states(self, initial_states: Any) -> Any:
        """A warm start given in the caller's vartype and labels, as samples-like on 0..n-1
        (BINARY, columns in variable order); None stays None.

        Raises
        ------
        ValueError
            When the states lack one of the BQM's variables.
        """
        if initial_states is None or (self.labels is None and self.vartype is dimod.BINARY):
            return initial_states
        samples, labels = dimod.as_samples(initial_states)
        n = self.bqm.num_variables
        if self.labels is not None:
            column = {label: j for j, label in enumerate(labels)}
            missing = [self.labels[i] for i in range(n) if self.labels[i] not in column]
            if missing:
                raise ValueError(f"initial_states have no value for variable {missing[0]!r}")
            samples = samples[:, [column[self.labels[i]] for i in range(n)]]
            labels = list(range(n))
        if self.vartype is dimod.SPIN:
            samples = (samples > 0).astype(np.int8)
        return samples, labels

    def solved(self) -> dimod.SampleSet | None:
        """The answer without sampling when there is nothing to sample: an empty BQM's one
        (empty) sample at its offset; None otherwise."""
        if self.bqm.num_variables:
            return None
        empty: tuple[np.ndarray, list] = (np.empty((1, 0), dtype=np.int8), [])
        return dimod.SampleSet.from_samples_bqm(empty, self.bqm, info={"timing": {}})

    def restore(self, sampleset: dimod.SampleSet) -> dimod.SampleSet:
        """``sampleset`` (of :attr:`bqm`) in the caller's labels and vartype; energies and info
        are kept (both forms have the same energy for every state)."""
        if self.labels is not None:
            sampleset = sampleset.relabel_variables(self.labels, inplace=False)
        if self.vartype is not dimod.BINARY:
            sampleset = sampleset.change_vartype(self.vartype, inplace=False)
        return sampleset
