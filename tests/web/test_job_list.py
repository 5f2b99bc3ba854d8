"""The web page's job list: filters by tag and by batch (see conftest.py for the server)."""

from __future__ import annotations

import pytest
from playwright.sync_api import Page, expect
from web_page import RESULT_TIMEOUT, sign_in

pytestmark = pytest.mark.service


def test_the_job_list_filters_by_tag_and_by_batch(page: Page, server, pair_files, screenshots):
    """A batch (POST /v1/batches) and a lone job, tagged apart: the list shows one tag's jobs,
    a batch's jobs with its progress (from a job's batch link), then all again."""
    views = {name: pair_files[name].read_bytes() for name in ("left", "right")}
    files = [(side, (f"{side}{i}.png", views[side])) for i in range(2) for side in views]
    params = {"params": '{"solver": "exact", "max_disparity": 8}'}
    with server.client() as api:
        batch = api.post("/v1/batches", files=files, data={**params, "tags": "web-batch"})
        assert batch.status_code == 202, batch.text
        lone = api.post(
            "/v1/jobs",
            files={side: (f"{side}.png", data) for side, data in views.items()},
            data={**params, "tags": "web-lone"},
        )
        assert lone.status_code == 202, lone.text
    batch_id, lone_id = batch.json()["id"], lone.json()["id"]
    batch_jobs = [job["id"] for job in batch.json()["jobs"]]
    sign_in(page, server)
    rows = page.locator("#jobs-table tbody tr")
    page.get_by_label("Tag", exact=True).fill("web-lone")
    page.get_by_role("button", name="Filter").click()
    expect(rows).to_have_count(1)
    expect(page.locator(f'tr[data-job="{lone_id}"]')).to_be_visible()
    assert page.url.endswith("#/jobs/tag/web-lone")

    page.get_by_role("button", name="Show all").click()
    first = page.locator(f'tr[data-job="{batch_jobs[0]}"]')
    first.get_by_role("link", name=f"batch {batch_id[:8]}").click()
    expect(rows).to_have_count(2)
    for job in batch_jobs:
        expect(page.locator(f'tr[data-job="{job}"]')).to_be_visible()
    summary = page.locator("#batch-summary")
    expect(summary).to_contain_text(f"Batch {batch_id[:8]} (web-batch)")
    expect(summary).to_contain_text("2/2 finished · 2 succeeded", timeout=RESULT_TIMEOUT)
    expect(page.get_by_label("Batch", exact=True)).to_have_value(batch_id)
    screenshots(page, "jobs-batch")

    page.get_by_label("Tag", exact=True).fill("web-lone")  # the batch's jobs with that tag: none
    page.get_by_role("button", name="Filter").click()
    expect(rows).to_have_count(0)
    expect(page.get_by_text("No job matches the filter.")).to_be_visible()
    page.get_by_role("button", name="Show all").click()
    expect(page.locator(f'tr[data-job="{lone_id}"]')).to_be_visible()
    assert page.url.endswith("#/jobs")
