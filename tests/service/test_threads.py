"""Worker processes get their share of the cores for the native thread pools (shared/threads.py):
a worker of N pool processes gives each cores / N threads, the control worker (which runs alone
between levels) every core."""

from __future__ import annotations

from pathlib import Path

import pytest

from shared.threads import THREAD_VARIABLES, thread_budget

pytestmark = pytest.mark.service


def environment(pid: int) -> dict[str, str]:
    raw = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
    return dict(item.decode().split("=", 1) for item in raw if b"=" in item)


def test_each_pool_process_gets_its_share_of_the_cores(workers):
    main = workers["main"]  # 2 pool processes
    for pid in [main.pid, *main.children()]:
        env = environment(pid)
        # cores / 2 (or the OMP_NUM_THREADS the tests run with)
        assert {env[name] for name in THREAD_VARIABLES} == {str(thread_budget(2))}
    control = environment(workers["control"].pid)  # 1 process
    assert {control[name] for name in THREAD_VARIABLES} == {str(thread_budget(1))}
