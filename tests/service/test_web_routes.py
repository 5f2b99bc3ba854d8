"""The routes the web page adds: /v1/me, the admin's /v1/users, and the job's images."""

from __future__ import annotations

import json
import re

import cv2
import harness
import numpy as np
import pytest
from fastapi.testclient import TestClient

from api.routes.views import ERROR_MAP_MAX, NOT_EVALUATED
from api.web import WEB_DIR

pytestmark = pytest.mark.service


def as_user(client: TestClient, key: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {key}"}


@pytest.fixture(scope="module")
def member(client) -> tuple[str, str]:
    """A non-admin (name, key), made through the admin route."""
    name = f"member-{harness.unique_prefix()[-6:]}"
    response = client.post("/v1/users", json={"name": name})
    assert response.status_code == 201, response.text
    return name, response.json()["key"]


def test_me_names_the_key_owner(client, member):
    name, key = member
    assert client.get("/v1/me", headers=as_user(client, key)).json()["name"] == name
    assert client.get("/v1/me", headers=as_user(client, key)).json()["admin"] is False
    assert client.get("/v1/me").json()["admin"] is True
    assert client.get("/v1/me", headers={"Authorization": "Bearer nope"}).status_code == 401


def test_user_routes_are_for_admins_only(client, member):
    _, key = member
    for method, path in [
        ("GET", "/v1/users"),
        ("POST", "/v1/users"),
        ("POST", "/v1/users/x/key"),
        ("DELETE", "/v1/users/x/key"),
        ("PUT", "/v1/users/x/quota"),
    ]:
        response = client.request(method, path, headers=as_user(client, key), json={})
        assert response.status_code == 403, (method, path, response.text)


def test_create_rotate_revoke_and_quota(client, settings):
    name = f"ada-{harness.unique_prefix()[-6:]}"
    created = client.post("/v1/users", json={"name": name})
    assert created.status_code == 201
    assert created.json()["user"]["limit_seconds"] == settings.default_qpu_seconds
    old_key = created.json()["key"]
    assert "key_hash" not in created.text
    assert client.post("/v1/users", json={"name": name}).status_code == 409
    assert client.post("/v1/users", json={"name": "no spaces"}).status_code == 422
    unlimited = client.post("/v1/users", json={"name": f"{name}-u", "qpu_seconds": None})
    assert unlimited.json()["user"]["limit_seconds"] is None

    rotated = client.post(f"/v1/users/{name}/key").json()["key"]
    assert client.get("/v1/me", headers=as_user(client, old_key)).status_code == 401
    assert client.get("/v1/me", headers=as_user(client, rotated)).status_code == 200

    quota = client.put(f"/v1/users/{name}/quota", json={"qpu_seconds": 7.5})
    assert quota.json()["limit_seconds"] == 7.5
    usage = client.get("/v1/usage", params={"user": name}).json()["users"][0]
    assert usage["limit_seconds"] == 7.5
    assert client.put(f"/v1/users/{name}/quota", json={"qpu_seconds": -1}).status_code == 422
    assert client.put("/v1/users/nobody-here/quota", json={"qpu_seconds": 1}).status_code == 404

    revoked = client.delete(f"/v1/users/{name}/key")
    assert revoked.json()["revoked"] is True
    assert client.get("/v1/me", headers=as_user(client, rotated)).status_code == 401
    me = client.get("/v1/me").json()["name"]
    assert client.delete(f"/v1/users/{me}/key").status_code == 409  # not one's own key


def test_job_images_left_error_map_and_colour_bars(client, member):
    from shared.synthetic import make_scene

    scene = make_scene(32, 48, max_disparity=8, seed=2)
    left, right = harness.png(scene.left), harness.png(scene.right)
    params = {"solver": "exact", "max_disparity": 8}
    with_gt = harness.submit(
        client, left, right, params, ground_truth=harness.npy(scene.disparity), gt_border=2
    )
    without = harness.submit(client, left, right, params)
    assert harness.wait_for(client, with_gt)["state"] == "succeeded"
    assert harness.wait_for(client, without)["state"] == "succeeded"

    view = cv2.imdecode(
        np.frombuffer(client.get(f"/v1/jobs/{with_gt}/left.png").content, np.uint8), 0
    )
    np.testing.assert_array_equal(view, np.rint(scene.left * 255).astype(np.uint8))

    response = client.get(f"/v1/jobs/{with_gt}/error.png")
    assert response.status_code == 200 and response.headers["x-scale-max"] == f"{ERROR_MAP_MAX:g}"
    errors = cv2.imdecode(np.frombuffer(response.content, np.uint8), cv2.IMREAD_COLOR)
    assert errors.shape == (32, 48, 3)
    assert (errors[:2] == NOT_EVALUATED).all() and (errors[:, :2] == NOT_EVALUATED).all()
    assert not (errors[2:-2, 2:-2] == NOT_EVALUATED).all(axis=2).any()
    missing = client.get(f"/v1/jobs/{without}/error.png")
    assert missing.status_code == 404 and "without a ground truth" in missing.json()["detail"]

    bar = client.get(f"/v1/jobs/{with_gt}/colorbar.png", params={"map": "disparity"})
    assert bar.headers["x-scale-max"] == "8"
    assert client.get(f"/v1/jobs/{with_gt}/preview.png").headers["x-scale-max"] == "8"
    assert client.get(f"/v1/jobs/{with_gt}/colorbar.png?map=nope").status_code == 422

    _, key = member  # another user's job: not found, like every other job route
    for path in ("left.png", "error.png", "colorbar.png"):
        response = client.get(f"/v1/jobs/{with_gt}/{path}", headers=as_user(client, key))
        assert response.status_code == 404, path


def test_the_page_is_served_with_a_self_only_policy(client):
    page = client.get("/", headers={"Authorization": ""})
    assert page.status_code == 200 and '<script type="module" src="/web/app.js">' in page.text
    assert "default-src 'self'" in page.headers["content-security-policy"]
    assert client.get("/web/style.css").status_code == 200
    modules = sorted(WEB_DIR.glob("*.js"))
    assert len(modules) > 1
    for path in modules:  # a module script served as anything but JavaScript does not run
        response = client.get(f"/web/{path.name}")
        assert response.status_code == 200, path.name
        assert response.headers["content-type"].startswith("text/javascript"), path.name
        assert response.headers["cache-control"] == "no-cache", path.name
    assert not re.search(r'(src|href)="(https?:)?//', page.text)  # nothing from elsewhere


@pytest.mark.parametrize(
    ("host", "signs_in"),
    [("127.0.0.1", True), ("localhost", True), ("::1", True), ("0.0.0.0", False), ("lab", False)],
)
def test_serve_puts_the_key_in_the_address_only_on_loopback(host, signs_in):
    from api.serve_cli import sign_in_url

    url = sign_in_url(f"http://{host}:8000", host, "qhsm_k")
    assert url == (f"http://{host}:8000/#key=qhsm_k" if signs_in else f"http://{host}:8000/")
    assert sign_in_url("http://127.0.0.1:8000", "127.0.0.1", None) == "http://127.0.0.1:8000/"


def test_a_colour_pair_keeps_its_colour_and_takes_a_ground_truth(client):
    from shared.synthetic import make_scene

    scene = make_scene(32, 48, max_disparity=8, seed=3)
    tint = np.array([0.6, 0.8, 1.0], dtype=np.float32)  # BGR: a colour view, not a gray one
    left, right = (harness.png(view[:, :, None] * tint) for view in (scene.left, scene.right))
    job_id = harness.submit(
        client, left, right, {"solver": "exact"}, ground_truth=harness.npy(scene.disparity)
    )
    assert harness.wait_for(client, job_id)["state"] == "succeeded"
    view = client.get(f"/v1/jobs/{job_id}/left.png").content
    colour = cv2.imdecode(np.frombuffer(view, np.uint8), cv2.IMREAD_UNCHANGED)
    assert colour.shape == (32, 48, 3) and not np.array_equal(colour[..., 0], colour[..., 2])
    assert client.get(f"/v1/jobs/{job_id}/error.png").status_code == 200


def test_serve_prints_the_key_only_when_it_makes_it(settings, tmp_path, capsys):
    """The full key is in serve's output once, when it is created; a later start says where
    it is and prints the plain address."""
    from api.serve_cli import announce_web_page

    local = settings.model_copy(update={"data_dir": tmp_path, "auth_enabled": True})
    url = "http://127.0.0.1:8000"
    first_key = announce_web_page(local, url)
    first = capsys.readouterr().err
    assert first_key and f"#key={first_key}" in first
    assert announce_web_page(local, url) == first_key
    later = capsys.readouterr().err
    assert first_key not in later and "#key=" not in later
    assert "web page: http://127.0.0.1:8000/\n" in later and str(tmp_path / "api-key") in later


# --- issue 22: what the page shows of a job, thumbnails, differences


@pytest.fixture(scope="module")
def scene_files():
    from shared.synthetic import make_scene

    scene = make_scene(48, 64, max_disparity=8, seed=3)
    return scene, harness.png(scene.left), harness.png(scene.right)


def _post(client, left, right, params, **form):
    files = {"left": ("im2.ppm", left), "right": ("dir/im6.ppm", right)}
    if "ground_truth" in form:
        files["ground_truth"] = ("gt.npy", form.pop("ground_truth"))
    return client.post("/v1/jobs", files=files, data={"params": json.dumps(params), **form})


def test_a_ground_truth_without_scale_gets_one_inferred_and_says_so(client, scene_files):
    scene, left, right = scene_files
    params = {"solver": "exact", "max_disparity": 8}
    created = _post(client, left, right, params, ground_truth=harness.npy(scene.disparity * 16))
    assert created.status_code == 202, created.text
    [note] = created.json()["warnings"]
    assert note.startswith("ground-truth scale not given: inferred 16 ")
    status = harness.wait_for(client, created.json()["id"])
    assert status["ground_truth"] == {"scale": 16.0, "border": 0, "inferred": True}
    assert status["warnings"] == [note] and status["metrics"]["rmse"] < 2
    given = _post(
        client, left, right, params, ground_truth=harness.npy(scene.disparity), gt_scale=1
    )
    assert given.json()["warnings"] == []
    unrelated = np.random.default_rng(0).uniform(1, 200, scene.disparity.shape)
    refused = _post(client, left, right, params, ground_truth=harness.npy(unrelated))
    assert refused.status_code == 422
    assert refused.json()["detail"].startswith("gt_scale: cannot infer the ground-truth scale")


def test_swapped_views_are_a_warning_of_the_job(client, scene_files):
    _, left, right = scene_files
    created = _post(client, right, left, {"solver": "exact", "max_disparity": 8})
    assert created.json()["warnings"] == []  # the views are checked when the job starts
    status = harness.wait_for(client, created.json()["id"])
    [warning] = status["warnings"]
    assert "the views look swapped" in warning
    assert status["disparity_range"]["warning"] == warning


def test_the_job_list_names_the_files_or_label_and_shows_scores_and_times(client, scene_files):
    scene, left, right = scene_files
    params = {"solver": "exact", "max_disparity": 8}
    labelled = _post(client, left, right, params, label="  tsukuba\nretake ", gt_scale=1,
                     ground_truth=harness.npy(scene.disparity)).json()["id"]  # fmt: skip
    harness.wait_for(client, labelled)
    items = {item["id"]: item for item in client.get("/v1/jobs").json()["items"]}
    item = items[labelled]
    assert item["label"] == "tsukuba retake"  # one line
    assert item["files"] == ["im2.ppm", "im6.ppm"]  # no folder the client sent
    assert item["metrics"]["rmse"] >= 0 and item["metrics"]["bpp"] >= 0
    assert item["started_at"] <= item["finished_at"]
    assert item["qpu_seconds"] is None  # exact is not metered
    too_long = _post(client, left, right, params, label="x" * 201)
    assert too_long.status_code == 422


def test_a_thumbnail_of_any_accepted_format_is_a_png(client, scene_files):
    scene, _, _ = scene_files
    grey = cv2.resize(np.rint(scene.left * 255).astype(np.uint8), (640, 480))
    for suffix in (".ppm", ".pgm", ".tiff"):
        image = grey if suffix == ".pgm" else cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)
        ok, data = cv2.imencode(suffix, image)
        assert ok
        response = client.post("/v1/thumbnail", files={"image": (f"v{suffix}", data.tobytes())})
        assert response.status_code == 200 and response.headers["content-type"] == "image/png"
        thumbnail = cv2.imdecode(np.frombuffer(response.content, np.uint8), cv2.IMREAD_UNCHANGED)
        assert thumbnail.shape[:2] == (240, 320), suffix
    refused = client.post("/v1/thumbnail", files={"image": ("x.ppm", b"not an image")})
    assert refused.status_code == 415


def test_the_difference_of_two_jobs_is_an_image_with_its_share(client, scene_files):
    _, left, right = scene_files
    a = _post(client, left, right, {"solver": "exact", "max_disparity": 8}).json()["id"]
    b = _post(client, left, right, {"solver": "exact", "max_disparity": 8, "lr_check": False})
    b = b.json()["id"]
    harness.wait_for(client, a), harness.wait_for(client, b)
    expected = np.abs(harness.download(client, a) - harness.download(client, b))
    response = client.get(f"/v1/jobs/{a}/difference.png", params={"with": b})
    assert response.status_code == 200 and response.headers["x-scale-max"] == f"{ERROR_MAP_MAX:g}"
    assert float(response.headers["x-differing-percent"]) == pytest.approx(
        100 * np.mean(expected > 1), abs=0.01
    )
    same = client.get(f"/v1/jobs/{a}/difference.png", params={"with": a})
    assert same.headers["x-differing-percent"] == "0.00"
    assert client.get(f"/v1/jobs/{a}/difference.png", params={"with": "0" * 32}).status_code == 404
