"""The chain kernel in C with vectors (``chains_native.c``): built beside the compiled module by
``qhsm build-kernels`` (:mod:`shared.kernel_build`, :func:`compile_library`), loaded by
:mod:`shared.kernels` (:func:`load`), which calls it in place of ``_chains_windows`` when the
arguments fit. The same labels and energies bit for bit, about 2x faster on Aloe's grids
(docs/benchmarks.md, "The chain kernel in C"). Without a C compiler nothing changes: numba's
kernel runs.
"""

from __future__ import annotations

import ctypes
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Final

import numpy as np

SOURCE: Final = Path(__file__).with_name("chains_native.c")
#: No fused multiply-adds (numba's floats); GNU C for the vector extensions.
FLAGS: Final = ("-O3", "-std=gnu11", "-ffp-contract=off", "-fPIC", "-shared", "-Wno-psabi")

_POINTER = ctypes.c_void_p
_ARGUMENTS = (
    _POINTER, ctypes.c_double, _POINTER, ctypes.c_double, _POINTER, _POINTER, ctypes.c_double,
    ctypes.c_double, _POINTER, ctypes.c_int, ctypes.c_int64, ctypes.c_int64, ctypes.c_int64,
    _POINTER,
)  # fmt: skip


def compile_library(compiler: Sequence[str], target: Path, cpu: str) -> Path:
    """Compile :data:`SOURCE` into the shared library ``target`` (atomically) for ``cpu`` (GCC's
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
            command = [*compiler, *FLAGS, *march, str(SOURCE), "-o", str(built)]
            done = subprocess.run(command, capture_output=True, text=True, check=False)
            if done.returncode == 0:
                break
            if attempt == len(attempts):
                raise RuntimeError(f"{shlex.join(command)} failed:\n{done.stderr}")
        os.replace(built, target)  # a process loading it sees all or nothing
    return target


class NativeChains:
    """``_chains_windows`` (same arguments, same result) from the loaded library."""

    def __init__(self, library: ctypes.CDLL) -> None:
        self.function = library.qhsm_chains_windows
        self.function.argtypes = _ARGUMENTS
        self.function.restype = ctypes.c_int

    def __call__(
        self,
        base: np.ndarray,
        scale: float,
        extra: np.ndarray,
        sign: float,
        first: np.ndarray,
        weight: np.ndarray,
        slope: float,
        truncation: float,
        labels: np.ndarray,
        turned: bool,
    ) -> np.ndarray | None:
        """Each chain's optimum (its labels into ``labels``), or None when the arrays' shapes
        do not agree or the window is wider than the library's buffer (numba's kernel then)."""
        chains, length, count = base.shape
        if (
            extra.shape != base.shape
            or first.shape != (chains, length)
            or weight.shape != (chains, max(length - 1, 0))
            or labels.shape != ((length, chains) if turned else (chains, length))
        ):
            return None
        energies = np.empty(chains)
        status = self.function(
            base.ctypes.data, scale, extra.ctypes.data, sign, first.ctypes.data,
            weight.ctypes.data, slope, truncation, labels.ctypes.data, int(turned), chains,
            length, count, energies.ctypes.data,
        )  # fmt: skip
        if status == 2:
            raise MemoryError("no memory for the chain kernel's messages")
        return energies if status == 0 else None


def load(path: Path) -> NativeChains | None:
    """The library at ``path``, or None when there is none or it does not load (built for
    another machine, damaged)."""
    if not path.exists():
        return None
    try:
        return NativeChains(ctypes.CDLL(str(path)))
    except (OSError, AttributeError):
        return None
