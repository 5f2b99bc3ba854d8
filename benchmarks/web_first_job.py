"""A new user's first job through the web page: Tsukuba submitted through the page of a real
`qhsm serve` (its own embedded Redis in a temporary data directory) with a solver, the
ground-truth scale left empty and border 18; prints the time from Submit to the result shown and
what the page says, and saves the job page's screenshot (README's docs/screenshots/job-tsukuba.png).

    python benchmarks/web_first_job.py [SCREENSHOT.png] [--solver exact]

Needs Debian's chromium (/usr/bin/chromium) and Playwright for Python (the `dev` extra).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
from playwright.sync_api import expect, sync_playwright

from shared.datasets import default_middlebury_dir
from workers.embedded_redis import free_port

CHROMIUM = "/usr/bin/chromium"
START_TIMEOUT = 120.0
RESULT_TIMEOUT_MS = 900_000


def start_serve(folder: Path, port: int) -> tuple[subprocess.Popen, str]:
    """`qhsm serve` on ``port`` with its data in ``folder``, and the sign-in address it prints."""
    drop = ("QHSM_REDIS_URL", "REDIS_URL", "QHSM_API_KEY", "QHSM_DATA_DIR")
    env = {name: value for name, value in os.environ.items() if name not in drop}
    log = folder / "serve.log"
    command = [sys.executable, "-m", "shared.cli", "serve", "--port", str(port)]
    with log.open("wb") as out:
        process = subprocess.Popen(
            [*command, "--data-dir", str(folder / "data")], env=env, stdout=out, stderr=out
        )
    deadline = time.monotonic() + START_TIMEOUT
    while time.monotonic() < deadline:
        found = re.search(r"web page: (\S+)", log.read_text())
        if found:
            try:
                if httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=1).status_code == 200:
                    return process, found.group(1)
            except httpx.HTTPError:
                pass
        time.sleep(0.3)
    process.kill()
    raise RuntimeError(f"qhsm serve did not start: {log.read_text()[-2000:]}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("screenshot", nargs="?", help="save the job page here (PNG)")
    parser.add_argument("--solver", default="exact")
    args = parser.parse_args()
    scene = default_middlebury_dir() / "tsukuba"
    folder = Path(tempfile.mkdtemp(prefix="qhsm-web-first-job-"))
    serve, sign_in = start_serve(folder, free_port())
    try:
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=CHROMIUM)
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            page.goto(sign_in)
            page.get_by_role("link", name="Submit", exact=True).click()
            page.get_by_label("Left image").set_input_files(str(scene / "left.ppm"))
            page.get_by_label("Right image").set_input_files(str(scene / "right.ppm"))
            page.get_by_label("Solver").select_option(args.solver)
            page.get_by_label("Label (optional)").fill("tsukuba")
            page.get_by_text("Ground truth (optional)").click()
            truth = page.get_by_label("Ground truth", exact=True)
            truth.set_input_files(str(scene / "gt_left.pgm"))
            page.get_by_label("Ground-truth border (px)").fill("18")
            expect(page.get_by_alt_text("chosen right file: right.ppm")).to_be_visible()
            started = time.monotonic()
            page.get_by_role("button", name="Submit").click()
            result = page.get_by_alt_text("Disparity", exact=True)
            expect(result).to_be_visible(timeout=RESULT_TIMEOUT_MS)
            seconds = time.monotonic() - started
            print(f"{args.solver}: Submit to the result shown in {seconds:.1f} s")
            print(" ".join(page.locator(".metrics").inner_text().split()))
            print(" ".join(page.locator(".warnings").inner_text().split()))
            if args.screenshot:
                page.wait_for_timeout(500)
                page.screenshot(path=args.screenshot, full_page=True)
            browser.close()
    finally:
        serve.send_signal(signal.SIGINT)
        serve.wait(60)
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
