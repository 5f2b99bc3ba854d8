"""An uploaded ground truth is read as the datasets store it and its scale follows its format."""

from __future__ import annotations

import numpy as np

from api.job_service import ground_truth_protocol
from api.uploads import decode_ground_truth
from shared.ground_truth import scale_of_format


def test_middlebury_2014_pfm_upload_is_read_in_pixels_and_scale_1():
    truth = np.array([[10.5, 20.25], [np.inf, 115.0]], np.float32)
    data = b"Pf\n2 2\n-0.003922\n" + np.ascontiguousarray(truth[::-1], "<f4").tobytes()
    values = decode_ground_truth(data, (2, 2))
    np.testing.assert_array_equal(values, [[10.5, 20.25], [0, 115.0]])
    views = np.zeros((2, 2), np.float32)
    stated = scale_of_format(data)
    truth_protocol, note = ground_truth_protocol(views, views, values, None, 0, stated)
    assert truth_protocol.scale == 1 and not truth_protocol.inferred and "PFM" in note
    truth_protocol, warning = ground_truth_protocol(views, views, values, 256, 0, stated)
    assert truth_protocol.scale == 256 and "256 given, but PFM" in warning
    assert ground_truth_protocol(views, views, values, 1, 0, stated)[1] == ""


def test_a_job_records_its_version_and_a_pfm_ground_truth_is_scored_in_pixels(api):
    from api_helpers import SCENE, post

    import qhsm

    truth = SCENE.disparity.astype(np.float32)
    height, width = truth.shape
    pfm = f"Pf\n{width} {height}\n-0.003922\n".encode()
    pfm += np.ascontiguousarray(truth[::-1], "<f4").tobytes()
    created = post(api, params={"max_disparity": 6}, ground_truth=pfm)
    assert created.status_code == 202, created.text
    assert any("PFM" in warning for warning in created.json()["warnings"])
    status = api.get(f"/v1/jobs/{created.json()['id']}").json()
    assert status["version"] == qhsm.__version__ and status["ground_truth"]["scale"] == 1


def test_a_finished_job_says_when_it_expires(api):
    from datetime import datetime, timedelta

    from api_helpers import post

    from workers.records import ACTIVE, JobState

    job_id = post(api, params={"max_disparity": 6}).json()["id"]
    assert api.get(f"/v1/jobs/{job_id}").json()["expires_at"] is None  # still queued
    store = api.app.state.services.store
    assert store.transition(job_id, JobState.RUNNING, ACTIVE) is not None
    assert store.transition(job_id, JobState.SUCCEEDED, ACTIVE, metrics=None) is not None
    status = api.get(f"/v1/jobs/{job_id}").json()
    ttl = timedelta(seconds=store.settings.result_ttl_seconds)
    finished = datetime.fromisoformat(status["finished_at"])
    assert datetime.fromisoformat(status["expires_at"]) == finished + ttl
