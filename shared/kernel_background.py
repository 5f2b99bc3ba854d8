"""``qhsm match`` in a terminal without compiled kernels builds them in the background, once:
``qhsm build-kernels`` (:mod:`shared.kernel_build`) in a detached process at the lowest
priority, so that the next runs start about a second of CPU sooner (Aloe: 3.8 s instead of
4.7 s; docs/benchmarks.md).

Never in scripts, CI or the service (stdin or stderr not a terminal, ``CI`` set,
``QHSM_BUILD_KERNELS=never``), without a C compiler (``numba.pycc`` needs one), while another
build runs (an exclusive ``flock`` on ``build.lock`` in the cache folder, handed to the build
and released by the system when it ends, however it ends), nor after a build of this source
failed (a marker named after :func:`shared.kernels.module_name`: an upgrade tries again).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import traceback
from collections.abc import Mapping
from pathlib import Path
from typing import IO

import shared
from shared import kernels

#: In the cache folder: held (``flock``) by the build running, and where its output goes.
LOCK = "build.lock"
LOG = "build.log"


def failed_marker(directory: Path) -> Path:
    """The file saying a build of this source failed (kept beside the modules)."""
    return directory / f"{kernels.module_name()}.failed"


def built(directory: Path) -> bool:
    """Whether a module for this source is in ``directory`` (loaded or not)."""
    return any(directory.glob(f"{kernels.module_name()}.*.*"))  # not the .failed marker


def c_compiler(environ: Mapping[str, str] = os.environ) -> str | None:
    """The C compiler ``numba.pycc`` would call, if it is on the PATH: setuptools' Unix compiler
    takes ``$CC``, else Python's own build ``CC`` (sysconfig)."""
    from shared.kernel_build import compiler_command

    command = compiler_command(environ)
    return shutil.which(command[0]) if command else None


def interactive() -> bool:
    """Whether someone is watching: stdin and stderr are terminals."""
    try:
        return all(stream is not None and stream.isatty() for stream in (sys.stdin, sys.stderr))
    except ValueError:  # a closed stream
        return False


def reason_not_to_build(
    directory: Path, *, terminal: bool, environ: Mapping[str, str] = os.environ
) -> str | None:
    """Why no background build starts here, or None when one may (cheapest checks first: the
    setting imports pydantic-settings, which ``qhsm match`` otherwise does not need)."""
    if os.name != "posix":
        return "not POSIX (the lock is an flock)"
    if not terminal:
        return "not a terminal"
    if environ.get("CI"):
        return "CI"
    if failed_marker(directory).exists():
        return f"a build of this source failed ({failed_marker(directory)})"
    if c_compiler(environ) is None:
        return "no C compiler"
    from shared.settings import get_settings

    if get_settings().build_kernels == "never":
        return "QHSM_BUILD_KERNELS=never"
    return None


def _lock(directory: Path) -> int | None:
    """An open descriptor of ``build.lock`` holding its exclusive lock, or None when a build
    holds it."""
    import fcntl

    directory.mkdir(parents=True, exist_ok=True)
    descriptor = os.open(directory / LOCK, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(descriptor)
        return None
    return descriptor


def start(directory: Path, stream: IO[str] | None = None) -> subprocess.Popen[bytes] | None:
    """Start the build detached (its own session, output to ``build.log``), unless one runs
    or this source's module or failure marker appeared meanwhile; say so on ``stream``."""
    descriptor = _lock(directory)
    if descriptor is None:
        return None
    try:
        if built(directory) or failed_marker(directory).exists():
            return None
        root = str(Path(shared.__file__).resolve().parents[1])  # the source this process runs
        path = os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p)
        log = directory / LOG
        with log.open("wb") as output:
            process = subprocess.Popen(
                [sys.executable, "-m", "shared.kernel_background", str(directory)],
                stdin=subprocess.DEVNULL,
                stdout=output,
                stderr=subprocess.STDOUT,
                cwd=directory,
                env={**os.environ, "PYTHONPATH": path},
                start_new_session=True,  # no SIGINT / SIGHUP from this terminal
                pass_fds=(descriptor,),  # the lock lives as long as the build
            )
    finally:
        os.close(descriptor)
    print(
        f"qhsm: building the compiled kernels in the background, once (log: {log})",
        file=stream or sys.stderr,
    )
    return process


def start_if_missing() -> subprocess.Popen[bytes] | None:
    """:func:`start` when this process has no compiled module and nothing says not to; a
    cache folder it cannot write is no reason to fail the match."""
    if kernels.compiled_module() is not None:
        return None
    directory = kernels.cache_directory()
    if reason_not_to_build(directory, terminal=interactive()) is not None:
        return None
    try:
        return start(directory)
    except OSError:
        return None


def build_recording_failure(directory: Path | None = None) -> Path:
    """:func:`shared.kernel_build.build`, leaving the failure marker if it fails (so no
    background build retries this source) and removing it when it succeeds; the packages'
    byte code first (:func:`shared.bytecode.compile_packages`: no compiler needed)."""
    from shared.bytecode import compile_packages
    from shared.kernel_build import build

    compile_packages()
    directory = directory or kernels.cache_directory()
    directory.mkdir(parents=True, exist_ok=True)
    try:
        target = build(directory)
    except Exception:  # not a Ctrl-C of `qhsm build-kernels`
        failed_marker(directory).write_text(traceback.format_exc())
        raise
    failed_marker(directory).unlink(missing_ok=True)
    return target


def main(directory: str) -> int:
    """The detached build: lowest priority, then :func:`build_recording_failure`."""
    os.nice(19)  # the CPU only when nothing else wants it
    print(f"wrote {build_recording_failure(Path(directory))}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
