"""The API's HTTP server for ``qhsm serve`` / ``qhsm demo``: its listening socket bound up front
(a busy port fails before Redis and workers start) and uvicorn in a background thread."""

from __future__ import annotations

import errno
import socket
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

from shared.config import Settings

if TYPE_CHECKING:
    import uvicorn  # imported when the thread starts (the CLI's start-up stays light)


def bind_api_socket(host: str, port: int) -> socket.socket:
    """Bind the API's listening socket now, so a busy port fails before anything starts."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as error:
        sock.close()
        reason = "is in use" if error.errno == errno.EADDRINUSE else f"cannot be bound: {error}"
        raise PortBusyError(
            f"port {port} on {host} {reason} (another `qhsm serve`?); pass --port or set "
            "QHSM_API_PORT"
        ) from None
    sock.listen(2048)
    sock.set_inheritable(True)
    return sock


class PortBusyError(RuntimeError):
    """The API port is taken."""


@dataclass
class ApiThread:
    """The API served by uvicorn in a background thread (``qhsm demo``, the benchmark)."""

    settings: Settings
    log_level: str = "warning"
    server: uvicorn.Server | None = None
    thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        return f"http://{self.settings.api_host}:{self.settings.api_port}"

    def start(self, timeout: float = 30.0) -> ApiThread:
        import uvicorn

        from api.app import create_app

        config = uvicorn.Config(
            create_app(self.settings),
            host=self.settings.api_host,
            port=self.settings.api_port,
            log_level=self.log_level,
        )
        self.server = server = uvicorn.Server(config)
        self.thread = threading.Thread(target=server.run, daemon=True)
        self.thread.start()
        deadline = time.monotonic() + timeout
        while not server.started:
            if not self.thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError(f"the API did not start on {self.url} (is the port taken?)")
            time.sleep(0.02)
        return self

    def join(self) -> None:
        if self.thread:
            self.thread.join()

    def stop(self) -> None:
        if self.server is not None:
            self.server.should_exit = True
        if self.thread:
            self.thread.join(10)
        self.server = self.thread = None
