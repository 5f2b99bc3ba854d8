"""``qhsm match`` in a terminal without compiled kernels starts one detached build (issue 28,
item 3), and only there: not in scripts or CI, not without a compiler, not while another build
runs, not again after this source's build failed."""

from __future__ import annotations

import fcntl
import io
import os
import subprocess
import sys
import time

import pytest

from shared import kernel_background, kernels

#: A terminal's environment with a compiler, as far as :func:`reason_not_to_build` reads it.
READY = {"CC": sys.executable}  # any executable on the PATH stands for the compiler here


@pytest.fixture
def auto(monkeypatch):
    monkeypatch.setenv("QHSM_BUILD_KERNELS", "auto")  # the tests' conftest says never


def test_a_terminal_with_a_compiler_builds(tmp_path, auto):
    assert kernel_background.reason_not_to_build(tmp_path, terminal=True, environ=READY) is None


@pytest.mark.parametrize(
    ("terminal", "environ", "reason"),
    [
        (False, READY, "not a terminal"),
        (True, {**READY, "CI": "true"}, "CI"),
        (True, {"CC": "/nonexistent/cc"}, "no C compiler"),
    ],
)
def test_scripts_ci_and_no_compiler_do_not(tmp_path, auto, terminal, environ, reason):
    found = kernel_background.reason_not_to_build(tmp_path, terminal=terminal, environ=environ)
    assert found == reason


def test_the_setting_opts_out(tmp_path, monkeypatch):
    monkeypatch.setenv("QHSM_BUILD_KERNELS", "never")
    reason = kernel_background.reason_not_to_build(tmp_path, terminal=True, environ=READY)
    assert reason == "QHSM_BUILD_KERNELS=never"


def test_a_failed_build_of_this_source_is_not_retried_but_another_source_is(
    tmp_path, auto, monkeypatch
):
    kernel_background.failed_marker(tmp_path).write_text("error")
    reason = kernel_background.reason_not_to_build(tmp_path, terminal=True, environ=READY)
    assert reason is not None and "failed" in reason
    monkeypatch.setattr(kernels, "module_name", lambda: "_qhsm_kernels_upgraded")
    assert kernel_background.reason_not_to_build(tmp_path, terminal=True, environ=READY) is None


def test_the_compiler_is_setuptools_choice():
    assert kernel_background.c_compiler({"CC": "sh -c"}) is not None  # the command's first word
    assert kernel_background.c_compiler({"CC": "no-such-compiler-here"}) is None


class _Spawned:
    """What :func:`subprocess.Popen` was asked to start."""

    def __init__(self) -> None:
        self.calls: list[tuple[list[str], dict]] = []

    def __call__(self, command: list[str], **options: object) -> _Spawned:
        self.calls.append((command, options))
        return self


def test_start_detaches_one_build_and_says_where_its_log_is(tmp_path, monkeypatch):
    spawned = _Spawned()
    monkeypatch.setattr(subprocess, "Popen", spawned)
    said = io.StringIO()
    assert kernel_background.start(tmp_path, said) is spawned
    ((command, options),) = spawned.calls
    assert command[1:] == ["-m", "shared.kernel_background", str(tmp_path)]
    assert options["start_new_session"] is True and options["stdin"] is subprocess.DEVNULL
    assert len(options["pass_fds"]) == 1  # the lock, held by the build
    assert str(tmp_path / kernel_background.LOG) in said.getvalue()
    assert said.getvalue().count("\n") == 1


def test_no_second_build_while_one_holds_the_lock(tmp_path, monkeypatch):
    spawned = _Spawned()
    monkeypatch.setattr(subprocess, "Popen", spawned)
    with (tmp_path / kernel_background.LOCK).open("w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        assert kernel_background.start(tmp_path, io.StringIO()) is None
    assert not spawned.calls
    kernel_background.failed_marker(tmp_path).write_text("error")  # finished meanwhile
    assert kernel_background.start(tmp_path, io.StringIO()) is None
    kernel_background.failed_marker(tmp_path).unlink()
    (tmp_path / f"{kernels.module_name()}.cpython-311-x86_64-linux-gnu.so").write_bytes(b"")
    assert kernel_background.start(tmp_path, io.StringIO()) is None
    assert not spawned.calls


def test_an_unwritable_cache_does_not_fail_the_match(tmp_path, auto, monkeypatch):
    monkeypatch.setattr(kernel_background, "interactive", lambda: True)
    monkeypatch.setattr(kernels, "compiled_module", lambda: None)
    monkeypatch.setenv("CC", sys.executable)
    monkeypatch.delenv("CI", raising=False)
    blocked = tmp_path / "file"
    blocked.write_text("")
    monkeypatch.setattr(kernels, "cache_directory", lambda: blocked / "kernels")
    assert kernel_background.start_if_missing() is None


def test_a_process_with_compiled_kernels_starts_nothing(monkeypatch):
    monkeypatch.setattr(kernels, "compiled_module", lambda: kernels)
    monkeypatch.setattr(kernel_background, "start", pytest.fail)
    assert kernel_background.start_if_missing() is None


def test_the_detached_build_holds_the_lock_and_marks_its_failure(tmp_path, monkeypatch):
    """A real detached build, made to fail at once (pycc finds no working compiler): it runs at
    niceness 19 in a session of its own, holds the lock while it runs, and leaves the marker."""
    monkeypatch.setenv("CC", "/bin/false")
    process = kernel_background.start(tmp_path, io.StringIO())
    assert process is not None
    assert os.getsid(process.pid) == process.pid
    time.sleep(0.5)
    assert os.getpriority(os.PRIO_PROCESS, process.pid) == 19 or process.poll() is not None
    assert kernel_background.start(tmp_path, io.StringIO()) is None  # locked while it runs
    assert process.wait(timeout=120) != 0
    assert kernel_background.failed_marker(tmp_path).exists()
    log = (tmp_path / kernel_background.LOG).read_text()
    assert "compiler" in log, log
    descriptor = os.open(tmp_path / kernel_background.LOCK, os.O_RDWR)
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)  # released with the process
    finally:
        os.close(descriptor)
