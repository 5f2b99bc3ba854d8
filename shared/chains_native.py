"""The chain kernel in C with vectors (``chains_native.c``, built and loaded by
:mod:`shared.native`): :mod:`shared.kernels` calls it in place of ``_chains_windows`` when the
arguments fit. The same labels and energies bit for bit, about 2x faster on Aloe's grids
(docs/benchmarks.md, "The chain kernel in C"). Without a C compiler nothing changes: numba's
kernel runs.
"""

from __future__ import annotations

import ctypes

import numpy as np

_POINTER = ctypes.c_void_p
_ARGUMENTS = (
    _POINTER, ctypes.c_double, _POINTER, ctypes.c_double, _POINTER, _POINTER, ctypes.c_double,
    ctypes.c_double, _POINTER, ctypes.c_int, ctypes.c_int64, ctypes.c_int64, ctypes.c_int64,
    _POINTER,
)  # fmt: skip


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
    ) -> object:
        """Each chain's optimum (its labels into ``labels``) as an array of energies, or
        NotImplemented when the arrays' shapes do not agree or the window is wider than the
        library's buffer (numba's kernel then)."""
        chains, length, count = base.shape
        if (
            extra.shape != base.shape
            or first.shape != (chains, length)
            or weight.shape != (chains, max(length - 1, 0))
            or labels.shape != ((length, chains) if turned else (chains, length))
        ):
            return NotImplemented
        energies = np.empty(chains)
        status = self.function(
            base.ctypes.data, scale, extra.ctypes.data, sign, first.ctypes.data,
            weight.ctypes.data, slope, truncation, labels.ctypes.data, int(turned), chains,
            length, count, energies.ctypes.data,
        )  # fmt: skip
        if status == 2:
            raise MemoryError("no memory for the chain kernel's messages")
        return energies if status == 0 else NotImplemented
