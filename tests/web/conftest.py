"""Browser tests of the web page: Debian's Chromium driven by Playwright (pytest-playwright's
``page`` fixture) against a real ``qhsm serve`` subprocess: its embedded Redis in a temporary
data directory (nothing is written to any other Redis), its Celery worker, and the fake solvers
of the service tests (``tests/service/qhsm_test_plugin.py``) for a slow job.

Set QHSM_WEB_SCREENSHOTS=DIR to save a screenshot of every page there (docs/screenshots).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import httpx
import numpy as np
import pytest

pytest.importorskip("playwright", reason="playwright is not installed (pip install -e '.[dev]')")

from workers.embedded_redis import free_port

CHROMIUM = Path("/usr/bin/chromium")
SERVICE_TESTS = Path(__file__).parents[1] / "service"
sys.path.insert(0, str(SERVICE_TESTS))  # the harness
sys.path.insert(0, str(Path(__file__).parent))  # web_page
import harness  # noqa: E402

#: Seconds the fake-slow solver sleeps per bundle: a job that takes long enough to cancel.
SLOW_SECONDS = 0.5
START_TIMEOUT = 180.0  # two test processes, each starting deployments, on a busy machine


@dataclass
class Server:
    """A running `qhsm serve`: its address, the sign-in URL it printed and the admin key."""

    url: str
    sign_in_url: str
    admin_key: str
    log: Path
    data_dir: Path

    def ledger(self):
        """The QPU ledger in the server's embedded Redis (to charge time without a QPU)."""
        import redis

        from shared.config import Settings
        from workers.embedded_redis import EMBEDDED_URL_FILE
        from workers.quota import QuotaLedger

        url = (self.data_dir / EMBEDDED_URL_FILE).read_text().strip()
        return QuotaLedger(redis.Redis.from_url(url), Settings.model_fields["key_prefix"].default)

    def client(self, key: str | None = None) -> httpx.Client:
        return httpx.Client(
            base_url=self.url, headers={"Authorization": f"Bearer {key or self.admin_key}"}
        )


@pytest.fixture(scope="session")
def browser_type_launch_args(browser_type_launch_args):
    """Launch the system Chromium (Playwright's own browser download is not used)."""
    if not CHROMIUM.exists():
        pytest.skip(f"{CHROMIUM} is absent: apt-get install -y chromium (as .ci/run does)")
    return {**browser_type_launch_args, "executable_path": str(CHROMIUM)}


@pytest.fixture(scope="session")
def server(tmp_path_factory) -> Server:
    """`qhsm serve` on a free port with its own data directory and embedded Redis."""
    if not CHROMIUM.exists():
        pytest.skip(f"{CHROMIUM} is absent: apt-get install -y chromium (as .ci/run does)")
    folder = tmp_path_factory.mktemp("web-serve")
    port = free_port()
    env = dict(os.environ)
    for name in (
        "QHSM_REDIS_URL",
        "REDIS_URL",
        "QHSM_KEY_PREFIX",
        "QHSM_API_KEY",
        "QHSM_AUTH_ENABLED",
    ):
        env.pop(name, None)
    root = str(Path(__file__).parents[2])
    env["PYTHONPATH"] = os.pathsep.join([root, str(SERVICE_TESTS), env.get("PYTHONPATH", "")])
    env["QHSM_TEST_SLOW_SECONDS"] = str(SLOW_SECONDS)
    env["QHSM_INSPECT_TIMEOUT"] = "0.5"
    log = folder / "serve.log"
    command = [
        sys.executable, "-m", "shared.cli", "serve",
        "--host", "127.0.0.1", "--port", str(port),
        "--data-dir", str(folder / "data"), "--concurrency", "2",
    ]  # fmt: skip
    with log.open("wb") as out:
        process = subprocess.Popen(command, env=env, stdout=out, stderr=subprocess.STDOUT)
    with harness.killed_at_exit(process):  # no test asserts on this stop
        sign_in_url = _wait_for_sign_in_url(process, log, port)
        key = (folder / "data" / "api-key").read_text().strip()
        yield Server(f"http://127.0.0.1:{port}", sign_in_url, key, log, folder / "data")


def _wait_for_sign_in_url(process: subprocess.Popen, log: Path, port: int) -> str:
    """The `web page:` URL serve printed, once the API answers."""
    deadline = time.monotonic() + START_TIMEOUT
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"qhsm serve exited: {log.read_text()[-2000:]}")
        found = re.search(r"web page: (\S+)", log.read_text())
        if found:
            try:
                if httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=1).status_code == 200:
                    return found.group(1)
            except httpx.HTTPError:
                pass
        time.sleep(0.2)
    process.kill()
    raise RuntimeError(f"qhsm serve did not start in {START_TIMEOUT:.0f} s: {log.read_text()}")


@pytest.fixture(scope="session")
def pair_files(tmp_path_factory) -> dict[str, Path]:
    """A small synthetic pair as PNG files, its ground truth (.npy) and a wrong-size right view."""
    import cv2

    from shared.synthetic import make_scene

    folder = tmp_path_factory.mktemp("pair")
    scene = make_scene(48, 64, max_disparity=8, seed=1)
    files = {name: folder / f"{name}.png" for name in ("left", "right", "small")}
    cv2.imwrite(str(files["left"]), np.rint(scene.left * 255).astype(np.uint8))
    cv2.imwrite(str(files["right"]), np.rint(scene.right * 255).astype(np.uint8))
    cv2.imwrite(str(files["small"]), np.rint(scene.right[:40, :50] * 255).astype(np.uint8))
    files["ground_truth"] = folder / "gt.npy"
    np.save(files["ground_truth"], scene.disparity)
    files["ground_truth_x16"] = folder / "gt16.png"  # Tsukuba's convention, no scale given
    cv2.imwrite(str(files["ground_truth_x16"]), np.rint(scene.disparity * 16).astype(np.uint8))
    for name in ("left", "right"):  # Middlebury's own format, which browsers do not show
        files[f"{name}_ppm"] = folder / f"{name}.ppm"
        grey = np.rint(getattr(scene, name) * 255).astype(np.uint8)
        cv2.imwrite(str(files[f"{name}_ppm"]), cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR))
    return files


@pytest.fixture(scope="session")
def screenshots():
    """Save a full-page screenshot under QHSM_WEB_SCREENSHOTS (no-op when unset)."""
    target = os.environ.get("QHSM_WEB_SCREENSHOTS")

    def take(page, name: str) -> None:
        if target:
            Path(target).mkdir(parents=True, exist_ok=True)
            page.wait_for_timeout(300)  # let the last poll paint
            page.screenshot(path=str(Path(target) / f"{name}.png"), full_page=True)

    return take
