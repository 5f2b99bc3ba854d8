"""The worker's metered solve: every bundle reserved, charged its reported time, stopped cleanly."""

from __future__ import annotations

import json
import time

import dimod
import numpy as np
import pytest

from shared.config import MatchConfig
from shared.pipeline import plan_run, prepare_level
from shared.solvers import SolveResult, registry
from shared.solvers.meters import qpu_time
from shared.solvers.registry import resolve
from shared.synthetic import make_scene
from workers.quota import (
    QpuMeter,
    QpuSemaphore,
    QuotaExceededError,
    QuotaLedger,
    bundle_estimate,
    solve_metered,
)


class FakeQPU:
    """Stands in for qpu-sim: reports a different QPU access time for every call."""

    name = "qpu-sim"
    description = "fake"
    offline = True
    uses_qpu_time = False

    def __init__(self) -> None:
        self.calls = 0
        self.seconds = lambda call: 0.001 * call  # the access time call number ``call`` reports

    def available(self):
        return registry.get_solver("exact").available()

    def solve(self, bqm: dimod.BinaryQuadraticModel, *, seed=None, initial_state=None, **params):
        self.calls += 1
        sample = np.zeros(bqm.num_variables, dtype=np.int8)
        return SolveResult(
            sample=sample,
            energy=float(bqm.energy(sample)),
            wall_time=0.0,
            timing={"qpu_access_time": self.seconds(self.calls)},
        )


@pytest.fixture
def fake(monkeypatch) -> FakeQPU:
    solver = FakeQPU()
    monkeypatch.setitem(registry._INSTANCES, "qpu-sim", solver)
    return solver


@pytest.fixture
def level():
    scene = make_scene(16, 24, max_disparity=6, seed=0)
    config = MatchConfig(
        preset="paper",
        solver="qpu-sim",
        encoding="domain-wall",
        max_disparity=6,
        solver_params={"num_reads": 10},
    )
    _, plans = plan_run(scene.left, scene.right, config)
    return prepare_level(scene.left, scene.right, config, plans[2]), config  # full resolution


@pytest.fixture
def meter(redis_client, prefix) -> QpuMeter:
    ledger = QuotaLedger(redis_client, prefix)
    return QpuMeter(ledger, QpuSemaphore(redis_client, prefix, limit=1), slot_ttl=60, slot_wait=5)


def test_each_bundle_is_charged_what_its_sample_set_reports(fake, level, meter):
    inputs, config = level
    meter.ledger.set_limit("ada", 10.0)
    rows = [(0, 1), (1, 2), (2, 3), (3, 4)]
    results = solve_metered(meter, "ada", "job", inputs, registry.resolve(config), rows)
    assert [r.row_start for r in results] == [0, 1, 2, 3]
    reported = sum(qpu_time.charged_seconds(r.timing) for r in results)
    usage = meter.ledger.job_usage("ada", "job")
    assert usage.seconds == pytest.approx(reported) == pytest.approx(0.001 * (1 + 2 + 3 + 4))
    assert usage.problems == 4
    assert meter.ledger.status("ada").reserved == 0.0


def test_estimate_of_a_bundle_is_the_model_for_its_size(level):
    inputs, config = level
    width, labels = inputs.shape[1], inputs.count
    expected = qpu_time.bundle_seconds("qpu-sim", 2 * width * (labels - 1), {"num_reads": 10})
    assert bundle_estimate(inputs, config, 0, 2, solver=resolve(config)) == expected


def test_running_out_of_budget_stops_before_the_next_bundle(fake, level, meter):
    inputs, config = level
    estimate = bundle_estimate(inputs, config, 0, 1, solver=resolve(config))
    fake.seconds = lambda call: estimate  # every bundle uses exactly its estimate
    meter.ledger.set_limit("ada", 2.5 * estimate)
    with pytest.raises(QuotaExceededError, match="not enough QPU budget left for user 'ada'"):
        solve_metered(
            meter, "ada", "job", inputs, registry.resolve(config), [(r, r + 1) for r in range(8)]
        )
    assert fake.calls == 2  # the third bundle was refused before it was sent
    usage = meter.ledger.job_usage("ada", "job")
    assert usage.problems == 2 and usage.seconds == pytest.approx(2 * estimate)


def test_a_stopped_job_sends_no_more_bundles(fake, level, meter):
    inputs, config = level
    states = iter([True, True, False])
    solver = registry.resolve(config)
    assert solve_metered(meter, "ada", "job", inputs, solver, [(0, 1), (1, 2), (2, 3)],
                         still_running=lambda: next(states)) is None  # fmt: skip
    assert fake.calls == 2
    assert meter.semaphore.in_flight() == 0


