"""Issue 10's API breaks seen by clients: a wrong key's message says where the key came from;
the API's docs pages load nothing from another host."""

from __future__ import annotations

import shutil

import pytest
from api_helpers import LEFT

from api.client import Client, ClientError
from tests.fresh_thread import in_fresh_thread

# --- 13. a wrong key's message says where the key came from -----------------------------------

WRONG_KEY = "qhsm_0badc0de_" + "y" * 43


def unauthorized_message(client: Client) -> str:
    with pytest.raises(ClientError) as raised:
        client.status("0123456789abcdef0123456789abcdef")
    client.close()
    assert ": 401: " in str(raised.value)
    return str(raised.value)


def test_a_wrong_key_says_it_came_from_the_key_option(live_api):
    client = Client(live_api.url, key=WRONG_KEY, key_source="the --key option")
    message = unauthorized_message(client)
    assert "invalid or revoked API key" in message
    assert "the key came from the --key option" in message


def test_a_wrong_key_says_it_came_from_the_environment(live_api, monkeypatch):
    monkeypatch.setenv("QHSM_API_KEY", WRONG_KEY)
    message = unauthorized_message(Client(live_api.url))
    assert "the key came from the QHSM_API_KEY environment variable" in message


def test_a_wrong_key_names_the_key_file_it_came_from(live_api, monkeypatch, tmp_path):
    monkeypatch.delenv("QHSM_API_KEY", raising=False)
    monkeypatch.setenv("QHSM_DATA_DIR", str(tmp_path))
    message = unauthorized_message(Client(live_api.url))
    assert "no API key was sent" in message and str(tmp_path / "api-key") in message
    (tmp_path / "api-key").write_text(WRONG_KEY + "\n")
    message = unauthorized_message(Client(live_api.url))
    assert f"the key came from the file {tmp_path / 'api-key'}" in message


def test_qhsm_submit_with_a_wrong_key_names_the_option(live_api, tmp_path, capsys):
    from shared.cli import main

    for name in ("l.png", "r.png"):
        (tmp_path / name).write_bytes(LEFT)
    left, right = str(tmp_path / "l.png"), str(tmp_path / "r.png")
    code = main(["submit", left, right, "--url", live_api.url, "--key", WRONG_KEY])
    assert code != 0
    assert "the key came from the --key option" in capsys.readouterr().err


# --- 15. /docs works offline ------------------------------------------------------------------


@pytest.mark.parametrize("path", ["/docs", "/redoc"])
def test_docs_pages_load_nothing_from_another_host(api, path):
    import re

    html = api.get(path).text
    urls = re.findall(r"""(?:src|href|url)\s*[=:]\s*['"]([^'"]+)['"]""", html)
    assert urls, html
    for url in urls:
        assert url.startswith("/"), f"{path} loads {url}"
        assert api.get(url).status_code == 200, url
    assert "http://" not in html and "https://" not in html


CHROMIUM = shutil.which("chromium")


@pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium (apt-get install chromium)")
def test_swagger_ui_renders_with_the_internet_blocked(live_api):
    sync_playwright = pytest.importorskip("playwright.sync_api").sync_playwright

    outside: list[str] = []

    def only_local(route):
        if route.request.url.startswith(live_api.url):
            route.continue_()
        else:
            outside.append(route.request.url)
            route.abort()

    def swagger_operations() -> list[str]:
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=CHROMIUM)
            try:
                page = browser.new_page()
                page.route("**/*", only_local)
                page.goto(f"{live_api.url}/docs")
                page.wait_for_selector(".opblock", timeout=15_000)
                return page.locator(".opblock-summary-path").all_inner_texts()
            finally:
                browser.close()

    operations = in_fresh_thread(swagger_operations)
    assert "/v1/jobs/{job_id}/disparity" in [text.replace("\u200b", "") for text in operations]
    assert outside == []
