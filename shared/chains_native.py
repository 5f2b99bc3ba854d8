"""The chain kernel in C with vectors (``chains_native.c``, built and loaded by
:mod:`shared.native`): :mod:`shared.kernels` calls it in place of ``_chains_windows`` when the
arguments fit. The same labels and energies bit for bit, about 2x faster on Aloe's grids
(docs/benchmarks.md, "The chain kernel in C"). The chain primal step's neighbour costs of a
window grid likewise (``_neighbour_costs``, the same floats, 2x faster). Without a C compiler
nothing changes: numba's kernels run.
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


_NEIGHBOUR_ARGUMENTS = (
    _POINTER, _POINTER, _POINTER, ctypes.c_double, ctypes.c_double, _POINTER, ctypes.c_int,
    ctypes.c_int64, ctypes.c_int64, ctypes.c_int64, _POINTER,
)  # fmt: skip


class NativeNeighbourCosts:
    """``_neighbour_costs`` (same arguments, same result) of a window grid from the loaded
    library; any other grid is left to numba."""

    def __init__(self, library: ctypes.CDLL) -> None:
        self.function = library.qhsm_neighbour_costs_windows
        self.function.argtypes = _NEIGHBOUR_ARGUMENTS
        self.function.restype = ctypes.c_int

    def __call__(
        self,
        candidates: np.ndarray,
        first: np.ndarray,
        windows: bool,
        weight_h: np.ndarray,
        weight_v: np.ndarray,
        slope: float,
        truncation: float,
        labels: np.ndarray,
        vertical: bool,
        out: np.ndarray,
    ) -> object:
        """None once ``out`` is written, or NotImplemented for candidates that are not windows
        or arrays whose shapes do not agree (numba's kernel then)."""
        height, width, count = out.shape
        if (
            not windows
            or first.shape != (height, width)
            or labels.shape != (height, width)
            or weight_h.shape != (height, max(width - 1, 0))
            or weight_v.shape != (max(height - 1, 0), width)
        ):
            return NotImplemented
        status = self.function(
            first.ctypes.data, weight_h.ctypes.data, weight_v.ctypes.data, slope, truncation,
            labels.ctypes.data, int(vertical), height, width, count, out.ctypes.data,
        )  # fmt: skip
        if status == 2:
            raise MemoryError("no memory for the neighbour costs' table")
        return None
