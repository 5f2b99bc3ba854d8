"""Issue 10's API breaks, the inputs: numbers, records, images and parameters that used to answer
500, poison a job record or exhaust memory. The HTTP layer's are in test_hardening_http.py, the
clients' in test_hardening_clients.py."""

from __future__ import annotations

import io
import json
import logging
import struct
import time
import tracemalloc
import zlib

import cv2
import harness
import numpy as np
import pytest
from api_helpers import SCENE, post
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from workers.records import ACTIVE, ChunkReport, JobState

MiB = 2**20


def jobs_total(api) -> int:
    return api.get("/v1/jobs", params={"limit": 1}).json()["total"]


def svc(api):
    return api.app.state.services


# --- 1. poisoned job records ------------------------------------------------------------------


@pytest.mark.parametrize("scale", ["inf", "-inf", "nan", "1e400", "1e-300", "0", "-1", "1e9"])
def test_gt_scale_must_be_finite_and_sane(api, scale):
    before = jobs_total(api)
    response = post(api, ground_truth=harness.npy(SCENE.disparity), gt_scale=scale)
    assert response.status_code == 422, response.text
    assert "gt_scale" in response.text
    assert jobs_total(api) == before  # nothing stored


@pytest.mark.parametrize(
    "params",
    [
        '{"levels": [{"slope": 1e400}]}',
        '{"levels": [{"truncation": Infinity}]}',
        '{"bilateral_sigma_color": NaN}',
        '{"solver": "sa", "solver_params": {"beta_range": [-Infinity, 1]}}',
    ],
)
def test_params_numbers_must_be_finite(api, params):
    response = post(api, params=params)
    assert response.status_code == 422
    assert "numbers must be finite" in response.json()["detail"]


@pytest.mark.parametrize("value", [float("inf"), float("-inf"), float("nan")])
def test_configs_refuse_non_finite_numbers_whatever_their_source(value):
    """The CLI and the bench build configs without JSON: the model itself refuses them too."""
    from pydantic import ValidationError

    from shared.config import LevelConfig, MatchConfig

    with pytest.raises(ValidationError, match="finite number"):
        LevelConfig(slope=value)
    with pytest.raises(ValidationError, match="finite number"):
        MatchConfig(lr_tolerance=value)


def test_a_record_that_no_longer_loads_is_skipped_and_logged_never_a_500(api, caplog):
    job_id = post(api, params={"max_disparity": 6}).json()["id"]
    store = svc(api).store
    key = store.key("job", job_id)
    record = json.loads(store.redis.get(key))
    record["ground_truth"] = {"scale": None, "border": 0}  # what gt_scale=inf used to store
    store.redis.set(key, json.dumps(record))

    with caplog.at_level(logging.ERROR, logger="workers.store"):
        page = api.get("/v1/jobs", params={"limit": 100})
        assert page.status_code == 200
        assert job_id not in [item["id"] for item in page.json()["items"]]
        assert api.get(f"/v1/jobs/{job_id}").status_code == 404
        assert api.delete(f"/v1/jobs/{job_id}").status_code == 404
    assert f"job {job_id}: stored record does not load" in caplog.text
    store.redis.delete(key)


def test_non_finite_metrics_are_stored_as_null_and_the_job_still_loads(api):
    job_id = post(api, params={"max_disparity": 6}).json()["id"]
    level = {"index": 0, "downsample": 1, "height": 24, "width": 32, "candidates": 4}
    level |= {"bundles": 24, "energy": float("inf"), "repaired": 0, "seconds": 0.1}
    level |= {"solver_seconds": 0.05, "timing": {"qpu_access_time": float("nan")}}
    svc(api).store.transition(job_id, JobState.RUNNING, {JobState.QUEUED})  # runs, then ends
    moved = svc(api).store.transition(
        job_id,
        JobState.SUCCEEDED,
        ACTIVE,
        metrics={"rmse": float("inf"), "bpp": float("nan"), "pixels": 768.0},
        levels=[level],
    )
    assert moved is not None
    response = api.get(f"/v1/jobs/{job_id}")
    assert response.status_code == 200, response.text
    metrics = response.json()["metrics"]
    assert {key: metrics[key] for key in ("rmse", "bpp", "pixels")} == {
        "rmse": None,
        "bpp": None,
        "pixels": 768,
    }
    assert metrics["d1"] is None  # a record from before the measure still loads
    assert response.json()["levels"][0]["energy"] is None


