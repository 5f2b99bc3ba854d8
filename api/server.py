"""The API's HTTP server for ``qhsm serve`` / ``qhsm demo``: its listening socket bound up front
(a busy port fails before Redis and workers start) and uvicorn in a background thread."""

from __future__ import annotations

import errno
import logging
import math
import os
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from types import FrameType
from typing import TYPE_CHECKING

from shared.config import Settings

log = logging.getLogger("qhsm.api")

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


#: Seconds beyond ``api_shutdown_seconds`` for uvicorn's own shutdown and the cleanup.
STOP_MARGIN = 2.0
_stopping = threading.Event()


def stoppable_server(
    settings: Settings, log_level: str, cleanup: Callable[[], object] = lambda: None
) -> uvicorn.Server:
    """uvicorn serving the API, stopped within seconds of SIGTERM or Ctrl-C whatever is in
    flight: uvicorn waits ``api_shutdown_seconds`` for requests to finish and then cancels
    them, but a sync route's thread (a large upload being decoded) cannot be cancelled and
    held the process (the loop waits for it, the interpreter joins it). So the signal also arms
    :func:`stop_after`: ``STOP_MARGIN`` s later ``cleanup`` runs and the process exits."""
    import uvicorn

    from api.app import create_app

    class StoppableServer(uvicorn.Server):
        def handle_exit(self, sig: int, frame: FrameType | None) -> None:
            super().handle_exit(sig, frame)
            stop_after(settings.api_shutdown_seconds + STOP_MARGIN, cleanup)

    config = uvicorn.Config(
        create_app(settings),
        host=settings.api_host,
        port=settings.api_port,
        log_level=log_level,
        timeout_graceful_shutdown=math.ceil(settings.api_shutdown_seconds),
    )
    return StoppableServer(config)


def stop_after(seconds: float, cleanup: Callable[[], object]) -> None:
    """In ``seconds`` (once per process, from a daemon thread): ``cleanup``, then exit at once,
    whatever threads are still running (a normal exit before then makes this moot). A cleanup
    the main thread already began (``qhsm serve`` stopping its workers, up to their 15 s warm
    shutdown) is not a stuck process: it is waited for, without the warning."""
    if _stopping.is_set():
        return
    _stopping.set()

    def stop() -> None:
        time.sleep(seconds)
        if not (isinstance(cleanup, Once) and cleanup.started.is_set()):
            log.warning("still running %g s after the stop signal: exiting now", seconds)
        try:
            cleanup()  # a run under way: returns once it has finished
        finally:
            logging.shutdown()
            os._exit(0)

    threading.Thread(target=stop, name="qhsm-stop", daemon=True).start()


class Once:
    """``action`` that runs at most once whoever calls it (the main thread or the stop); a
    second caller waits until the first one's run has finished; ``started`` once one began."""

    def __init__(self, action: Callable[[], object]) -> None:
        self.action = action
        self.started = threading.Event()
        self._lock = threading.Lock()

    def __call__(self) -> None:
        with self._lock:
            if not self.started.is_set():
                self.started.set()
                self.action()


def once(action: Callable[[], object]) -> Once:
    """:class:`Once` of ``action``."""
    return Once(action)


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
            timeout_graceful_shutdown=math.ceil(self.settings.api_shutdown_seconds),
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
