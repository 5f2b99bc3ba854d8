"""The kernels written in C (``chains_native.c``, ``median_native.c``, ``volume_native.c``), each
built into a shared library beside the compiled module by ``qhsm build-kernels``
(:mod:`shared.kernel_build`, :func:`compile_library`) and loaded by :mod:`shared.kernels`
(:func:`load`), whose bindings (:mod:`shared.chains_native`, :mod:`shared.median_native`,
:mod:`shared.volume_native`) call them in place of numba's chain, neighbour-cost and
least-cost kernels and OpenCV's weighted median, with the same results bit for bit. Without a
C compiler nothing changes: numba's kernels and OpenCV's filter run.
"""

from __future__ import annotations

import ctypes
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Final, NamedTuple


class Library(NamedTuple):
    """One C source built into a shared library of its own."""

    source: Path
    #: Libraries it links (after the source).
    links: tuple[str, ...]
    #: What it must define to be loaded (one built from older sources may lack some).
    symbols: tuple[str, ...]


def _source(name: str) -> Path:
    return Path(__file__).with_name(f"{name}_native.c")


#: Each source in a library of its own: built together in one, the chain kernel's loops moved and
#: its real calls took 3-10 % longer (docs/benchmarks.md, "The weighted median on every core");
#: alone, its library is the very file measured before.
LIBRARIES: Final = {
    "chains": Library(
        _source("chains"), (), ("qhsm_chains_windows", "qhsm_neighbour_costs_windows")
    ),
    "median": Library(_source("median"), ("-lm",), ("qhsm_median_weights", "qhsm_weighted_median")),
    "volume": Library(_source("volume"), (), ("qhsm_least_costs",)),
}
#: No fused multiply-adds (numba's and OpenCV's floats); GNU C for the vector extensions.
FLAGS: Final = ("-O3", "-std=gnu11", "-ffp-contract=off", "-fPIC", "-shared", "-Wno-psabi")
#: The numba kernels they stand in for (a build of either builds them).
KERNELS: Final = ("_chains_windows", "_neighbour_costs", "least_costs")


def compile_library(compiler: Sequence[str], target: Path, cpu: str, name: str) -> Path:
    """Compile library ``name`` of :data:`LIBRARIES` into ``target`` (atomically) for ``cpu``
    (GCC's and Clang's ``-march``; a compiler without that level gets the generic target: the
    same floats, narrower vectors).

    Parameters
    ----------
    compiler : sequence of str
        The C compiler's command (``$CC`` or Python's build ``CC``).
    target : pathlib.Path
        The library's path.
    cpu : str
        An x86-64 level (``x86-64-v3``) or ``""``: no ``-march``.
    name : str
        A key of :data:`LIBRARIES`.

    Returns
    -------
    pathlib.Path
        ``target``.
    """
    import shlex  # a build's imports, not a match's
    import subprocess
    import tempfile

    library = LIBRARIES[name]
    with tempfile.TemporaryDirectory(dir=target.parent) as scratch:
        built = Path(scratch) / target.name
        attempts = ([f"-march={cpu}"], []) if cpu else ([],)
        for attempt, march in enumerate(attempts, start=1):
            command = [
                *compiler, *FLAGS, *march, str(library.source), "-o", str(built), *library.links
            ]  # fmt: skip
            done = subprocess.run(command, capture_output=True, text=True, check=False)
            if done.returncode == 0:
                break
            if attempt == len(attempts):
                raise RuntimeError(f"{shlex.join(command)} failed:\n{done.stderr}")
        os.replace(built, target)  # a process loading it sees all or nothing
    return target


def load(path: Path, name: str) -> ctypes.CDLL | None:
    """Library ``name`` at ``path``, or None when there is none or it does not load (built for
    another machine, damaged, without one of its symbols)."""
    if not path.exists():
        return None
    try:
        library = ctypes.CDLL(str(path))
        for symbol in LIBRARIES[name].symbols:
            getattr(library, symbol)
    except (OSError, AttributeError):
        return None
    return library
