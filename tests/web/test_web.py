"""The lab's web page in a real browser against a real `qhsm serve` (see conftest.py)."""

from __future__ import annotations

import io
import re
from pathlib import Path
from urllib.parse import urlsplit

import cv2
import numpy as np
import pytest
from playwright.sync_api import Page, expect
from web_page import RESULT_TIMEOUT, sign_in, submit_pair

pytestmark = pytest.mark.service


def test_the_sign_in_url_of_serve_signs_the_admin_in_and_leaves_no_key_behind(
    page: Page, server, screenshots
):
    assert urlsplit(server.sign_in_url).fragment == f"key={server.admin_key}"
    page.goto(server.sign_in_url)
    expect(page.locator("#switch-to")).to_have_text("local-admin (admin)")  # says who, asks
    page.get_by_role("button", name="Sign in as local-admin").click()
    expect(page.locator("#who-name")).to_have_text("local-admin (admin)")
    assert "key=" not in page.url  # dropped from the address bar (and so from the history)
    assert page.evaluate("sessionStorage.getItem('qhsm.key')") == server.admin_key
    requests = [line for line in server.log.read_text().splitlines() if '"GET /' in line]
    assert requests and not [line for line in requests if server.admin_key in line]
    expect(page.get_by_role("link", name="Users", exact=True)).to_be_visible()
    page.get_by_role("button", name="Sign out").click()
    expect(page.get_by_label("API key")).to_be_visible()
    assert page.evaluate("sessionStorage.getItem('qhsm.key')") is None
    screenshots(page, "sign-in")


def test_a_wrong_key_is_refused_with_the_api_message(page: Page, server):
    page.goto(server.url)
    page.get_by_label("API key").fill("qhsm_0badc0de_" + "x" * 43)
    page.get_by_role("button", name="Sign in").click()
    expect(page.get_by_role("alert").filter(has_text="invalid or revoked API key")).to_be_visible()
    expect(page.locator("#nav")).to_be_hidden()
    assert page.evaluate("sessionStorage.getItem('qhsm.key')") is None