def test_a_non_finite_solver_timing_does_not_break_the_job_status(api):
    job_id = post(api, params={"max_disparity": 6}).json()["id"]
    timing = {"qpu_access_time": float("inf"), "sampling_time": 0.5}
    report = ChunkReport(level=0, bundles=8, wall_time=0.2, timing=timing)
    svc(api).store.record_chunk(job_id, 0, report)
    response = api.get(f"/v1/jobs/{job_id}")
    assert response.status_code == 200, response.text
    assert response.json()["usage"] == {"solver_seconds": 0.2, "sampling_time": 0.5}
    assert job_id in [i["id"] for i in api.get("/v1/jobs", params={"limit": 100}).json()["items"]]


LEVEL = st.fixed_dictionaries(
    {},
    optional={
        "downsample": st.sampled_from([1, 2, 4, 64]),
        "candidates": st.integers(2, 64),
        "slope": st.floats(0, 1e300),
        "truncation": st.floats(0, 1e300),
        "edge_factor": st.floats(0, 1e300),
    },
)
CONFIG_PARAMS = st.fixed_dictionaries(
    {},
    optional={
        "preset": st.sampled_from(["accurate", "paper"]),
        "levels": st.lists(LEVEL, min_size=1, max_size=4),
        "pyramid": st.sampled_from(["image", "bins"]),
        "max_disparity": st.one_of(st.just("auto"), st.integers(1, 10**5)),
        "max_coarse_bins": st.integers(2, 64),
        "bundle_height": st.integers(1, 64),
        "bilateral_sigma_color": st.floats(1e-300, 1e300),
        "solver": st.sampled_from(["exact", "sa", "qpu-sim", "hybrid-sim", "gurobi"]),
        "solver_params": st.dictionaries(
            st.sampled_from(["num_reads", "num_sweeps", "time_limit"]),
            st.one_of(st.integers(-10, 10**12), st.floats(allow_nan=False), st.text(max_size=3)),
        ),
    },
)


