"""Run a call in a thread of its own, for code that needs no asyncio loop running around it.

pytest-playwright's session-scoped sync Playwright (the tests under tests/web) keeps an asyncio
loop marked as running in the test process's main thread until the session ends. Under
pytest-xdist any test file may run after those in the same process, so ``asyncio.run`` and a
second sync Playwright would fail there ("cannot be called from a running event loop"); a new
thread has no running loop.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

T = TypeVar("T")


def in_fresh_thread(function: Callable[[], T]) -> T:
    """``function()`` called in a new thread; its result returned, its exception raised here."""
    with ThreadPoolExecutor(1, thread_name_prefix="fresh") as pool:
        return pool.submit(function).result()