def test_submit_exact_shows_the_disparity_its_metrics_and_downloads(
    page: Page, server, pair_files, screenshots
):
    sign_in(page, server)
    page.get_by_role("link", name="Submit", exact=True).click()
    expect(page.get_by_label("Solver")).to_contain_text("exact")
    screenshots(page, "submit")
    job_id = submit_pair(page, pair_files, "exact", ground_truth=True, tags="web-run, exact")
    disparity = page.get_by_alt_text("Disparity", exact=True)
    expect(disparity).to_be_visible(timeout=RESULT_TIMEOUT)
    assert disparity.evaluate("img => [img.naturalWidth, img.naturalHeight]") == [64, 48]
    with server.client() as api:
        status = api.get(f"/v1/jobs/{job_id}").json()
        result = np.load(io.BytesIO(api.get(f"/v1/jobs/{job_id}/disparity?format=npy").content))
    metrics = page.get_by_label("metrics")
    expect(metrics).to_contain_text(f"{status['metrics']['rmse']:.3f} px")
    expect(metrics).to_contain_text(f"{status['metrics']['bpp']:.2f} %")
    expect(metrics).to_contain_text("bad pixels")
    expect(page.get_by_alt_text("Error map", exact=True)).to_be_visible()
    expect(page.get_by_alt_text("Left view", exact=True)).to_be_visible()
    expect(page.locator(".ticks").first).to_contain_text("8 px")  # the colour bar's top
    expect(page.locator("table.levels tbody tr")).to_have_count(len(status["levels"]))
    with page.expect_download() as download:
        page.get_by_role("button", name="16-bit PNG").click()
    png = cv2.imread(download.value.path(), cv2.IMREAD_UNCHANGED)
    assert png.dtype == np.uint16
    np.testing.assert_allclose(png / 256.0, result, atol=1 / 256)
    with page.expect_download() as download:  # the left-right check's map beside it
        page.get_by_role("button", name="validity PNG").click()
    with server.client() as api:
        served = api.get(status["links"]["validity"]).content
    assert Path(download.value.path()).read_bytes() == served
    expect(page.get_by_role("button", name="confidence PFM")).to_be_visible()
    # who decided each pixel: the map, its legend (from the API's one) with the status' counts
    expect(page.get_by_alt_text("Provenance map", exact=True)).to_be_visible()
    legend = page.get_by_label("provenance legend")
    counts = status["provenance_counts"]
    expect(legend.locator("li")).to_have_count(len(counts))
    expect(legend.locator('li[data-stage="certified"]')).to_contain_text(
        f"certified: {counts['certified']} px"
    )
    with page.expect_download() as download:
        page.get_by_role("button", name="provenance PNG").click()
    with server.client() as api:
        served = api.get(status["links"]["provenance"]).content
    assert Path(download.value.path()).read_bytes() == served
    expect(page.get_by_role("button", name="depth PFM")).to_have_count(0)  # no cameras given
    page.get_by_role("button", name="Pin", exact=True).click()  # kept past the retention
    expect(page.get_by_role("button", name="Unpin")).to_be_visible()
    expect(page.locator("dl.kv").first).to_contain_text("never: pinned")
    expect(page.locator("dl.kv").first).to_contain_text("exact, web-run")  # its tags
    with server.client() as api:
        assert api.get(f"/v1/jobs/{job_id}").json()["pinned"] is True
    screenshots(page, "job")
    with page.expect_download() as download:
        page.get_by_role("button", name="Export").click()
    assert download.value.suggested_filename == f"{job_id}.zip"
    page.get_by_role("link", name="Usage", exact=True).click()
    with page.expect_download() as download:  # the QPU ledger as CSV
        page.get_by_role("button", name="Export CSV").click()
    header = Path(download.value.path()).read_text().splitlines()[0]
    assert header == "user,job,qpu_seconds,problems,first_charged_at,last_charged_at"


def test_two_jobs_on_one_pair_compare_side_by_side(page: Page, server, pair_files, screenshots):
    with server.client() as api:
        exact = [job for job in api.get("/v1/jobs").json()["items"] if job["solver"] == "exact"]
    sign_in(page, server)
    page.get_by_role("link", name="Submit", exact=True).click()
    page.get_by_text("Advanced solver parameters").click()
    page.get_by_label("Advanced parameters (JSON)").fill('{"num_reads": 4, "num_sweeps": 100}')
    page.get_by_label("Preset").select_option("paper")
    sa = submit_pair(page, pair_files, "sa", ground_truth=True)
    expect(page.get_by_alt_text("Disparity", exact=True)).to_be_visible(timeout=RESULT_TIMEOUT)
    expect(page.locator("pre.params")).to_contain_text('"num_sweeps": 100')
    expect(page.locator("pre.params")).to_contain_text('"preset": "paper"')
    page.get_by_label("Compare with").select_option(exact[0]["id"])
    page.get_by_role("button", name="Compare").click()
    page.wait_for_url(f"**/#/compare/{sa}/{exact[0]['id']}")
    columns = page.locator(".compare .column")
    expect(columns).to_have_count(2)
    expect(columns.nth(0).get_by_role("heading")).to_contain_text("sa")
    expect(columns.nth(1).get_by_role("heading")).to_contain_text("exact")
    for column in (columns.nth(0), columns.nth(1)):
        expect(column.get_by_alt_text("Disparity", exact=True)).to_be_visible()
        expect(column.get_by_label("metrics")).to_contain_text("RMSE")
    difference = page.get_by_alt_text("Difference", exact=True)  # |sa - exact|
    expect(difference).to_be_visible()
    assert difference.evaluate("img => [img.naturalWidth, img.naturalHeight]") == [64, 48]
    expect(page.locator(".difference figcaption")).to_contain_text(
        re.compile(r"\|sa − exact\| in px: [\d.]+ % of the pixels differ by more than 1 px")
    )
    screenshots(page, "compare")


