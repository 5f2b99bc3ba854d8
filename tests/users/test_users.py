"""Users, API keys and the authentication dependencies; the ``qhsm admin`` command."""

from __future__ import annotations

import json
from datetime import UTC, datetime
from typing import Annotated

import pytest
from fastapi import Depends, FastAPI
from fastapi.testclient import TestClient

from api.users import User, UserError, UserStore, admin_user, current_user, key_digest
from shared.cli import main


@pytest.fixture
def store(redis_client, prefix) -> UserStore:
    return UserStore(redis_client, prefix, default_qpu_seconds=42.0)


@pytest.fixture
def client(store) -> TestClient:
    app = FastAPI()
    app.state.users = store

    @app.get("/me")
    def me(user: Annotated[User, Depends(current_user)]) -> dict:
        return {"name": user.name, "admin": user.admin}

    @app.get("/admin-only")
    def admin_only(user: Annotated[User, Depends(admin_user)]) -> dict:
        return {"name": user.name}

    return TestClient(app)


def test_keys_are_stored_only_as_hashes(store, redis_client, prefix, redis_values):
    user, key = store.create_user("ada", qpu_seconds=5)
    assert key.startswith(f"qhsm_{user.key_id}_") and len(key) > 50
    stored = redis_values(redis_client, f"{prefix}:*")
    assert key.encode() not in stored
    assert key_digest(key).encode() in stored
    assert "key" not in json.dumps(user.model_dump(mode="json")).replace("key_", "")
    assert store.ledger.status("ada").limit == 5.0


def test_authenticate_accepts_only_the_current_key(store):
    _, key = store.create_user("ada")
    assert store.authenticate(key).name == "ada"
    assert store.authenticate(f"  {key}\n").name == "ada"
    assert store.authenticate(key[:-1] + ("A" if key[-1] != "A" else "B")) is None
    assert store.authenticate("qhsm_00000000_" + "x" * 43) is None
    assert store.authenticate("not a key") is None
    new = store.rotate_key("ada")
    assert store.authenticate(key) is None and store.authenticate(new).name == "ada"
    store.revoke("ada")
    assert store.authenticate(new) is None
    assert store.get("ada").revoked
    again = store.rotate_key("ada")  # a new key brings a revoked user back
    assert store.authenticate(again).name == "ada" and not store.get("ada").revoked


def test_user_management_errors_are_clear(store):
    store.create_user("ada")
    with pytest.raises(UserError, match="exists already"):
        store.create_user("ada")
    with pytest.raises(UserError, match="invalid user name"):
        store.create_user("ada:evil")
    with pytest.raises(UserError, match="no user 'bob'"):
        store.rotate_key("bob")
    assert [u.name for u in store.list_users()] == ["ada"]
    assert store.ledger.status("ada").limit == 42.0  # the default budget
    store.create_user("root", admin=True, qpu_seconds=None)
    assert store.ledger.status("root").limit is None


def test_bearer_dependency_gives_401_403_and_the_user(store, client):
    _, key = store.create_user("ada")
    _, root = store.create_user("root", admin=True)

    missing = client.get("/me")
    assert missing.status_code == 401
    assert missing.headers["www-authenticate"].startswith("Bearer")
    assert "Authorization: Bearer" in missing.json()["detail"]
    wrong = client.get("/me", headers={"Authorization": f"Bearer {key}x"})
    assert wrong.status_code == 401 and 'error="invalid_token"' in wrong.headers["www-authenticate"]
    basic = client.get("/me", headers={"Authorization": "Basic YWRhOnB3"})
    assert basic.status_code == 401

    assert client.get("/me", headers={"Authorization": f"Bearer {key}"}).json() == {
        "name": "ada",
        "admin": False,
    }
    assert client.get("/admin-only", headers={"Authorization": f"Bearer {key}"}).status_code == 403
    assert client.get("/admin-only", headers={"Authorization": f"Bearer {root}"}).status_code == 200
    store.revoke("ada")
    assert client.get("/me", headers={"Authorization": f"Bearer {key}"}).status_code == 401


