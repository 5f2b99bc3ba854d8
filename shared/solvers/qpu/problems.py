"""Which D-Wave problems a piece of work sent, so a job's problems can be found on Leap: the
label each problem carries there and the problem ids SAPI returned.

A worker opens :func:`sent_problems` around a task's solve (``workers.orchestration``) with the
task's label, ``qhsm job <id> level <n> bundle <first>``; the Leap adapters' base samplers are
wrapped in :class:`LabelledSampler`, which gives every problem that label with its number in the
task (``... #k``) and keeps the id SAPI returned. The chunk report, the job's status and the
owner's usage ledger then carry the ids. Outside such a block (``qhsm match``) problems are
labelled ``qhsm`` and nothing is kept.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from typing import Any

import dimod

from shared.solvers.composites import ChildComposite

#: The label of a problem sent outside any job (``qhsm match``).
DEFAULT_LABEL = "qhsm"


@dataclass
class ProblemLog:
    """The problems one task sent: its label and, in order, the ids SAPI returned."""

    label: str
    ids: list[str] = field(default_factory=list)
    sent: int = 0

    def next_label(self) -> str:
        """The label of the task's next problem: ``<label> #k``, k counting from 1."""
        self.sent += 1
        return f"{self.label} #{self.sent}"


_current: ContextVar[ProblemLog | None] = ContextVar("qhsm_problem_log", default=None)


def task_label(job_id: str, level: int, first_bundle: str) -> str:
    """``qhsm job <id> level <n> bundle <first>``: ``level`` 0-based, shown 1-based."""
    return f"qhsm job {job_id} level {level + 1} bundle {first_bundle}"


@contextmanager
def sent_problems(label: str) -> Iterator[ProblemLog]:
    """Label and log every problem the Leap adapters send inside the block."""
    log = ProblemLog(label)
    token = _current.set(log)
    try:
        yield log
    finally:
        _current.reset(token)


def current() -> ProblemLog | None:
    """The open :func:`sent_problems` log, if any."""
    return _current.get()


class LabelledSampler(ChildComposite, dimod.Structured):
    """A Leap sampler (``DWaveSampler``, ``LeapHybridSampler``) whose every problem is labelled
    and whose problem ids are logged (:func:`sent_problems`); everything else is the child's
    (its graph, properties, ``solver``, ...)."""

    def __getattr__(self, name: str) -> Any:  # the child's own attributes (client, solver, ...)
        if name == "_child":
            raise AttributeError(name)
        return getattr(self._child, name)

    @property
    def properties(self) -> dict[str, Any]:
        return self._child.properties  # its own, as the child's users read them

    @property
    def nodelist(self) -> list:
        return self._child.nodelist

    @property
    def edgelist(self) -> list:
        return self._child.edgelist

    def sample(self, bqm: dimod.BinaryQuadraticModel, **params: Any) -> dimod.SampleSet:
        """The child's answer (resolved) to ``bqm`` sent with the label; its id logged."""
        log = current()
        params["label"] = log.next_label() if log is not None else DEFAULT_LABEL
        sampleset = self._child.sample(bqm, **params)
        sampleset.resolve()
        problem_id = sampleset.info.get("problem_id")
        if log is not None and problem_id:
            log.ids.append(str(problem_id))
        return sampleset
