"""A sampler's settings (issue 30): handed over, they win over the environment, and the adapter
passes their values on (the token to Leap, the endpoint into its error messages)."""

from __future__ import annotations

from shared.config import Settings
from shared.solvers.qpu.dwave import QPUSolver


def test_an_adapter_reads_the_settings_it_was_handed(monkeypatch):
    monkeypatch.setenv("DWAVE_API_TOKEN", "from-the-environment")
    solver = QPUSolver()
    assert solver.available().ok  # none handed: the environment's, read when asked
    solver.settings = Settings().model_copy(update={"dwave_api_token": None})
    assert not solver.available().ok and "DWAVE_API_TOKEN" in solver.available().reason
    solver.settings = None
    assert solver.available().ok


def test_its_errors_name_the_endpoint_of_its_settings(monkeypatch):
    monkeypatch.setenv("DWAVE_API_ENDPOINT", "http://from-the-environment/sapi/v2/")
    solver = QPUSolver()
    solver.settings = Settings().model_copy(
        update={"dwave_endpoint": "http://handed-over/sapi/v2/"}
    )
    error = solver.translate(ConnectionError("refused"))
    assert "http://handed-over/sapi/v2/" in str(error) and "from-the-environment" not in str(error)