def test_an_image_dropped_on_its_box_is_taken(page: Page, server, pair_files):
    sign_in(page, server)
    page.get_by_role("link", name="Submit", exact=True).click()
    data = list(pair_files["left"].read_bytes())
    transfer = page.evaluate_handle(
        """(bytes) => {
            const transfer = new DataTransfer();
            const file = new File([new Uint8Array(bytes)], "dropped.png", {type: "image/png"});
            transfer.items.add(file);
            return transfer;
        }""",
        data,
    )
    page.locator('.drop[data-input="left"]').dispatch_event("drop", {"dataTransfer": transfer})
    expect(page.get_by_alt_text("chosen left file: dropped.png")).to_be_visible()
    assert page.get_by_label("Left image").evaluate("input => input.files[0].name") == "dropped.png"


def test_api_validation_errors_show_next_to_their_field(page: Page, server, pair_files):
    sign_in(page, server)
    page.get_by_role("link", name="Submit", exact=True).click()
    page.get_by_role("button", name="Submit").click()
    expect(page.locator('.field-error[data-field="left"]')).to_have_text("Choose the left image.")
    page.get_by_label("Left image").set_input_files(pair_files["left"])
    page.get_by_label("Right image").set_input_files(pair_files["small"])
    page.get_by_label("Solver").select_option("exact")
    page.get_by_role("button", name="Submit").click()
    expect(page.locator('.field-error[data-field="right"]')).to_contain_text("50x40")
    page.get_by_label("Right image").set_input_files(pair_files["right"])
    page.get_by_label("Max disparity (px)").fill("5000")
    page.get_by_role("button", name="Submit").click()
    expect(page.locator('.field-error[data-field="max_disparity"]')).to_contain_text(
        "max_disparity"
    )
    expect(page.get_by_label("Max disparity (px)")).to_have_attribute("aria-invalid", "true")
    expect(page.locator('.field-error[data-field="right"]')).to_be_empty()
    # unavailable solvers are listed, disabled, with their reason
    unavailable = page.locator("#solver option", has_text="fake-unavailable")
    expect(unavailable).to_be_disabled()
    expect(unavailable).to_contain_text("needs hardware this machine lacks")


def test_a_slow_job_shows_live_progress_and_can_be_cancelled(
    page: Page, server, pair_files, screenshots
):
    sign_in(page, server)
    job_id = submit_pair(page, pair_files, "fake-slow")
    progress = page.locator("#view-job .bar-text")
    expect(progress).to_contain_text(
        re.compile(r"level 1/\d+ · [1-9]\d*/\d+ bundles"), timeout=20_000
    )
    page.get_by_role("link", name="Jobs", exact=True).click()
    row = page.locator(f'tr[data-job="{job_id}"]')
    expect(row.locator(".badge")).to_have_text("running")
    screenshots(page, "jobs")
    row.get_by_role("button", name="Cancel").click()
    expect(row.locator(".badge")).to_have_text("cancelled")
    with server.client() as api:
        assert api.get(f"/v1/jobs/{job_id}").json()["state"] == "cancelled"


def test_another_users_job_is_neither_listed_nor_reachable(page: Page, server, pair_files):
    with server.client() as api:
        response = api.post("/v1/users", json={"name": "web-bob"})
        assert response.status_code == 201, response.text
        bob = response.json()["key"]
        admin_jobs = api.get("/v1/jobs").json()["items"]
    assert admin_jobs, "the admin's jobs of the earlier tests"
    sign_in(page, server, bob)
    expect(page.locator("#who-name")).to_have_text("web-bob")
    expect(page.get_by_text("No jobs yet")).to_be_visible()
    expect(page.get_by_role("link", name="Users", exact=True)).to_be_hidden()
    page.goto(f"{server.url}/#/job/{admin_jobs[0]['id']}")
    expect(page.get_by_role("heading", name="Job not found")).to_be_visible()
    expect(page.get_by_role("alert")).to_contain_text("no job")
    # bob's own job is listed for him and, with its owner, for the admin
    job_id = submit_pair(page, pair_files, "exact")
    page.get_by_role("link", name="Jobs", exact=True).click()
    expect(page.locator("#jobs-table tbody tr")).to_have_count(1)
    expect(page.locator(f'tr[data-job="{job_id}"]')).to_be_visible()
    sign_in(page, server)
    expect(page.locator(f'tr[data-job="{job_id}"] .owner-col')).to_have_text("web-bob")