def test_auth_disabled_makes_everyone_the_local_admin(store, client):
    store.auth_enabled = False
    assert client.get("/admin-only").json() == {"name": "local"}


def test_admin_cli_round_trip(redis_url, redis_client, prefix, monkeypatch, capsys):
    monkeypatch.setenv("QHSM_REDIS_URL", redis_url)
    monkeypatch.setenv("QHSM_KEY_PREFIX", prefix)
    monkeypatch.setenv("QHSM_DEFAULT_QPU_SECONDS", "9")

    assert main(["admin", "create-user", "ada", "--qpu-seconds", "2.5"]) == 0
    key = capsys.readouterr().out.strip()
    store = UserStore(redis_client, prefix)
    assert store.authenticate(key).name == "ada"
    assert main(["admin", "create-user", "root", "--admin"]) == 0
    capsys.readouterr()
    assert main(["admin", "create-user", "ada"]) == 1
    assert "exists already" in capsys.readouterr().err

    assert main(["admin", "set-quota", "ada", "7"]) == 0
    assert main(["admin", "rotate-key", "ada"]) == 0
    new_key = capsys.readouterr().out.strip().splitlines()[-1]
    assert store.authenticate(key) is None and store.authenticate(new_key).name == "ada"
    assert main(["admin", "revoke", "ada"]) == 0
    capsys.readouterr()

    assert main(["admin", "list-users", "--json"]) == 0
    rows = {row["name"]: row for row in json.loads(capsys.readouterr().out)}
    assert rows["ada"]["limit_seconds"] == 7.0 and rows["ada"]["revoked"]
    assert rows["root"]["admin"] and rows["root"]["limit_seconds"] == 9.0
    assert new_key not in json.dumps(rows) and "key_hash" not in json.dumps(rows)

    reservation = store.ledger.reserve("ada", "job1", 1.0, ttl=60)
    store.ledger.settle(reservation, 0.5)
    assert main(["admin", "usage", "ada", "--json"]) == 0
    [usage] = json.loads(capsys.readouterr().out)
    assert usage["used_seconds"] == 0.5 and usage["remaining_seconds"] == 6.5
    [job] = usage["jobs"]
    charged = datetime.fromisoformat(job.pop("last_charged_at"))
    assert job.pop("first_charged_at") == charged.isoformat()
    assert abs((datetime.now(UTC) - charged).total_seconds()) < 60  # Redis's clock is this one's
    assert job == {"id": "job1", "qpu_seconds": 0.5, "problems": 1, "problem_ids": []}
    assert usage["warning"] is None  # 6.5 of 7 s left
    assert main(["admin", "usage"]) == 0
    assert "ada: used 0.500 s of 7 s" in capsys.readouterr().out
    assert main(["admin", "set-quota", "ada", "7", "--period", "weekly"]) == 0
    assert "used 0.500 s this week (weekly budget, resets at" in capsys.readouterr().out
    assert main(["admin", "usage", "ada"]) == 0
    assert "weekly since" in capsys.readouterr().out
    assert main(["admin", "set-quota", "ada", "7", "--period", "default"]) == 0
    assert "lifetime budget, never resets" in capsys.readouterr().out
    assert main(["admin", "set-quota", "bob", "1"]) == 1
    for infinite in ("1e400", "nan"):  # "unlimited" says it; an overflow does not
        with pytest.raises(SystemExit):
            main(["admin", "set-quota", "ada", infinite])
        assert "finite" in capsys.readouterr().err


