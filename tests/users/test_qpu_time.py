"""The QPU / hybrid time model: D-Wave's published formula and whole-job estimates."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.bundles import bundle_rows, segment_columns
from shared.config import MatchConfig
from shared.pyramid import level_shape, plan
from shared.solvers.meters import qpu_time
from shared.solvers.meters.qpu_time import ADVANTAGE_TIMING_DATA as DATA
from shared.solvers.qpu.embedding_cache import (
    DirectoryStore,
    EmbeddingCache,
    EmbeddingSize,
    structure_digest,
)
from shared.solvers.registry import resolve


def test_qpu_model_is_programming_plus_reads_times_sample_time():
    """One qubit: log10(1) = 0, so the readout time is 10**(first readout parameter) us."""
    readout = 10 ** DATA["readout_time_model_parameters"][6]
    programming = DATA["typical_programming_time"] + DATA["default_programming_thermalization"]
    per_read = DATA["default_annealing_time"] + readout + DATA["qpu_delay_time_per_sample"]
    expected = (programming + 100 * per_read) * 1e-6
    assert qpu_time.qpu_access_seconds(1, {"num_reads": 100}) == pytest.approx(expected)
    longer = qpu_time.qpu_access_seconds(1, {"num_reads": 100, "annealing_time": 120.0})
    assert longer - expected == pytest.approx(100 * 100.0 * 1e-6)


@settings(max_examples=40, deadline=None)
@given(
    qubits=st.integers(1, qpu_time.MAX_QUBITS - 1),
    reads=st.integers(1, 2000),
    more_qubits=st.integers(1, 1000),
    more_reads=st.integers(1, 500),
)
def test_qpu_estimate_grows_with_qubits_and_reads(qubits, reads, more_qubits, more_reads):
    base = qpu_time.qpu_access_seconds(qubits, {"num_reads": reads})
    assert qpu_time.qpu_access_seconds(qubits + more_qubits, {"num_reads": reads}) >= base
    assert qpu_time.qpu_access_seconds(qubits, {"num_reads": reads + more_reads}) > base


def test_default_reads_match_the_qpu_adapter():
    """Without ``num_reads`` the estimate counts the reads the QPU adapter samples with (its
    defaults), and the reads do count."""
    from shared.solvers.registry import get_solver

    reads = get_solver("qpu").defaults["num_reads"]
    default = qpu_time.bundle_seconds("qpu", 100)
    assert default == qpu_time.bundle_seconds("qpu", 100, {"num_reads": reads})
    assert default < qpu_time.bundle_seconds("qpu", 100, {"num_reads": reads + 1})


def test_a_live_solver_replaces_the_offline_model():
    class LiveSolver:
        def estimate_qpu_access_time(self, num_qubits, num_reads=1, **params):
            return 1000.0 * num_qubits + num_reads

    estimate = qpu_time.bundle_seconds(
        "qpu", 10, {"num_reads": 7}, num_qubits=30, solver=LiveSolver()
    )
    assert estimate == pytest.approx((30_000 + 7) * 1e-6)


def test_hybrid_charge_is_the_time_limit_never_below_the_minimum():
    assert qpu_time.hybrid_charge_seconds(500) == 3.0
    assert qpu_time.hybrid_charge_seconds(2560) == pytest.approx(6.5)  # halfway 1024..4096
    assert qpu_time.hybrid_charge_seconds(500, {"time_limit": 20}) == 20.0
    assert qpu_time.hybrid_charge_seconds(500, {"time_limit": 1}) == 3.0


def test_charged_seconds_prefers_the_hybrid_charge_time():
    assert qpu_time.charged_seconds({"qpu_access_time": 0.01}) == 0.01
    assert qpu_time.charged_seconds({"qpu_access_time": 0.04, "charge_time": 3.0}) == 3.0
    assert qpu_time.charged_seconds({"run_time": 5.0}) == 0.0


@pytest.mark.parametrize("preset", ["accurate", "paper"])
@pytest.mark.parametrize("encoding", ["one-hot", "domain-wall"])
def test_job_estimate_counts_every_bundle_of_every_level(encoding, preset):
    # whole rows (a width beyond the row's; qpu-sim's default is --bundle-width auto), every
    # tile sent (not the residual design's 4x4 tiles: tests/core/test_tile_certificate.py)
    config = MatchConfig(solver="qpu-sim", encoding=encoding, bundle_height=2, preset=preset,
                         bundle_width=4096, solver_params={"num_reads": 10},
                         warm_start=False, certify_tiles=False)  # fmt: skip
    estimate = qpu_time.job_seconds(resolve(config), (37, 50), 20)
    per_pixel = {"one-hot": 0, "domain-wall": -1}[encoding]
    views = 2 if preset == "accurate" else 1  # the right view's bundles too
    plans = plan(config, 20)
    assert len(estimate.levels) == len(plans) == 3  # paper: 1/4, 1/2, 1; bins of 4, 2, 1 px
    for level, got in zip(plans, estimate.levels, strict=True):
        height, width = level_shape((37, 50), level.downsample)
        assert got.bundles == views * len(bundle_rows(height, 2))
        assert got.variables_per_bundle == 2 * width * (level.candidates + per_pixel)
        each = qpu_time.bundle_seconds("qpu-sim", got.variables_per_bundle, {"num_reads": 10})
        assert got.seconds == pytest.approx(each * got.bundles)  # one call each: no copies known
    assert estimate.bundles == sum(level.bundles for level in estimate.levels)
    assert estimate.seconds == pytest.approx(sum(level.seconds for level in estimate.levels))


def test_job_estimate_counts_row_segments(tmp_path):
    """Segments multiply the bundles and shrink them; auto uses the width a run chose."""
    config = MatchConfig(
        solver="qpu-sim", inference="rows", bundle_width=24, bundle_margin=6, lr_check=False
    )
    got = qpu_time.job_seconds(resolve(config), (10, 50), 20).levels[-1]
    assert got.bundles == 10 * len(segment_columns(50, 24, 6)) == 10 * 3
    assert got.variables_per_bundle == 24 * (got_labels(config) - 1)

    cache = EmbeddingCache(DirectoryStore(tmp_path))
    auto = MatchConfig(solver="qpu-sim", inference="rows", lr_check=False, bundle_margin=6)
    labels = got_labels(auto)
    key = qpu_time.auto_width_key("qpu-sim", "domain-wall", 1, labels, 50, 6)
    cache.record_width(key, 30)
    level = qpu_time.job_seconds(resolve(auto), (10, 50), 20, cache).levels[-1]
    assert level.bundles == 10 * len(segment_columns(50, 30, 6))
    cache.record_width(key, None)  # whole rows embed
    assert qpu_time.job_seconds(resolve(auto), (10, 50), 20, cache).levels[-1].bundles == 10


def got_labels(config: MatchConfig) -> int:
    return plan(config, 20)[-1].candidates


def test_unmetered_solvers_cost_nothing():
    assert qpu_time.job_seconds(resolve(MatchConfig(solver="sa")), (40, 60), 16).seconds == 0.0
    assert not qpu_time.is_metered("exact") and qpu_time.is_metered("hybrid-sim")


def test_warm_started_levels_are_estimated_as_reverse_anneals():
    cold = MatchConfig(solver="qpu", solver_params={"num_reads": 100, "warm_start": False})
    warm = MatchConfig(solver="qpu", solver_params={"num_reads": 100, "warm_start": True})
    cold_levels = qpu_time.job_seconds(resolve(cold), (60, 80), 16).levels
    warm_levels = qpu_time.job_seconds(resolve(warm), (60, 80), 16).levels
    # every level is warm: the coarsest starts from the data term's winner-takes-all
    for cold_level, warm_level in zip(cold_levels, warm_levels, strict=True):
        assert warm_level.seconds != cold_level.seconds
        assert warm_level.seconds == pytest.approx(cold_level.seconds, rel=0.2)


class KnownSizes:
    """An embedding cache that knows the sizes of some bundle structures."""

    def __init__(self, sizes: dict[tuple[str, str], EmbeddingSize]) -> None:
        self.sizes = sizes

    def known_size(self, solver: str, digest: str) -> EmbeddingSize | None:
        return self.sizes.get((solver, digest))


@settings(max_examples=25, deadline=None)
@given(
    encoding=st.sampled_from(["one-hot", "domain-wall"]),
    height=st.integers(1, 3),
    width=st.integers(1, 9),
    labels=st.integers(2, 5),
    seed=st.integers(0, 50),
)
def test_a_bundle_shape_has_the_structure_of_every_bundle_of_that_shape(
    encoding, height, width, labels, seed
):
    """The estimate finds a bundle's embedding from its shape alone: the QUBO graph of real
    costs (any biases, zeros included) is the graph of the zero-cost bundle."""
    import numpy as np

    from shared.encodings import get_codec
    from shared.energy import Costs

    rng = np.random.default_rng(seed)
    costs = Costs(
        candidates=rng.integers(0, 9, (height, width, labels)).astype(np.int32),
        unary=rng.random((height, width, labels)) * (rng.random() < 0.8),
        pair_h=rng.random((height, width - 1, labels, labels)).round(1),
        pair_v=rng.random((height - 1, width, labels, labels)).round(1),
    )
    bqm = get_codec(encoding).encode(costs)
    digest = qpu_time.bundle_digest(encoding, height, width, labels)
    assert digest == structure_digest(bqm)


def test_known_embeddings_replace_the_assumed_qubits_level_by_level():
    config = MatchConfig(solver="qpu", encoding="domain-wall", preset="paper",
                         solver_params={"num_reads": 100})  # fmt: skip
    shape = (40, 64)
    assumed = qpu_time.job_seconds(resolve(config), shape, 16)
    assert all(not level.embedding_known for level in assumed.levels)
    finest = assumed.levels[-1]
    digest = qpu_time.bundle_digest("domain-wall", 1, finest.shape[1], 4)
    size = EmbeddingSize(qubits=150, chains=finest.variables_per_bundle, longest_chain=3)
    known = qpu_time.job_seconds(resolve(config), shape, 16, KnownSizes({("qpu", digest): size}))
    assert [level.embedding_known for level in known.levels] == [False, False, True]
    assert known.levels[:2] == assumed.levels[:2]
    assert known.levels[-1].qubits_per_bundle == 150
    each = qpu_time.qpu_access_seconds(150, {"num_reads": 100})
    assert known.levels[-1].seconds == pytest.approx(each * finest.bundles)
    # another solver's embedding of the same structure is not used
    other = qpu_time.job_seconds(
        resolve(config), shape, 16, KnownSizes({("qpu-sim", digest): size})
    )
    assert other == assumed


def test_an_unreachable_embedding_store_falls_back_to_the_assumption():
    class Broken:
        def known_size(self, solver, digest):
            raise ConnectionError("store down")

    config = MatchConfig(solver="qpu-sim")
    assert qpu_time.job_seconds(resolve(config), (20, 30), 16, Broken()) == qpu_time.job_seconds(
        resolve(config), (20, 30), 16
    )


def test_bundles_larger_than_the_qpu_are_never_looked_up():
    """No embedding can exist, and their QUBO (here 64 x 2000 pixels x 64 labels) is not built."""

    class Counting(KnownSizes):
        calls = 0

        def known_size(self, solver, digest):
            Counting.calls += 1
            return None

    assert qpu_time.known_embedding(Counting({}), "qpu", "one-hot", (64, 2000), 64) is None
    assert Counting.calls == 0
    assert qpu_time.known_embedding(Counting({}), "qpu", "one-hot", (1, 20), 4) is None
    assert Counting.calls == 1