def test_a_link_with_another_users_key_never_switches_a_signed_in_tab_silently(page: Page, server):
    """Login CSRF: `/#key=<someone else's key>` used to switch the tab to that account, and
    the uploads then went there. The page now says whose key it is and asks."""
    with server.client() as api:
        response = api.post("/v1/users", json={"name": "web-mallory"})
        assert response.status_code == 201, response.text
        mallory = response.json()["key"]
    sign_in(page, server)
    page.goto(f"{server.url}/#key={mallory}")
    expect(page.locator("#switch-to")).to_have_text("web-mallory")
    expect(page.locator("#switch-current")).to_have_text("local-admin (admin)")
    assert "key=" not in page.url
    assert page.evaluate("sessionStorage.getItem('qhsm.key')") == server.admin_key
    page.get_by_role("button", name="Stay local-admin").click()
    expect(page.locator("#who-name")).to_have_text("local-admin (admin)")
    assert page.evaluate("sessionStorage.getItem('qhsm.key')") == server.admin_key
    # choosing to switch does switch; the tab's own key in a link asks nothing
    page.goto(f"{server.url}/#key={mallory}")
    page.get_by_role("button", name="Sign in as web-mallory").click()
    expect(page.locator("#who-name")).to_have_text("web-mallory")
    page.goto(f"{server.url}/#key={mallory}")
    expect(page.locator("#who-name")).to_have_text("web-mallory")
    expect(page.locator("#view-switch")).to_be_hidden()


def test_admin_creates_a_user_sets_a_quota_and_sees_usage(page: Page, server, screenshots):
    sign_in(page, server)
    page.get_by_role("link", name="Users", exact=True).click()
    page.get_by_label("User name").fill("web-carol")
    page.get_by_label("QPU budget (s)").fill("5")
    page.get_by_role("button", name="Create user").click()
    key = page.locator("#issued-key-value").inner_text()
    with server.client(key) as api:
        assert api.get("/v1/me").json()["name"] == "web-carol"
    row = page.locator('tr[data-user="web-carol"]')
    expect(row).to_contain_text("5")
    row.get_by_label("QPU budget of web-carol").fill("12.5")
    row.get_by_role("button", name="Set").click()
    expect(row.locator('td[data-label="Budget s"]')).to_have_text("12.5")
    row.get_by_label("Budget period of web-carol").select_option("monthly")
    row.get_by_role("button", name="Set").click()
    expect(row.get_by_label("Budget period of web-carol")).to_have_value("monthly")
    with server.client() as api:
        usage = api.get("/v1/usage", params={"user": "web-carol"}).json()["users"][0]
    assert usage["limit_seconds"] == 12.5
    page.get_by_label("User name").fill("web-carol")
    page.get_by_role("button", name="Create user").click()
    expect(page.locator('.field-error[data-field="name"]')).to_contain_text("exists already")
    screenshots(page, "users")
    ledger = server.ledger()  # a QPU job's charge, as a QPU worker settles it
    ledger.settle(ledger.reserve("web-carol", "c" * 32, 2.0, ttl=60), 1.5, problems=3)
    page.get_by_role("link", name="Usage", exact=True).click()
    card = page.locator('.usage-card[data-user="web-carol"]')
    expect(card.locator("dd")).to_have_text(
        ["1.5 s", "0 ms", "11 s", "12.5 s", re.compile(r"^monthly since \d{4}-\d\d-01$"),
         re.compile(r"^\d{4}-\d\d-01 00:00:00 UTC$"), "1.5 s"]
    )  # fmt: skip
    expect(card.locator("tbody td")).to_have_text(["cccccccc", "1.5 s", "3"])
    screenshots(page, "usage")
    page.get_by_role("link", name="Users", exact=True).click()
    page.locator('tr[data-user="web-carol"]').get_by_role("button", name="Revoke").click()
    expect(page.locator('tr[data-user="web-carol"] .badge')).to_have_text("revoked")
    with server.client(key) as api:
        assert api.get("/v1/me").status_code == 401


