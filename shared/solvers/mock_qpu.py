"""The offline stand-in's base sampler (``qpu-sim``) and its read budget.

``qpu-sim`` runs the ``qpu`` code path (embedding, chain strength, unembedding, majority vote,
timing model) on dwave-system's ``MockDWaveSampler`` over a Pegasus P16 graph. The mock samples
with its default substitute, dwave-samplers' ``SteepestDescentSampler`` (C, vectorised over
reads): one greedy descent from a random state per read, no annealing.

Why the stand-in has its own read budget: a QPU read costs about 0.1 ms of QPU time, so ``qpu``
asks for 500; a read of the mock is a full descent on the embedded problem (about 1 ms of CPU
for a 120-px Tsukuba segment on ~1,650 qubits) and was 57 % of a bundle's time, which put a
Tsukuba job (6,912 bundles) at 25-55 min on two cores. Descents from random states add nothing
measurable past the first hundred (Tsukuba segments' energy gaps vs their optimum are the same
with 100 and 500 reads: docs/benchmarks.md, "Row segments"), so ``qpu-sim`` takes
:data:`SIM_NUM_READS` unless ``num_reads`` is given, and its simulated QPU time (what it charges,
and what a job's estimate assumes) is the timing model's value for the reads it took. ``qpu``
keeps 500.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from dwave.system.testing import MockDWaveSampler

#: ``qpu-sim``'s reads per bundle when ``num_reads`` is not given (``qpu``: 500).
SIM_NUM_READS = 100


def mock_sampler() -> MockDWaveSampler:
    """The stand-in's base sampler: ``MockDWaveSampler`` on Pegasus P16 with its default
    substitute (``SteepestDescentSampler``), parameter warnings off (we pass QPU parameters
    such as ``annealing_time`` that the mock accepts but does not simulate).

    Returns
    -------
    MockDWaveSampler
        A structured sampler with the QPU's properties; seed it per call through
        ``substitute_kwargs["seed"]``.
    """
    from dwave.system.testing import MockDWaveSampler

    from shared.solvers.dwave import MOCK_TOPOLOGY

    topology_type, shape = MOCK_TOPOLOGY
    return MockDWaveSampler(
        topology_type=topology_type, topology_shape=shape, parameter_warnings=False
    )
