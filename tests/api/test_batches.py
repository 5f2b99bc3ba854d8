"""POST /v1/batches and GET /v1/batches/{id} (issue 31): one job per pair under one batch id,
validated all or nothing, admission per pair, seen only by its owner and admins."""

from __future__ import annotations

import io
import json
import uuid

import harness
import pytest
from api_helpers import LEFT, RIGHT, SCENE
from hypothesis import given
from hypothesis import strategies as st

from api.users import UserStore

GT = harness.png(SCENE.disparity * 4)


def post_batch(client, count=2, left=None, right=None, headers=None, **data):
    left = left or [LEFT] * count
    right = right or [RIGHT] * count
    files = [("left", (f"l{i}.png", image)) for i, image in enumerate(left)]
    files += [("right", (f"r{i}.png", image)) for i, image in enumerate(right)]
    files += [("ground_truth", (f"gt{i}.png", gt)) for i, gt in enumerate(data.pop("gts", []))]
    form = {k: v if isinstance(v, str) else json.dumps(v) for k, v in data.items()}
    return client.post("/v1/batches", files=files, data=form, headers=headers or {})


def user_headers(api_settings, **budget) -> tuple[str, dict[str, str]]:
    name = f"batch-{uuid.uuid4().hex[:8]}"
    _, key = UserStore.from_settings(api_settings).create_user(name, **budget)
    return name, {"Authorization": f"Bearer {key}"}


def total_jobs(client, headers=None) -> int:
    return client.get("/v1/jobs", params={"limit": 100}, headers=headers or {}).json()["total"]


def test_a_batch_makes_one_job_per_pair_and_lists_them_with_its_progress(api):
    tag = f"t{uuid.uuid4().hex[:8]}"
    pairs = [{"name": "first", "ground_truth": 0, "gt_scale": 4}, {"max_disparity": 5}]
    created = post_batch(api, params={"max_disparity": 6}, pairs=pairs, gts=[GT], tags=f"{tag},lab")
    assert created.status_code == 202, created.text
    body = created.json()
    assert created.headers["location"] == f"/v1/batches/{body['id']}"
    assert len(body["jobs"]) == 2 and all(job["state"] == "queued" for job in body["jobs"])

    batch = api.get(f"/v1/batches/{body['id']}").json()
    assert [job["id"] for job in batch["jobs"]] == [job["id"] for job in body["jobs"]]
    assert [job["name"] for job in batch["jobs"]] == ["first", "l1.png"]
    assert batch["tags"] == ["lab", tag]
    assert batch["progress"] == {
        "total": 2, "by_state": {"queued": 2}, "finished": 0, "fraction": 0.0
    }  # fmt: skip
    first, second = (api.get(f"/v1/jobs/{job['id']}").json() for job in body["jobs"])
    assert first["batch"] == second["batch"] == body["id"]
    assert first["ground_truth"]["scale"] == 4 and second["ground_truth"] is None
    assert first["config"]["max_disparity"] == 6 and second["config"]["max_disparity"] == 5
    listed = api.get("/v1/jobs", params={"tag": tag}).json()
    assert {job["id"] for job in listed["items"]} == {job["id"] for job in body["jobs"]}

    api.delete(f"/v1/jobs/{body['jobs'][0]['id']}")  # cancelled: finished
    progress = api.get(f"/v1/batches/{body['id']}").json()["progress"]
    assert progress["by_state"] == {"cancelled": 1, "queued": 1} and progress["fraction"] == 0.5
    api.delete(f"/v1/jobs/{body['jobs'][1]['id']}")


@pytest.mark.parametrize(
    ("change", "status", "says"),
    [
        ({"right": [RIGHT, harness.png(SCENE.right[:, :20])]}, 422, "pair 1 (l1.png)"),
        ({"left": [LEFT, b"GIF89a not an image"]}, 415, "pair 1 (l1.png)"),
        ({"right": [RIGHT]}, 422, "2 left views but 1 right views"),
        ({"pairs": [{}]}, 422, "one object per pair (2)"),
        ({"pairs": [{}, {"ground_truth": 0}]}, 422, "pairs[1].ground_truth"),
        ({"pairs": [{}, {"colour": "red"}]}, 422, "pairs[1].colour"),
        ({"pairs": "[{"}, 400, "pairs: not JSON"),
        ({"params": {"solver": "quantum-magic"}}, 422, "pair 0 (l0.png): params"),
        ({"gts": [GT]}, 422, "ground_truth: 1 files for 2 pairs"),
    ],
    ids=[
        "sizes",
        "format",
        "count",
        "pairs-count",
        "gt-index",
        "pairs-field",
        "pairs-json",
        "solver",
        "gt-count",
    ],
)
def test_a_bad_pair_is_named_and_nothing_is_created(api, change, status, says):
    before = total_jobs(api)
    refused = post_batch(api, **change)
    assert refused.status_code == status, refused.text
    assert says in refused.json()["detail"]
    assert total_jobs(api) == before


