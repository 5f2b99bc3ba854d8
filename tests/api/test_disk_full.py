"""A full data disk (issue 20, item 4): the API and an embedded Redis on a 4 MiB tmpfs that is
then filled. Every endpoint that writes answers 507 with ``Retry-After`` and a message, never a
500, and a refused upload leaves no folder behind. Skipped where tmpfs cannot be mounted (not
root, or no CAP_SYS_ADMIN)."""

from __future__ import annotations

import contextlib
import json
import subprocess
from pathlib import Path

import harness
import pytest
import redis

from api.users import UserStore
from shared.config import Settings
from shared.synthetic import make_scene
from workers.embedded_redis import EmbeddedRedis

SIZE = "4m"
VIEW = harness.png(make_scene(24, 32).left)


@pytest.fixture
def full_disk(tmp_path):
    """A mounted tmpfs (unmounted afterwards) that the test fills with ``fill()``."""
    mount = tmp_path / "disk"
    mount.mkdir()
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={SIZE}", "tmpfs", str(mount)],
        capture_output=True,
        text=True,
    )
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


def fill(folder: Path) -> None:
    """Write until the disk is full."""
    with (folder / "filler").open("ab") as out, contextlib.suppress(OSError):
        while True:
            out.write(b"\0" * 65536)
            out.flush()


def redis_full(server: EmbeddedRedis, timeout: float = 10.0) -> None:
    """Write until Redis has noticed that its append-only file cannot grow (it then refuses
    every write with MISCONF)."""
    import time

    import redis

    client = redis.Redis.from_url(server.url)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            client.set("probe", "x" * 65536)
        except redis.ResponseError as error:
            assert str(error).startswith("MISCONF"), error
            return
        time.sleep(0.1)
    raise AssertionError("Redis kept accepting writes on a full disk")


def test_every_writing_endpoint_answers_507_on_a_full_disk(full_disk):
    server = EmbeddedRedis(full_disk / "redis").start()
    try:
        settings = Settings(
            redis_url=server.url,
            key_prefix=harness.unique_prefix(),
            data_dir=full_disk / "data",
            inspect_timeout=0.3,
        )
        _, key = UserStore.from_settings(settings).create_user("full", admin=True, qpu_seconds=None)
        files = {"left": ("l.png", VIEW), "right": ("r.png", VIEW)}
        fill(full_disk)
        redis_full(server)
        with harness.api_client(settings, key) as client:
            answers = {
                "submit": client.post(
                    "/v1/jobs", files=files, data={"params": json.dumps({"solver": "exact"})}
                ),
                "create user": client.post("/v1/users", json={"name": "later"}),
                "set quota": client.put("/v1/users/full/quota", json={"qpu_seconds": 3}),
            }
            for what, response in answers.items():
                assert response.status_code == 507, (what, response.text)
                assert response.headers["retry-after"], what
                assert "out of storage" in response.json()["detail"], what
            assert client.get("/v1/usage").status_code in (200, 507)  # reads work if they can
            assert client.get("/v1/jobs").status_code == 200
        uploads = redis.Redis.from_url(server.url).keys(f"{settings.key_prefix}:job:*")
        assert uploads == []  # no partial upload left
    finally:
        server.stop()


def test_a_submit_cut_short_by_a_full_redis_leaves_nothing_behind(api_settings, monkeypatch):
    """Redis fills between the uploads and the record (they are written to Redis, not to
    disk): 507, and neither the uploads nor a record remain."""
    from workers import store as store_module

    original = store_module.JobStore.__init__
    refused = []

    def init(self, client, settings):
        original(self, client, settings)

        def create(**_):
            refused.append(True)
            raise redis.ResponseError("MISCONF Errors writing to the AOF file: No space left")

        self._create = create

    monkeypatch.setattr(store_module.JobStore, "__init__", init)
    users = UserStore.from_settings(api_settings)
    _, key = users.create_user(f"spill-{harness.unique_prefix()[-6:]}")
    with harness.api_client(api_settings, key) as client:
        before = set(users.redis.scan_iter(match=f"{api_settings.key_prefix}:job:*:upload"))
        response = client.post(
            "/v1/jobs", files={"left": ("l.png", VIEW), "right": ("r.png", VIEW)}
        )
        assert response.status_code == 507, response.text
        assert client.get("/v1/jobs").json()["total"] == 0
    assert refused  # the uploads had been written when Redis refused the record
    after = set(users.redis.scan_iter(match=f"{api_settings.key_prefix}:job:*:upload"))
    assert after == before


def misconf() -> Exception:
    """What kombu raises when Redis refuses to store a task message on a full disk: its own
    ``ChannelError`` raised from Redis's MISCONF (a 500 before issue 29)."""
    from kombu.exceptions import ChannelError

    try:
        raise redis.ResponseError("MISCONF Errors writing to the AOF file: No space left")
    except redis.ResponseError as cause:
        try:
            raise ChannelError(str(cause)) from cause
        except ChannelError as error:
            return error


def test_a_submit_whose_start_cannot_be_sent_is_507_and_never_runs_later(api_settings, monkeypatch):
    """Redis takes the record but not the start's message (a full disk), and the removal of the
    record fails too: 507, and the watchdog fails the orphan instead of starting it, so the
    client's retry is the only run (a retried submit ran twice before)."""
    from workers import store as store_module
    from workers.records import JobState
    from workers.store import JobStore
    from workers.watchdog import Watchdog

    users = UserStore.from_settings(api_settings)
    _, key = users.create_user(f"orphan-{harness.unique_prefix()[-6:]}")
    monkeypatch.setattr(
        store_module.JobStore, "discard", lambda self, job_id: (_ for _ in ()).throw(misconf())
    )
    with harness.api_client(api_settings, key) as client:
        celery = client.app.state.services.celery
        monkeypatch.setattr(celery, "send_task", lambda *a, **k: (_ for _ in ()).throw(misconf()))
        response = client.post(
            "/v1/jobs", files={"left": ("l.png", VIEW), "right": ("r.png", VIEW)}
        )
        assert response.status_code == 507, response.text
        assert "out of storage (Redis cannot write)" in response.json()["detail"]
        [orphan] = client.get("/v1/jobs").json()["items"]
    store = JobStore.from_settings(api_settings)
    assert store.get(orphan["id"]).dispatched is False

    sent = []
    clock = iter(range(0, 10_000, int(api_settings.watchdog_lost_seconds) + 1))
    watchdog = Watchdog(celery, store, "test", clock=lambda: next(clock))
    monkeypatch.setattr(celery, "send_task", lambda *a, **k: sent.append(a))
    actions = [action for _ in range(3) for job, action in watchdog.tick() if job == orphan["id"]]
    assert actions == ["abandoned"] and sent == []
    record = store.get(orphan["id"])
    assert record.state is JobState.FAILED and "submit it again" in record.error


def test_a_submit_whose_start_was_sent_is_marked_dispatched(api_settings):
    users = UserStore.from_settings(api_settings)
    _, key = users.create_user(f"sent-{harness.unique_prefix()[-6:]}")
    with harness.api_client(api_settings, key) as client:
        response = client.post(
            "/v1/jobs", files={"left": ("l.png", VIEW), "right": ("r.png", VIEW)}
        )
        assert response.status_code == 202, response.text
        store = client.app.state.services.store
        assert store.get(response.json()["id"]).dispatched is True