def test_bundles_wait_for_a_free_lab_wide_slot(fake, level, meter, redis_client, prefix):
    inputs, config = level
    other = QpuSemaphore(redis_client, prefix, limit=1).try_acquire("bob", ttl=0.3)
    assert other is not None  # bob's bundle holds the only slot; it expires after 0.3 s
    started = time.monotonic()
    solve_metered(meter, "ada", "job", inputs, registry.resolve(config), [(0, 1)])
    assert time.monotonic() - started >= 0.25
    assert fake.calls == 1


def test_a_bundle_estimate_uses_the_embedding_once_a_worker_found_it(level, tmp_path, monkeypatch):
    from shared.solvers.qpu import embedding_cache
    from shared.solvers.qpu.embedding_cache import DirectoryStore, EmbeddingCache, EmbeddingSize

    inputs, config = level
    cache = EmbeddingCache(DirectoryStore(tmp_path))
    monkeypatch.setattr(embedding_cache, "_default_cache", cache)
    width, labels = inputs.shape[1], inputs.count
    assumed = bundle_estimate(inputs, config, 0, 1, solver=resolve(config))
    digest = qpu_time.bundle_digest(config.encoding, 1, width, labels)
    size = EmbeddingSize(qubits=7, chains=width * (labels - 1), longest_chain=1)
    cache.store.set(embedding_cache.size_key("qpu-sim", digest), json.dumps(size.__dict__))
    known = bundle_estimate(inputs, config, 0, 1, solver=resolve(config))
    assert known == qpu_time.qpu_access_seconds(7, {"num_reads": 10}) != assumed
    # a two-row bundle is another structure, not embedded yet: still the assumption
    two_rows = qpu_time.bundle_seconds("qpu-sim", 2 * width * (labels - 1), {"num_reads": 10})
    assert bundle_estimate(inputs, config, 0, 2, solver=resolve(config)) == two_rows


# --- a metered solver added after the timing model was imported ----------------------------------

PLUGIN = "lab-qpu"
#: What a lab's plugin package holds: a QPU-metered solver (here the offline QPU path again).
PLUGIN_MODULE = """
from shared.solvers import SolverSpec
from shared.solvers.params import SimulatedQPUParams

SPEC = SolverSpec(
    "named-by-the-entry-point",
    "shared.solvers.qpu.dwave:SimulatedQPUSolver",
    params=SimulatedQPUParams,
    meter="qpu",
    offline=True,
)
"""


def register_by_call(folder, monkeypatch) -> None:
    from shared.solvers.params import SimulatedQPUParams

    registry.register(
        PLUGIN, "shared.solvers.qpu.dwave:SimulatedQPUSolver", SimulatedQPUParams, meter="qpu"
    )


def register_by_entry_point(folder, monkeypatch) -> None:
    (folder / "lab_qpu_plugin.py").write_text(PLUGIN_MODULE)
    info = folder / "lab_qpu_plugin-0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: lab-qpu-plugin\nVersion: 0\n")
    (info / "entry_points.txt").write_text(f"[qhsm.solvers]\n{PLUGIN} = lab_qpu_plugin:SPEC\n")
    monkeypatch.syspath_prepend(folder)


class ReservationWatcher(FakeQPU):
    """The plugin's sampler: notes what its owner has reserved while each bundle is solved."""

    def __init__(self, ledger: QuotaLedger, owner: str) -> None:
        super().__init__()
        self.name = PLUGIN
        self.ledger, self.owner = ledger, owner
        self.reserved: list[float] = []

    def solve(self, bqm, **params):
        self.reserved.append(self.ledger.status(self.owner).reserved)
        return super().solve(bqm, **params)


@pytest.fixture(params=[register_by_call, register_by_entry_point], ids=["register", "entry-point"])
def plugin_config(request, tmp_path, monkeypatch, level) -> MatchConfig:
    """The level's job on a QPU-metered solver registered only now, long after
    ``shared.solvers.meters.qpu_time`` was imported (the registry is restored afterwards)."""
    monkeypatch.setattr(registry, "_SPECS", dict(registry._SPECS))
    request.param(tmp_path, monkeypatch)
    assert registry.spec(PLUGIN).meter == "qpu"
    _, config = level
    return MatchConfig.model_validate({**config.model_dump(), "solver": PLUGIN})