@settings(
    max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(params=CONFIG_PARAMS, shape=st.sampled_from([(24, 32), (1, 1), (1, 40), (40, 1)]))
def test_config_shaped_params_on_a_real_pair_never_cause_a_server_error(api, params, shape):
    """Well-formed params at the edges of their ranges, on tiny and degenerate images: a 202 or
    a 4xx that says why, never a 500."""
    view = harness.png(np.random.default_rng(0).random(shape).astype(np.float32))
    response = post(api, left=view, right=view, params=params)
    assert response.status_code < 500, (params, shape, response.text)


# --- 3. decompression bombs -------------------------------------------------------------------


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png_declaring(width: int, height: int, *, pixels: bool = True) -> bytes:
    """An 8-bit gray PNG of zeros (compresses ~1000:1), or only its header."""
    header = _chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
    body = b""
    if pixels:
        compressor, rows = zlib.compressobj(9), bytes(width + 1) * 64
        data = b"".join(compressor.compress(rows) for _ in range(height // 64))
        body = _chunk(b"IDAT", data + compressor.flush())
    return b"\x89PNG\r\n\x1a\n" + header + body + _chunk(b"IEND", b"")


def test_a_decompression_bomb_is_refused_from_its_header_fast_and_without_memory(api):
    bomb = png_declaring(8000, 8000)  # 64 Mpx (16x the limit) in ~70 KB
    assert len(bomb) < 200_000
    tracemalloc.start()
    try:
        started = time.monotonic()
        response = post(api, left=bomb, right=bomb)
        seconds = time.monotonic() - started
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert response.status_code == 413
    assert "8000x8000 = 64000000 pixels is above the limit" in response.json()["detail"]
    assert seconds < 1.0
    assert peak < 100 * MiB


@pytest.mark.parametrize(
    "upload",
    [
        png_declaring(60000, 60000, pixels=False),  # header only: OpenCV itself raised
        b"PF\n60000 60000\n-1.0\n" + bytes(64),  # PFM
        b"P5\n60000 60000\n255\n" + bytes(64),  # PGM
    ],
    ids=["png", "pfm", "pgm"],
)
def test_a_header_claiming_a_huge_image_is_413(api, upload):
    assert len(upload) < 100
    response = post(api, left=upload, right=upload)
    assert response.status_code == 413
    assert "60000x60000" in response.json()["detail"]


@pytest.mark.parametrize("suffix", [".png", ".ppm", ".pgm", ".jpg", ".tif", ".bmp", ".pfm"])
@pytest.mark.parametrize("depth", ["8-bit", "16-bit or float"])
def test_every_supported_format_passes_the_header_check(api, suffix, depth):
    """The size check reads the header of every format the README lists (none is refused)."""
    gray = SCENE.left
    if suffix == ".pfm":
        image = gray.astype(np.float32)
    elif depth == "8-bit" or suffix in (".jpg", ".bmp"):
        image = np.rint(gray * 255).astype(np.uint8)
    else:
        image = np.rint(gray * 65535).astype(np.uint16)
    if suffix in (".ppm", ".pfm", ".jpg", ".bmp", ".tif"):
        image = np.dstack([image] * 3)
    ok, encoded = cv2.imencode(suffix, image)
    assert ok
    data = encoded.tobytes()
    response = post(api, left=data, right=data, params={"max_disparity": 6})
    assert response.status_code == 202, response.text


def test_a_ground_truth_image_is_measured_before_decoding(api):
    response = post(api, ground_truth=png_declaring(60000, 60000, pixels=False))
    assert response.status_code == 422
    assert "ground_truth is 60000x60000" in response.json()["detail"]


# --- 4. other inputs that answered 500 --------------------------------------------------------


def npy_header(shape: tuple[int, ...], descr: str = "<f4") -> bytes:
    stream = io.BytesIO()
    header = {"descr": descr, "fortran_order": False, "shape": shape}
    np.lib.format.write_array_header_1_0(stream, header)
    return stream.getvalue()


@pytest.mark.parametrize(
    ("upload", "code", "message"),
    [
        (npy_header((10**6, 10**6)), 422, "ground_truth is 1000000x1000000"),
        (npy_header((24, 32)) + bytes(100), 422, "truncated"),
        (npy_header((24, 32), "|O"), 415, "unsupported values object"),
        (b"\x93NUMPY\x01\x00\x10\x00{'descr': oops}\n", 422, "header does not parse"),
        # numpy's tokenizer gives up on it (tokenize.TokenError: a 500 before)
        (b"\x93NUMPY\x01\x00\x20\x00{'descr': __import__" + b" " * 11 + b"\n", 422, "parse"),
        (b"\x93NUMPY\x03\x00" + bytes(16), 415, "not a readable .npy"),
        # no value per pixel (an IndexError, a 500, before: issue 29)
        (npy_header((24, 32, 0)), 422, "0 channels per pixel"),
        (npy_header((24, 32, 5)) + bytes(24 * 32 * 5 * 4), 422, "5 channels per pixel"),
    ],
    ids=[
        "huge",
        "truncated",
        "object",
        "malformed",
        "unterminated",
        "version-3",
        "no-channel",
        "five-channels",
    ],
)
def test_npy_ground_truth_header_is_checked_before_allocating(api, upload, code, message):
    response = post(api, ground_truth=upload)
    assert response.status_code == code, response.text
    assert message in response.json()["detail"]


def test_a_fortran_order_npy_ground_truth_is_read_correctly(api):
    truth = np.asfortranarray(SCENE.disparity.astype(np.float32))
    response = post(api, params={"max_disparity": 6}, ground_truth=harness.npy(truth))
    assert response.status_code == 202, response.text
    stored = svc(api).store.load_upload(response.json()["id"], "ground_truth")
    np.testing.assert_array_equal(stored, SCENE.disparity)


@pytest.mark.parametrize(
    "params",
    # deep enough for any parser's recursion, within the 64 KiB that params may have
    ["[" * 20_000 + "]" * 20_000, '{"solver_params": ' + '{"a": ' * 8_000 + "1" + "}" * 8_001],
    ids=["lists", "objects"],
)
def test_deeply_nested_params_are_422(api, params):
    response = post(api, params=params)
    assert response.status_code == 422
    assert "nested too deeply" in response.json()["detail"]


@pytest.mark.parametrize("offset", ["9223372036854775807", "-1", "1e3"])
def test_list_offsets_are_bounded(api, offset):
    assert api.get("/v1/jobs", params={"offset": offset}).status_code == 422


@pytest.mark.parametrize("budget", ["Infinity", "-Infinity", "NaN", "1e400"])
def test_budgets_are_finite_or_null_never_infinite(api, api_settings, budget):
    """An infinite budget used to mean unlimited silently; unlimited is null, said so."""
    import uuid

    from api.users import UserError, UserStore

    name = f"budget-{uuid.uuid4().hex[:6]}"
    body = f'{{"name": "{name}", "qpu_seconds": {budget}}}'
    headers = {"Content-Type": "application/json"}
    created = api.post("/v1/users", content=body, headers=headers)
    assert created.status_code == 422, created.text
    assert api.post("/v1/users", json={"name": name, "qpu_seconds": 5}).status_code == 201
    quota = api.put(f"/v1/users/{name}/quota", content=f'{{"qpu_seconds": {budget}}}',
                    headers=headers)  # fmt: skip
    assert quota.status_code == 422, quota.text
    assert "finite" in quota.text
    assert api.put(f"/v1/users/{name}/quota", json={"qpu_seconds": None}).status_code == 200
    store = UserStore.from_settings(api_settings)
    with pytest.raises(ValueError, match="finite"):
        store.ledger.set_limit(name, float(budget))
    with pytest.raises(UserError, match="finite"):
        store.create_user(f"{name}-2", qpu_seconds=float(budget))