def test_usage_route_shows_own_usage_and_admins_everyones(store):
    from api.routes import usage

    app = FastAPI()
    app.state.users = store
    app.include_router(usage.router, prefix="/v1")
    client = TestClient(app)
    _, ada = store.create_user("ada", qpu_seconds=3)
    _, bob = store.create_user("bob", qpu_seconds=4)
    _, root = store.create_user("root", admin=True)
    for name, job, seconds in [("ada", "j1", 0.5), ("ada", "j2", 0.25), ("bob", "j3", 1.0)]:
        store.ledger.settle(store.ledger.reserve(name, job, 1.0, ttl=60), seconds)

    assert client.get("/v1/usage").status_code == 401
    mine = client.get("/v1/usage", headers={"Authorization": f"Bearer {ada}"}).json()
    assert [entry["user"] for entry in mine["users"]] == ["ada"]
    [entry] = mine["users"]
    assert entry["used_seconds"] == 0.75 and entry["remaining_seconds"] == 2.25
    assert {job["id"]: job["qpu_seconds"] for job in entry["jobs"]} == {"j1": 0.5, "j2": 0.25}
    assert mine["qpu_in_flight"] is None
    other = client.get(
        "/v1/usage", params={"user": "bob"}, headers={"Authorization": f"Bearer {ada}"}
    )
    assert other.status_code == 403

    everyone = client.get("/v1/usage", headers={"Authorization": f"Bearer {root}"}).json()
    assert [entry["user"] for entry in everyone["users"]] == ["ada", "bob", "root"]
    assert everyone["total_used_seconds"] == 1.75 and everyone["qpu_in_flight"] == 0
    only_bob = client.get(
        "/v1/usage", params={"user": "bob"}, headers={"Authorization": f"Bearer {root}"}
    ).json()
    assert [entry["user"] for entry in only_bob["users"]] == ["bob"]
    assert bob not in str(everyone) and ada not in str(everyone)


def test_usage_has_dates_a_csv_export_and_warns_when_the_budget_runs_low(
    store, redis_url, prefix, monkeypatch, capsys
):
    import csv
    import io

    from api.routes import usage

    app = FastAPI()
    app.state.users = store
    app.include_router(usage.router, prefix="/v1")
    client = TestClient(app)
    _, ada = store.create_user("ada", qpu_seconds=10)
    headers = {"Authorization": f"Bearer {ada}"}
    first = store.ledger.settle(store.ledger.reserve("ada", "j1", 1.0, ttl=60), 0.5)
    assert first == 0.5
    [entry] = client.get("/v1/usage", headers=headers).json()["users"]
    assert entry["warning"] is None
    store.ledger.settle(store.ledger.reserve("ada", "j1", 1.0, ttl=60), 0.5)
    store.ledger.settle(store.ledger.reserve("ada", "j2", 9.0, ttl=60), 8.25)  # 0.75 s left
    [entry] = client.get("/v1/usage", headers=headers).json()["users"]
    assert "runs low: 0.750 s of 10 s left (7.5 %)" in entry["warning"]
    j1 = next(job for job in entry["jobs"] if job["id"] == "j1")
    assert j1["first_charged_at"] <= j1["last_charged_at"] and j1["problems"] == 2

    answer = client.get("/v1/usage", params={"format": "csv"}, headers=headers)
    assert answer.status_code == 200 and answer.headers["content-type"].startswith("text/csv")
    rows = list(csv.DictReader(io.StringIO(answer.text)))
    assert [(row["user"], row["job"], float(row["qpu_seconds"])) for row in rows] == [
        ("ada", "j1", 1.0),
        ("ada", "j2", 8.25),
    ]
    assert rows[0]["last_charged_at"] == j1["last_charged_at"].replace("Z", "+00:00")
    assert client.get("/v1/usage", params={"format": "xml"}, headers=headers).status_code == 422

    monkeypatch.setenv("QHSM_REDIS_URL", redis_url)
    monkeypatch.setenv("QHSM_KEY_PREFIX", prefix)
    assert main(["admin", "usage", "ada", "--csv"]) == 0
    assert capsys.readouterr().out == answer.text
    assert main(["admin", "usage", "ada"]) == 0
    assert "warning: QPU budget of user 'ada' runs low" in capsys.readouterr().out