def test_a_metered_solver_registered_later_is_estimated_and_reserved(
    plugin_config, level, meter, monkeypatch
):
    inputs, builtin = level  # the same job on qpu-sim: the same meter and parameter schema
    assert qpu_time.meter_of(PLUGIN) == "qpu" and qpu_time.is_metered(PLUGIN)
    watcher = ReservationWatcher(meter.ledger, "ada")
    monkeypatch.setitem(registry._INSTANCES, PLUGIN, watcher)

    estimate = bundle_estimate(inputs, plugin_config, 0, 1, solver=resolve(plugin_config))
    assert estimate == bundle_estimate(inputs, builtin, 0, 1, solver=resolve(builtin)) > 0
    job = qpu_time.job_seconds(resolve(plugin_config), (16, 24), 6)
    assert job.seconds == qpu_time.job_seconds(resolve(builtin), (16, 24), 6).seconds > 0
    assert job.as_dict()["metered"] and job.levels[-1].qubits_per_bundle

    meter.ledger.set_limit("ada", 0.5 * estimate)
    with pytest.raises(QuotaExceededError, match="not enough QPU budget left for user 'ada'"):
        solve_metered(meter, "ada", "job", inputs, registry.resolve(plugin_config), [(0, 1)])
    assert watcher.calls == 0  # refused before it was sent: the bundle needs its estimate

    meter.ledger.set_limit("ada", 10 * estimate)
    watcher.seconds = lambda call: 0.25 * estimate
    solve_metered(meter, "ada", "job", inputs, registry.resolve(plugin_config), [(0, 1), (1, 2)])
    assert watcher.reserved == [pytest.approx(estimate)] * 2  # each held its estimate meanwhile
    usage = meter.ledger.job_usage("ada", "job")
    assert usage.problems == 2 and usage.seconds == pytest.approx(0.5 * estimate)
    assert meter.ledger.status("ada").reserved == 0.0


class FakeLeapBatch:
    """Stands in for ``hybrid``: the task's bundles as one batch, sending two D-Wave problems
    whose ids SAPI returns (what ``LabelledSampler`` logs), each charged 0.5 s."""

    name = "hybrid-sim"

    def __init__(self, ledger: QuotaLedger) -> None:
        self.ledger = ledger
        self.reserved: list[float] = []

    def solve_batch(self, problems: list[tuple], **params) -> list[SolveResult]:
        from shared.solvers.qpu.problems import current

        self.reserved.append(self.ledger.status("ada").reserved)
        log = current()
        if log is not None:
            log.ids.extend(["sapi-1", "sapi-2"])
        share = 1.0 / len(problems)
        return [
            SolveResult(
                sample=np.zeros(bqm.num_variables, dtype=np.int8),
                energy=float(bqm.offset),
                wall_time=0.0,
                timing={"charge_time": share},
            )
            for bqm, _, _ in problems
        ]


def test_a_level_reserves_what_its_accepted_estimate_said_and_keeps_its_problem_ids(
    level, meter, monkeypatch
):
    """The issue's case: the estimate said 3.0 s, the worker reserved 3.3 s (every variable of
    the level, as if nothing were solved on the host), and a user with 3.1 s left failed at
    once. Now a level reserves its share of the accepted estimate."""
    from shared.solvers.qpu.problems import sent_problems

    inputs, paper = level
    config = MatchConfig.model_validate({**paper.model_dump(), "solver": "hybrid-sim"})
    fake = FakeLeapBatch(meter.ledger)
    monkeypatch.setitem(registry._INSTANCES, "hybrid-sim", fake)
    bundles = [tuple(bundle.as_list()) for bundle in inputs.planned_bundles(config)]
    upper = qpu_time.batch_estimate(
        inputs, config, [inputs.as_bundle(b) for b in bundles], solver=resolve(config)
    )
    accepted = 3.0
    assert upper > accepted + 0.1
    meter.ledger.set_limit("ada", accepted + 0.1)
    with pytest.raises(QuotaExceededError):  # without the accepted estimate: the upper bound
        solve_metered(meter, "ada", "job", inputs, registry.resolve(config), bundles)
    with sent_problems("qhsm job job level 3 bundle 0") as log:
        solve_metered(
            meter, "ada", "job", inputs, registry.resolve(config), bundles, level_estimate=accepted
        )
    assert fake.reserved == [pytest.approx(accepted)]
    usage = meter.ledger.job_usage("ada", "job")
    assert usage.problem_ids == ("sapi-1", "sapi-2") == tuple(log.ids)
    assert usage.problems == 2 and usage.seconds == pytest.approx(1.0)
    [job] = meter.ledger.usage("ada").as_dict()["jobs"]
    assert job["problem_ids"] == ["sapi-1", "sapi-2"]
    half = bundles[: len(bundles) // 2]  # a task with half the level's bundles: half of it
    solve_metered(
        meter, "ada", "job", inputs, registry.resolve(config), half, level_estimate=accepted
    )
    assert fake.reserved[-1] == pytest.approx(accepted * len(half) / len(bundles))
