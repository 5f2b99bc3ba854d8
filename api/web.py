"""The lab's web page at ``/``: static HTML, CSS and JavaScript modules from ``api/web`` (no build
step, nothing loaded from elsewhere). The page signs in with an API key and calls the /v1 API."""

from __future__ import annotations

import os
from pathlib import Path

from fastapi import FastAPI
from fastapi.responses import FileResponse, Response
from fastapi.staticfiles import StaticFiles
from starlette.types import Scope

WEB_DIR = Path(__file__).parent / "web"
#: Everything the page loads comes from this origin; nothing else may run or be fetched.
CONTENT_SECURITY_POLICY = (
    "default-src 'self'; img-src 'self' blob: data:; style-src 'self'; script-src 'self'; "
    "connect-src 'self'; frame-ancestors 'none'; base-uri 'none'; form-action 'none'"
)
HEADERS = {
    "Content-Security-Policy": CONTENT_SECURITY_POLICY,
    "Referrer-Policy": "no-referrer",
    "Cache-Control": "no-cache",
}
#: Browsers run a module script only when it is served as JavaScript; the platform's table of
#: types (on Windows, the registry) is not trusted to say so.
JAVASCRIPT = "text/javascript; charset=utf-8"


class WebFiles(StaticFiles):
    """The page's files, revalidated on every load (a 304 when unchanged), so that a browser never
    runs a mix of an old and a new server's modules."""

    def file_response(
        self,
        full_path: str | os.PathLike[str],
        stat_result: os.stat_result,
        scope: Scope,
        status_code: int = 200,
    ) -> Response:
        response = super().file_response(full_path, stat_result, scope, status_code)
        response.headers["Cache-Control"] = "no-cache"
        if isinstance(response, FileResponse) and str(full_path).endswith(".js"):
            response.headers["Content-Type"] = JAVASCRIPT
        return response


def mount(app: FastAPI) -> None:
    """Serve the page at ``/`` and its files under ``/web/``."""

    @app.get("/", include_in_schema=False)
    def index() -> FileResponse:
        return FileResponse(WEB_DIR / "index.html", headers=HEADERS)

    app.mount("/web", WebFiles(directory=WEB_DIR), name="web")