def test_the_page_needs_nothing_but_its_own_server(page: Page, server):
    """Every request stays on 127.0.0.1; anything else is aborted and would break the page."""
    requests, blocked = [], []

    def route(request_route):
        url = request_route.request.url
        requests.append(url)
        if urlsplit(url).hostname == "127.0.0.1" or url.startswith(("blob:", "data:")):
            request_route.continue_()
        else:
            blocked.append(url)
            request_route.abort()

    page.context.route("**/*", route)
    sign_in(page, server)
    page.get_by_role("link", name="Submit", exact=True).click()
    expect(page.get_by_label("Solver")).to_contain_text("exact")
    page.get_by_role("link", name="Usage", exact=True).click()
    expect(page.get_by_role("heading", name="QPU usage")).to_be_visible()
    assert requests and not blocked
    response = page.request.get(server.url)
    assert "default-src 'self'" in response.headers["content-security-policy"]


@pytest.mark.parametrize("view", ["jobs", "job", "submit", "usage", "users"])
def test_phone_width_has_no_sideways_scrolling(page: Page, server, view, screenshots):
    page.set_viewport_size({"width": 390, "height": 844})
    sign_in(page, server)
    address = view
    if view == "job":
        with server.client() as api:
            jobs = api.get("/v1/jobs").json()["items"]
        address = "job/" + next(job["id"] for job in jobs if job["state"] == "succeeded")
    page.goto(f"{server.url}/#/{address}")
    expect(page.locator(f"#view-{view}")).to_be_visible()
    ready = {
        "jobs": page.locator("#jobs-table tbody tr").first,
        "job": page.get_by_alt_text("Disparity", exact=True),
        "submit": page.locator("#solver option").first,
        "usage": page.locator(".usage-card").first,
        "users": page.locator("#users-table tbody tr").first,
    }[view]
    expect(ready).to_be_attached()
    width = page.evaluate("document.documentElement.scrollWidth")
    assert width <= 390, f"{view}: the page is {width} px wide on a 390 px screen"
    screenshots(page, f"phone-{view}")


# --- issue 22: what a new user runs into


def test_ppm_views_get_png_thumbnails_from_the_api(page: Page, server, pair_files):
    sign_in(page, server)
    page.get_by_role("link", name="Submit", exact=True).click()
    page.get_by_label("Left image").set_input_files(pair_files["left_ppm"])
    thumb = page.get_by_alt_text("chosen left file: left.ppm")
    expect(thumb).to_be_visible()
    assert thumb.evaluate("img => [img.naturalWidth, img.naturalHeight]") == [64, 48]
    bad = {"name": "notes.ppm", "mimeType": "image/x-portable-pixmap", "buffer": b"P6 nonsense"}
    page.get_by_label("Right image").set_input_files(bad)
    expect(page.locator('.field-error[data-field="right"]')).to_contain_text("notes.ppm")


