"""What the web tests do on the page again and again: sign in, submit a pair."""

from __future__ import annotations

import re

from playwright.sync_api import Page, expect

RESULT_TIMEOUT = 60_000  # ms: the exact solver on a 64x48 pair takes well under a second


def sign_in(page: Page, server, key: str | None = None) -> None:
    """Open the page through a `#key=` address (what `qhsm serve` prints when it makes the
    key) and accept its question whose account that is (unless the tab is already that user)."""
    page.goto(f"{server.url}/#key={key or server.admin_key}")
    # a tab signed in as someone else shows both (its user, and the question)
    asked = page.locator("#view-switch:visible").or_(page.locator("#who:visible"))
    expect(asked.first).to_be_visible()
    if page.locator("#view-switch").is_visible():
        page.locator("#switch-accept").click()
    expect(page.locator("#who")).to_be_visible()


def submit_pair(
    page: Page, pair_files, solver: str, *, ground_truth: bool = False, tags: str = ""
) -> str:
    """Fill and send the submit form; the id of the job the page then shows."""
    page.get_by_role("link", name="Submit", exact=True).click()
    page.get_by_label("Left image").set_input_files(pair_files["left"])
    page.get_by_label("Right image").set_input_files(pair_files["right"])
    page.get_by_label("Solver").select_option(solver)
    page.get_by_label("Max disparity (px)").fill("8")
    if tags:
        page.get_by_label("Tags (optional)").fill(tags)
    if ground_truth:
        page.get_by_text("Ground truth (optional)").click()
        page.get_by_label("Ground truth", exact=True).set_input_files(pair_files["ground_truth"])
    page.get_by_role("button", name="Submit").click()
    page.wait_for_url(re.compile(r"#/job/[0-9a-f]{32}$"))
    return page.url.rsplit("/", 1)[1]
