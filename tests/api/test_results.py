"""A finished job's results beyond the disparity: the validity and confidence maps, depth and
point cloud from the cameras given at submit (the job is finished through the store: no worker
runs here)."""

from __future__ import annotations

import io
import uuid

import numpy as np
import pytest
from api_helpers import LEFT, RIGHT, SCENE, post

from api.users import UserStore
from tests.calibration import middlebury_calib
from workers.records import ACTIVE, JobRecord, JobState, now

CAMERAS = {"focal": 100.0, "baseline": 0.5, "doffs": 1.0}


def finish(api, job_id: str, maps: dict[str, np.ndarray]) -> np.ndarray:
    """Finish a queued job as a worker would, with its result and maps; the result."""
    store = api.app.state.services.store
    disparity = SCENE.disparity.astype(np.float32)
    assert store.transition(job_id, JobState.RUNNING, ACTIVE) is not None
    store.save_result(job_id, disparity, maps)
    assert store.apply(job_id, JobRecord.succeeded, now(), None, None, list(maps)).changed
    return disparity


def test_validity_and_confidence_maps_are_linked_and_served(api):
    job_id = post(api, params={"max_disparity": 6}).json()["id"]
    links = api.get(f"/v1/jobs/{job_id}").json()["links"]
    assert links["validity"] is None and links["confidence"] is None  # not finished
    assert api.get(f"/v1/jobs/{job_id}/validity.png").status_code == 409
    valid = np.zeros(SCENE.disparity.shape, bool)
    valid[:, 4:] = True
    confidence = np.where(valid, 0.75, 0.0).astype(np.float32)
    finish(api, job_id, {"validity": valid, "confidence": confidence})
    links = api.get(f"/v1/jobs/{job_id}").json()["links"]
    assert links["depth"] is None  # no cameras given
    png = api.get(links["validity"])
    assert png.status_code == 200 and png.headers["content-type"] == "image/png"
    import cv2

    image = cv2.imdecode(np.frombuffer(png.content, np.uint8), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(image == 255, valid)
    served = api.get(f"/v1/jobs/{job_id}/confidence", params={"format": "npy"})
    assert np.array_equal(np.load(io.BytesIO(served.content)), confidence)
    assert api.get(links["confidence"]).content.startswith(b"Pf")
    refused = api.get(f"/v1/jobs/{job_id}/depth")
    assert refused.status_code == 404 and "focal and baseline" in refused.json()["detail"]


def test_the_provenance_map_is_linked_served_and_counted(api):
    from shared import provenance_map as pm

    job_id = post(api, params={"max_disparity": 6}).json()["id"]
    status = api.get(f"/v1/jobs/{job_id}").json()
    assert status["links"]["provenance"] is None and status["provenance_counts"] is None
    assert api.get(f"/v1/jobs/{job_id}/provenance").status_code == 409  # not finished
    stages = np.zeros(SCENE.disparity.shape, np.uint8)
    stages[:, 4:] = pm.Stage.CERTIFIED
    stages[2, 5] = pm.Stage.SOLVER
    store = api.app.state.services.store
    assert store.transition(job_id, JobState.RUNNING, ACTIVE) is not None
    store.save_result(job_id, SCENE.disparity.astype(np.float32), {"provenance": stages})
    counts = pm.counts(stages)
    assert store.apply(
        job_id, JobRecord.succeeded, now(), None, None, ["provenance"], counts
    ).changed
    status = api.get(f"/v1/jobs/{job_id}").json()
    assert status["provenance_counts"] == counts and counts["solver"] == 1
    png = api.get(status["links"]["provenance"])
    assert png.status_code == 200 and png.headers["content-type"] == "image/png"
    import cv2

    image = cv2.imdecode(np.frombuffer(png.content, np.uint8), cv2.IMREAD_COLOR)
    assert np.array_equal(pm.decode(image), stages)
    codes = api.get(f"/v1/jobs/{job_id}/provenance", params={"format": "npy"})
    assert np.array_equal(np.load(io.BytesIO(codes.content)), stages)
    assert api.get(f"/v1/jobs/{job_id}/provenance", params={"format": "tiff"}).status_code == 422
    legend = api.get("/v1/provenance-legend").json()
    assert [entry["name"] for entry in legend] == list(counts)


def test_a_run_without_a_map_says_so(api):
    job_id = post(api, params={"max_disparity": 6}).json()["id"]
    finish(api, job_id, {})
    assert api.get(f"/v1/jobs/{job_id}").json()["links"]["confidence"] is None
    missing = api.get(f"/v1/jobs/{job_id}/confidence")
    assert missing.status_code == 404 and "no confidence map" in missing.json()["detail"]
    assert api.get(f"/v1/jobs/{job_id}/provenance").status_code == 404


def test_depth_and_point_cloud_from_the_cameras_given_at_submit(api):
    created = post(api, params={"max_disparity": 6}, **CAMERAS)
    assert created.status_code == 202, created.text
    job_id = created.json()["id"]
    valid = np.ones(SCENE.disparity.shape, bool)
    valid[0] = False
    disparity = finish(api, job_id, {"validity": valid})
    links = api.get(f"/v1/jobs/{job_id}").json()["links"]
    depth = np.load(io.BytesIO(api.get(links["depth"].replace("pfm", "npy")).content))
    shifted = disparity + CAMERAS["doffs"]
    expected = np.where(shifted > 0, 100.0 * 0.5 / shifted, np.nan)
    assert np.allclose(depth, expected, equal_nan=True)
    ply = api.get(links["points"]).content
    header, _, body = ply.partition(b"end_header\n")
    count = int(header.split(b"element vertex ")[1].split()[0])
    assert count == int((valid & (shifted > 0)).sum()) and len(body) == count * 15


def test_incomplete_cameras_are_422(api):
    for fields in ({"focal": 100}, {"baseline": 0.5}, {"doffs": 2}, {"focal": -1, "baseline": 1}):
        response = post(api, params={"max_disparity": 6}, **fields)
        assert response.status_code == 422, (fields, response.text)


def ttl(api, job_id: str, *part: str) -> int:
    store = api.app.state.services.store
    return store.redis.ttl(store.key("job", job_id, *part))


def test_a_pinned_job_does_not_expire_until_unpinned(api):
    job_id = post(api, params={"max_disparity": 6}).json()["id"]
    pinned = api.post(f"/v1/jobs/{job_id}/pin")  # while queued: kept when it finishes
    assert pinned.status_code == 200 and pinned.json()["pinned"] is True
    finish(api, job_id, {"confidence": np.zeros(SCENE.disparity.shape, np.float32)})
    status = api.get(f"/v1/jobs/{job_id}").json()
    assert status["pinned"] is True and status["expires_at"] is None
    for part in [(), ("result",), ("view", "left.png")]:
        assert ttl(api, job_id, *part) == -1, part  # no expiry
    unpinned = api.delete(f"/v1/jobs/{job_id}/pin").json()
    assert unpinned["pinned"] is False and unpinned["expires_at"] is not None
    retention = api.app.state.services.settings.result_ttl_seconds
    for part in [(), ("result",), ("view", "left.png")]:
        assert retention - 60 < ttl(api, job_id, *part) <= retention, part
    assert api.post(f"/v1/jobs/{job_id}/pin").json()["pinned"] is True  # a finished one too
    assert ttl(api, job_id, "result") == -1


def test_pin_of_an_unknown_or_someone_elses_job_is_404(api, api_settings):
    unknown = api.post(f"/v1/jobs/{'0' * 32}/pin")
    assert unknown.status_code == 404 and "no job" in unknown.json()["detail"]
    job_id = post(api, params={"max_disparity": 6}).json()["id"]  # the admin's
    _, key = UserStore.from_settings(api_settings).create_user(f"pinner-{uuid.uuid4().hex[:6]}")
    theirs = {"Authorization": f"Bearer {key}"}
    for method, path in [("POST", "pin"), ("DELETE", "pin"), ("GET", "export")]:
        answer = api.request(method, f"/v1/jobs/{job_id}/{path}", headers=theirs)
        assert answer.status_code == 404, (method, path)
    assert api.get(f"/v1/jobs/{job_id}").json()["pinned"] is False


def test_export_is_one_zip_of_the_status_and_the_files(api):
    import json
    import zipfile

    job_id = post(api, params={"max_disparity": 6}, label="export me").json()["id"]
    valid = np.ones(SCENE.disparity.shape, bool)
    disparity = finish(api, job_id, {"validity": valid})
    response = api.get(f"/v1/jobs/{job_id}/export")
    assert response.status_code == 200 and response.headers["content-type"] == "application/zip"
    archive = zipfile.ZipFile(io.BytesIO(response.content))
    names = {name.split("/", 1)[1] for name in archive.namelist()}
    assert names == {"job.json", "disparity.pfm", "validity.png", "left.png"}
    record = json.loads(archive.read(f"{job_id}/job.json"))
    assert record["label"] == "export me" and record["config"]["max_disparity"] == 6
    assert {"levels", "usage", "version", "metrics"} <= set(record)
    import cv2

    pfm = archive.read(f"{job_id}/disparity.pfm")
    decoded = cv2.imdecode(np.frombuffer(pfm, np.uint8), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(decoded, disparity)


def test_a_metered_jobs_status_warns_when_its_owners_budget_runs_low(api, api_settings):
    users = UserStore.from_settings(api_settings)
    name = f"thrifty-{uuid.uuid4().hex[:6]}"
    _, key = users.create_user(name, qpu_seconds=100.0)
    mine = {"Authorization": f"Bearer {key}"}
    created = api.post(
        "/v1/jobs",
        files={"left": ("l.png", LEFT), "right": ("r.png", RIGHT)},
        data={"params": '{"solver": "qpu-sim", "max_disparity": 6}'},
        headers=mine,
    )
    assert created.status_code == 202, created.text
    job_id = created.json()["id"]
    assert not any(
        "runs low" in w for w in api.get(f"/v1/jobs/{job_id}", headers=mine).json()["warnings"]
    )
    users.ledger.settle(users.ledger.reserve(name, job_id, 95.0, ttl=60), 95.0)
    warnings = api.get(f"/v1/jobs/{job_id}", headers=mine).json()["warnings"]
    assert any("runs low: 5.000 s of 100 s left (5.0 %)" in w for w in warnings)
    assert api.delete(f"/v1/jobs/{job_id}", headers=mine).status_code == 200


def test_jobs_are_listed_by_tag(api, api_settings):
    run = f"run-{uuid.uuid4().hex[:6]}"
    tagged = [
        post(api, params={"max_disparity": 6}, tags=f"{run}, scene.a,{run}").json()["id"]
        for _ in range(3)
    ]
    post(api, params={"max_disparity": 6}, tags="other")
    status = api.get(f"/v1/jobs/{tagged[0]}").json()
    assert status["tags"] == sorted([run, "scene.a"])
    page = api.get("/v1/jobs", params={"tag": run, "limit": 2}).json()
    assert [item["id"] for item in page["items"]] == tagged[::-1][:2] and page["total"] == 3
    assert page["next"] == f"/v1/jobs?offset=2&limit=2&tag={run}"
    assert api.get(page["next"]).json()["items"][0]["id"] == tagged[0]
    # another user sees none of them under the tag
    _, key = UserStore.from_settings(api_settings).create_user(f"tagger-{uuid.uuid4().hex[:6]}")
    theirs = api.get("/v1/jobs", params={"tag": run}, headers={"Authorization": f"Bearer {key}"})
    assert theirs.json()["total"] == 0
    for bad in ("a b", "x" * 41, ",".join(f"t{i}" for i in range(11))):
        refused = post(api, params={"max_disparity": 6}, tags=bad)
        assert refused.status_code == 422 and "tags" in refused.text, bad
    assert api.get("/v1/jobs", params={"tag": "no spaces"}).status_code == 422


@pytest.mark.parametrize("per_job", [False, True], ids=["one-request", "per-job"])
def test_submit_batch_sends_every_pair_under_one_tag(
    live_api, api, api_settings, tmp_path, capsys, per_job
):
    import json

    import cv2
    import harness

    from shared.cli import main
    from shared.synthetic import make_scene

    for name, seed in (("a", 1), ("b", 2)):
        folder = tmp_path / "lab" / name
        folder.mkdir(parents=True)
        scene = make_scene(24, 32, max_disparity=6, seed=seed)
        for view, image in (("left.png", scene.left), ("right.png", scene.right)):
            cv2.imwrite(str(folder / view), (image * 255).round().astype(np.uint8))
        cv2.imwrite(str(folder / "gt_left.png"), (scene.disparity * 8).astype(np.uint8))
        (folder / "protocol.json").write_text(json.dumps({"scale": 8, "max_disparity": 7}))
    (tmp_path / "lab" / "a" / "calib.txt").write_text(CALIB.replace("ndisp=8\n", ""))
    tag = f"batch-{uuid.uuid4().hex[:6]}"
    key = harness.admin_key(api_settings)
    argv = ["submit-batch", str(tmp_path), "--url", live_api.url, "--key", key, "--json"]
    assert main([*argv, "--tag", tag, "--solver", "exact", *["--per-job"] * per_job]) == 0
    batch = json.loads(capsys.readouterr().out)
    if per_job:
        assert batch["batch"] is None
    else:  # one POST /v1/batches: its jobs listed under its id, in the order of the pairs
        listing = api.get(f"/v1/batches/{batch['batch']}").json()
        assert [job["id"] for job in listing["jobs"]] == [job["id"] for job in batch["jobs"]]
        assert listing["tags"] == [tag] and listing["progress"]["total"] == 2
    assert batch["tag"] == tag and batch["url"].endswith(f"/v1/jobs?tag={tag}")
    assert [(job["name"], job["max_disparity"]) for job in batch["jobs"]] == [
        ("lab/a", 7),
        ("lab/b", 7),
    ]
    listed = api.get("/v1/jobs", params={"tag": tag}).json()["items"]
    assert sorted(item["label"] for item in listed) == ["lab/a", "lab/b"]
    status = api.get(f"/v1/jobs/{batch['jobs'][0]['id']}").json()
    assert status["ground_truth"]["scale"] == 8 and status["config"]["solver"] == "exact"
    cameras = [api.get(f"/v1/jobs/{job['id']}").json()["cameras"] for job in batch["jobs"]]
    assert cameras[0]["focal"] == 100 and cameras[0]["cx"] == 15.5 and cameras[1] is None
    assert main(["submit-batch", str(tmp_path / "none"), "--url", live_api.url, "--key", key]) == 1
    assert "no such directory" in capsys.readouterr().err


CALIB = middlebury_calib(100, (15.5, 16.5), 11.5, doffs=1, baseline=500, size=(32, 24), ndisp=8)


def test_a_calibration_file_at_submit_gives_the_depth(api):
    created = post(api, params={"max_disparity": 6}, calib=CALIB.encode())
    assert created.status_code == 202, created.text
    job_id = created.json()["id"]
    disparity = finish(api, job_id, {})
    depth = api.get(f"/v1/jobs/{job_id}/depth", params={"format": "npy"})
    shifted = disparity + 1.0
    expected = np.where(shifted > 0, 100.0 * 500 / shifted, np.nan)
    assert np.allclose(np.load(io.BytesIO(depth.content)), expected, equal_nan=True)
    for extra, message in [
        ({"calib": b"baseline=1\n"}, "no P2/P3"),  # no cam0: read as KITTI
        ({"calib": b"cam0=[1 0]\nbaseline=1\n"}, "not a Middlebury calib.txt"),
        ({"calib": b"\xff\xfe"}, "not UTF-8"),
        ({"calib": CALIB.encode(), "focal": 10}, "either calib or focal"),
    ]:
        refused = post(api, params={"max_disparity": 6}, **extra)
        assert refused.status_code == 422 and message in refused.json()["detail"], refused.text
