"""The kernels written in C (``chains_native.c``, ``median_native.c``, ``volume_native.c``): one
shared library built beside the compiled module by ``qhsm build-kernels``
(:mod:`shared.kernel_build`, :func:`compile_library`) and loaded by :mod:`shared.kernels`
(:func:`load`), whose bindings (:mod:`shared.chains_native`, :mod:`shared.median_native`,
:mod:`shared.volume_native`) call it in place of numba's chain and least-cost kernels and
OpenCV's weighted median, with the same results bit for bit. Without a C compiler nothing
changes: numba's kernels and OpenCV's filter run.
"""

from __future__ import annotations

import ctypes
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Final

SOURCES: Final = tuple(
    Path(__file__).with_name(f"{name}_native.c") for name in ("chains", "median", "volume")
)
#: No fused multiply-adds (numba's and OpenCV's floats); GNU C for the vector extensions.
FLAGS: Final = ("-O3", "-std=gnu11", "-ffp-contract=off", "-fPIC", "-shared", "-Wno-psabi")
#: The numba kernels it stands in for (a build of either builds it).
KERNELS: Final = ("_chains_windows", "least_costs")
#: What a library must define to be loaded (one built from older sources lacks some).
SYMBOLS: Final = (
    "qhsm_chains_windows", "qhsm_median_weights", "qhsm_weighted_median", "qhsm_least_costs",
)  # fmt: skip


def compile_library(compiler: Sequence[str], target: Path, cpu: str) -> Path:
    """Compile :data:`SOURCES` into the shared library ``target`` (atomically) for ``cpu`` (GCC's
    and Clang's ``-march``; a compiler without that level gets the generic target: the same
    floats, narrower vectors).

    Parameters
    ----------
    compiler : sequence of str
        The C compiler's command (``$CC`` or Python's build ``CC``).
    target : pathlib.Path
        The library's path.
    cpu : str
        An x86-64 level (``x86-64-v3``) or ``""``: no ``-march``.

    Returns
    -------
    pathlib.Path
        ``target``.
    """
    import shlex  # a build's imports, not a match's
    import subprocess
    import tempfile

    with tempfile.TemporaryDirectory(dir=target.parent) as scratch:
        built = Path(scratch) / target.name
        attempts = ([f"-march={cpu}"], []) if cpu else ([],)
        for attempt, march in enumerate(attempts, start=1):
            sources = [str(source) for source in SOURCES]
            command = [*compiler, *FLAGS, *march, *sources, "-o", str(built), "-lm"]
            done = subprocess.run(command, capture_output=True, text=True, check=False)
            if done.returncode == 0:
                break
            if attempt == len(attempts):
                raise RuntimeError(f"{shlex.join(command)} failed:\n{done.stderr}")
        os.replace(built, target)  # a process loading it sees all or nothing
    return target


def load(path: Path) -> ctypes.CDLL | None:
    """The library at ``path``, or None when there is none or it does not load (built for
    another machine, damaged, without one of :data:`SYMBOLS`)."""
    if not path.exists():
        return None
    try:
        library = ctypes.CDLL(str(path))
        for symbol in SYMBOLS:
            getattr(library, symbol)
    except (OSError, AttributeError):
        return None
    return library