def test_only_the_owner_and_admins_see_a_batch(api, api_settings):
    _, ada = user_headers(api_settings)
    _, bob = user_headers(api_settings)
    created = post_batch(api, headers=ada, params={"max_disparity": 6})
    assert created.status_code == 202, created.text
    url = created.headers["location"]
    assert api.get(url, headers=ada).status_code == 200
    assert api.get(url).status_code == 200  # the admin
    hidden = api.get(url, headers=bob)
    assert hidden.status_code == 404 and "no batch" in hidden.json()["detail"]
    assert api.get("/v1/batches/nope", headers=ada).status_code == 404
    for job in created.json()["jobs"]:
        api.delete(f"/v1/jobs/{job['id']}")


def test_the_active_job_cap_counts_the_whole_batch(make_client, api_settings):
    _, ada = user_headers(api_settings)
    with make_client(max_active_jobs_per_user=2) as client:
        refused = post_batch(client, count=3, headers=ada, params={"max_disparity": 6})
        assert refused.status_code == 429, refused.text
        assert "pair 2 (l2.png)" in refused.json()["detail"]
        assert total_jobs(client, ada) == 0
        created = post_batch(client, count=2, headers=ada, params={"max_disparity": 6})
        assert created.status_code == 202, created.text
        for job in created.json()["jobs"]:
            client.delete(f"/v1/jobs/{job['id']}", headers=ada)


def test_a_metered_batchs_jobs_are_priced_on_a_worker(api, api_settings):
    """Issue 29: the API never estimates; each metered pair's job is written `pricing` and its
    pricing worker checks its estimate against the budget (done here as the task does)."""
    from workers import pricing
    from workers.app import make_celery
    from workers.quota import QuotaExceededError, QuotaLedger
    from workers.store import JobStore

    params = {"solver": "qpu-sim", "max_disparity": 6}
    _, ada = user_headers(api_settings, qpu_seconds=0.001)
    created = post_batch(api, count=2, headers=ada, params=params)
    assert created.status_code == 202, created.text
    jobs = created.json()["jobs"]
    assert [job["state"] for job in jobs] == ["pricing", "pricing"]
    store = JobStore.from_settings(api_settings)
    ledger = QuotaLedger(store.redis, api_settings.key_prefix)
    celery = make_celery(api_settings, with_tasks=False)
    with pytest.raises(QuotaExceededError, match="not enough QPU budget left"):
        pricing.price_job(celery, store, ledger, jobs[0]["id"], None)
    for job in jobs:
        api.delete(f"/v1/jobs/{job['id']}", headers=ada)


def test_a_batch_above_its_pixel_bound_is_refused_at_the_pair_that_crosses_it(make_client):
    with make_client(max_batch_pixels=2 * 24 * 32) as client:
        before = total_jobs(client)
        refused = post_batch(client, count=3, params={"max_disparity": 6})
        assert refused.status_code == 413, refused.text
        detail = refused.json()["detail"]
        assert "pair 2 (l2.png)" in detail and "QHSM_MAX_BATCH_PIXELS=1536" in detail
        assert total_jobs(client) == before


def test_a_pair_that_loses_its_room_while_written_takes_the_batch_back(api, monkeypatch):
    """Another request took the last slot between admission and writing: the jobs written
    already are removed, the pair is named."""
    from api import job_service
    from workers.store import ActiveJobsCapError

    written = []
    write = job_service.write

    def racing(record, arrays, svc):
        if written:
            raise ActiveJobsCapError(record.owner, 8, 8)
        write(record, arrays, svc)
        written.append(record.id)

    monkeypatch.setattr(job_service, "write", racing)
    before = total_jobs(api)
    refused = post_batch(api, count=2, params={"max_disparity": 6})
    assert refused.status_code == 429, refused.text
    assert "pair 1 (l1.png)" in refused.json()["detail"]
    assert written and api.get(f"/v1/jobs/{written[0]}").status_code == 404
    assert total_jobs(api) == before


@given(
    pairs=st.integers(0, 6),
    rights=st.integers(0, 6),
    truths=st.integers(0, 6),
    limit=st.integers(1, 5),
)
def test_pair_specs_accept_exactly_the_uploads_that_pair_up(pairs, rights, truths, limit):
    """Without ``pairs``: as many right as left views, 1 to the limit, and a ground truth for
    every pair or none; each pair then gets its own file, in order."""
    from api.batch_service import BatchForm, pair_specs
    from api.errors import ServiceError

    upload = io.BytesIO()
    form = BatchForm([upload] * pairs, [upload] * rights, ground_truth=[upload] * truths)
    fits = pairs == rights and 1 <= pairs <= limit and truths in (0, pairs)
    try:
        specs = pair_specs(form, limit)
    except ServiceError as error:
        assert not fits, error.message
        assert error.status_code == 422
    else:
        assert fits
        expected = list(range(pairs)) if truths else [None] * pairs
        assert [spec.ground_truth for spec in specs] == expected
