"""Thread budgets (shared/threads.py): processes that share the cores never start a thread per
core each in OpenCV, OpenMP/BLAS and numba, and a count the user set wins."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading

import pytest
from hypothesis import given
from hypothesis import strategies as st

import shared.threads as threads_module
from shared.threads import (
    THREAD_VARIABLES,
    USER_VARIABLE,
    beside,
    both,
    cores,
    each_beside,
    holding_core,
    inherited_threads,
    spare_core,
    thread_budget,
    thread_environment,
)


@given(processes=st.integers(1, 64))
def test_processes_share_the_cores(processes):
    budget = thread_budget(processes, environ={})
    assert budget == max(1, cores() // processes)
    assert budget * processes <= max(cores(), processes)  # never more threads than cores


@given(user=st.integers(1, 32), processes=st.integers(1, 8))
def test_a_count_the_user_set_wins(user, processes):
    environ = {"OMP_NUM_THREADS": str(user)}
    assert thread_budget(processes, environ) == user
    child = thread_environment(1, environ)
    assert {child[name] for name in THREAD_VARIABLES} == {str(user)}
    # a child of that child still sees the user's count, not the values written for it
    assert thread_budget(processes, child) == user


def test_values_a_qhsm_parent_wrote_are_not_taken_for_the_users():
    """``qhsm serve`` itself runs with every core; its workers' pool processes get their share."""
    parent = thread_environment(cores(), environ={})
    assert parent[USER_VARIABLE] == ""
    assert thread_budget(2, parent) == max(1, cores() // 2)
    assert inherited_threads(parent) == cores()
    assert inherited_threads({"NUMBA_NUM_THREADS": "3"}) is None  # set by a user, not a parent


def test_limit_threads_sizes_opencv_and_numba_in_a_new_process():
    code = (
        "import json, cv2, numba\n"
        "from shared.threads import limit_threads, threads\n"
        "limit_threads(1)\n"
        "print(json.dumps([cv2.getNumThreads(), numba.get_num_threads(), threads()]))\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in (*THREAD_VARIABLES, USER_VARIABLE)}
    done = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    assert json.loads(done.stdout) == [1, 1, 1]


def _thread_name(fail: bool = False) -> str:
    if fail:
        raise ValueError("raised in the thread")
    return threading.current_thread().name


def test_beside_runs_on_a_spare_core_and_raises_there(monkeypatch):
    monkeypatch.setattr(threads_module, "_budget", 2)
    assert beside(_thread_name)() != threading.current_thread().name
    failed = beside(_thread_name, fail=True)
    with pytest.raises(ValueError, match="raised in the thread"):
        failed()


def test_beside_calls_now_without_a_spare_core(monkeypatch):
    monkeypatch.setattr(threads_module, "_budget", 1)  # a worker's pool process: its core alone
    assert beside(_thread_name)() == threading.current_thread().name
    with pytest.raises(ValueError, match="raised in the thread"):
        beside(_thread_name, fail=True)


@pytest.mark.parametrize("budget", [1, 2])
def test_each_beside_answers_in_order_the_first_here(monkeypatch, budget):
    """Every view's share of a step: the results in the arguments' order, the first computed
    by the caller's thread, the others on the spare core when there is one."""
    monkeypatch.setattr(threads_module, "_budget", budget)
    here = threading.current_thread().name

    def named(index: int) -> tuple[int, str]:
        return index, threading.current_thread().name

    results = each_beside(named, [(index,) for index in range(3)])
    assert [index for index, _ in results] == [0, 1, 2]
    assert results[0][1] == here
    assert all((name == here) == (budget == 1) for _, name in results[1:])


@pytest.mark.parametrize("budget", [1, 2, 3])
def test_a_core_is_spare_while_fewer_tasks_hold_one_than_the_budget_has(monkeypatch, budget):
    monkeypatch.setattr(threads_module, "_budget", budget)
    assert spare_core()
    with holding_core():
        assert spare_core() == (budget > 1)
        with holding_core():
            assert spare_core() == (budget > 2)
        assert spare_core() == (budget > 1)
    with pytest.raises(RuntimeError), holding_core():
        raise RuntimeError("a task that fails lets its core go")
    assert spare_core()


def test_both_runs_the_second_on_the_helper_and_answers_in_order():
    from concurrent.futures import ThreadPoolExecutor

    here = threading.current_thread().name
    assert both(_thread_name, _thread_name, None) == (here, here)
    with ThreadPoolExecutor(1) as helper:
        first, second = both(_thread_name, _thread_name, helper)
        assert first == here and second != here
        with pytest.raises(ValueError, match="raised in the thread"):
            both(_thread_name, lambda: _thread_name(fail=True), helper)
