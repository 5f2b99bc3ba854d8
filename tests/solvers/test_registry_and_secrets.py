"""The registry lists every solver with a useful reason; the D-Wave token never leaks."""

from __future__ import annotations

import json
import logging
from typing import ClassVar

import numpy as np
import pytest
from dwave import graphs as dwave_graphs
from dwave.cloud import exceptions as cloud
from solver_helpers import stereo_costs

from shared.cli import main
from shared.encodings import get_codec
from shared.solvers import SolverError, SolverUnavailableError
from shared.solvers.qpu.embedding_cache import DirectoryStore, EmbeddingCache
from shared.solvers.registry import get_solver, solver_names

SENTINEL = "SENTINEL-TOKEN-7f3a9c"
EXPECTED = {
    "exact",
    "sa",
    "tabu",
    "steepest-descent",
    "gurobi",
    "qpu",
    "qpu-sim",
    "hybrid",
    "hybrid-sim",
}


def test_cli_lists_every_solver_with_availability(capsys):
    assert set(solver_names()) >= EXPECTED
    assert main(["solvers", "--json"]) == 0
    rows = {row["name"]: row for row in json.loads(capsys.readouterr().out)}
    assert rows["qpu"]["available"] is False and "set DWAVE_API_TOKEN" in rows["qpu"]["reason"]
    assert rows["hybrid"]["available"] is False
    for name in ("qpu-sim", "hybrid-sim"):
        assert rows[name]["available"] and rows[name]["offline"]
        assert rows[name]["reason"].startswith("offline simulator")
    assert "size-limited pip licence" in rows["gurobi"]["reason"]
    assert rows["sa"]["available"] and not rows["sa"]["offline"]


def test_match_with_an_unavailable_solver_fails_with_the_reason(tmp_path, capsys):
    code = main(
        ["match", "left.png", "right.png", "-o", str(tmp_path / "d.pfm"), "--solver", "qpu"]
    )
    assert code == 1
    assert "solver qpu is not available" in capsys.readouterr().err


def test_token_configured_is_reported(monkeypatch):
    monkeypatch.setenv("DWAVE_API_TOKEN", SENTINEL)
    for name in ("qpu", "hybrid"):
        availability = get_solver(name).available()
        assert availability.ok and availability.reason == "DWAVE_API_TOKEN configured"
        assert SENTINEL not in availability.reason


class LeakyDWaveSampler:
    """Stands in for DWaveSampler: records the token and fails with it in the message, as a
    careless library might."""

    tokens: ClassVar[list[str]] = []

    def __init__(self, token=None, **options):
        self.tokens.append(token)
        raise cloud.SolverAuthenticationError(f"token {token} rejected by {options}")


def test_sentinel_token_never_appears_in_errors_logs_or_results(monkeypatch, caplog, tmp_path):
    import dwave.system

    monkeypatch.setenv("DWAVE_API_TOKEN", SENTINEL)
    monkeypatch.setattr(dwave.system, "DWaveSampler", LeakyDWaveSampler)
    caplog.set_level(logging.DEBUG)
    bqm = get_codec("domain-wall").encode(stereo_costs(1, 4))

    with pytest.raises(SolverUnavailableError) as caught:
        get_solver("qpu").solve(bqm, seed=0, preprocess="none")
    assert LeakyDWaveSampler.tokens[-1] == SENTINEL  # the token did reach the sampler
    assert "DWAVE_API_TOKEN" in str(caught.value)

    # Errors that carry the library's text are scrubbed too.
    qpu = get_solver("qpu")
    for error in (cloud.SolverFailureError(f"bad {SENTINEL}"), ValueError(SENTINEL)):
        translated = qpu.translate(error)
        assert isinstance(translated, SolverError)
        assert SENTINEL not in str(translated) and "***" in str(translated)

    # A successful run on the same code path (the simulator) carries no token either.
    sim = get_solver("qpu-sim")
    result = sim.solve(bqm, seed=0, num_reads=10)
    for text in (
        str(caught.value),
        caplog.text,
        repr(result.info),
        repr(result.timing),
        np.array2string(result.sample),
    ):
        assert SENTINEL not in text


def test_redis_embedding_store_round_trip(redis_store):
    client, store = redis_store
    assert store.get("missing") is None and store.generation() == 0
    cache = EmbeddingCache(store)
    bqm = get_codec("domain-wall").encode(stereo_costs(1, 3))
    target = list(dwave_graphs.chimera_graph(2).edges)
    embedding, source, key = cache.lookup(bqm, target, "chimera2", timeout=5)
    assert source == "computed" and client.exists(store.prefix + key)
    assert store.generation() == 1  # what the estimates' cache is keyed by
    again, source, _ = EmbeddingCache(store).lookup(bqm, target, "chimera2", timeout=5)
    assert source == "store" and again == embedding


def test_directory_store_ignores_partial_writes(tmp_path):
    store = DirectoryStore(tmp_path)
    store.set("k", '{"0": [1, 2]}')
    assert store.get("k") == '{"0": [1, 2]}'
    assert not list(tmp_path.glob("*.tmp"))