def test_a_job_names_its_files_warns_and_explains_what_it_shows(
    page: Page, server, pair_files, screenshots
):
    """A ground truth without its scale (inferred, and the page says so), a label, the list's
    columns, the repair count explained, the parameters folded away."""
    sign_in(page, server)
    page.get_by_role("link", name="Submit", exact=True).click()
    page.get_by_label("Left image").set_input_files(pair_files["left_ppm"])
    page.get_by_label("Right image").set_input_files(pair_files["right_ppm"])
    page.get_by_label("Solver").select_option("exact")
    page.get_by_label("Label (optional)").fill("synthetic, scale inferred")
    page.get_by_text("Ground truth (optional)").click()
    expect(page.get_by_label("Ground-truth scale")).to_have_value("")  # no silent 1
    page.get_by_label("Ground truth", exact=True).set_input_files(pair_files["ground_truth_x16"])
    expect(page.get_by_alt_text("chosen right file: right.ppm")).to_be_visible()
    screenshots(page, "submit-filled")
    page.get_by_role("button", name="Submit").click()
    page.wait_for_url(re.compile(r"#/job/[0-9a-f]{32}$"))
    job_id = page.url.rsplit("/", 1)[1]
    expect(page.get_by_role("heading", name="synthetic, scale inferred")).to_be_visible()
    expect(page.get_by_label("warnings")).to_contain_text("inferred 16")
    expect(page.get_by_label("metrics")).to_contain_text("RMSE", timeout=RESULT_TIMEOUT)
    facts = page.locator(".kv").first
    expect(facts).to_contain_text("scale 16 (inferred from the views)")
    expect(facts).to_contain_text("left.ppm · right.ppm")
    expect(page.locator("#repaired-note")).to_contain_text("not a valid label encoding")
    expect(page.locator("pre.params")).to_be_hidden()  # folded: it used to fill half the page
    screenshots(page, "job")
    page.get_by_text("Parameters (JSON)", exact=True).click()
    expect(page.locator("pre.params")).to_be_visible()
    page.get_by_role("link", name="Jobs", exact=True).click()
    row = page.locator(f'tr[data-job="{job_id}"]')
    expect(row.locator("td.job-name a")).to_have_text("synthetic, scale inferred")
    expect(row.locator('td[data-label="RMSE · BPP"]')).to_contain_text(" px · ")
    expect(row.locator('td[data-label="Duration"]')).to_contain_text(" s")
    expect(row.locator('td[data-label="QPU"]')).to_have_text("—")  # exact is not metered


def test_swapped_views_warn_on_the_job_page(page: Page, server, pair_files):
    sign_in(page, server)
    page.get_by_role("link", name="Submit", exact=True).click()
    page.get_by_label("Left image").set_input_files(pair_files["right"])
    page.get_by_label("Right image").set_input_files(pair_files["left"])
    page.get_by_label("Solver").select_option("exact")
    page.get_by_role("button", name="Submit").click()
    page.wait_for_url(re.compile(r"#/job/[0-9a-f]{32}$"))
    warning = page.get_by_label("warnings")
    expect(warning).to_contain_text("the views look swapped")
    expect(warning).to_contain_text("pass the left view first")


def test_a_job_lists_the_ids_of_its_d_wave_problems(page: Page, server, pair_files):
    """What finds a job's problems on Leap: their SAPI ids, as the task reports record them
    (written here as a QPU worker would), folded away under the solver usage."""
    import redis

    from shared.config import Settings
    from workers.embedded_redis import EMBEDDED_URL_FILE
    from workers.records import ChunkReport
    from workers.store import JobStore

    sign_in(page, server)
    job_id = submit_pair(page, pair_files, "exact")
    url = (server.data_dir / EMBEDDED_URL_FILE).read_text().strip()
    store = JobStore(redis.Redis.from_url(url), Settings(redis_url=url))
    ids = ["5f0c9a2e-0d7e-4b47-9e11-7a1c2b3d4e5f", "0b1c2d3e-4f50-6172-8394-a5b6c7d8e9f0"]
    expect(page.locator(".downloads")).to_be_visible(timeout=RESULT_TIMEOUT)  # it finished
    report = ChunkReport(level=0, bundles=1, wall_time=0.1, problem_ids=ids)
    store.record_chunk(job_id, "qpu-task", report)
    page.reload()
    summary = page.get_by_text("D-Wave problems (2): ids on Leap")
    expect(summary).to_be_visible()
    summary.click()
    expect(page.get_by_label("D-Wave problem ids")).to_have_text("\n".join(ids))
