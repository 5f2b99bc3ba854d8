"""A cost volume's least costs per pixel in C with vectors (``volume_native.c``, built and
loaded by :mod:`shared.native`): :mod:`shared.kernels` calls it in place of numba's
``least_costs`` when the arguments fit. The same values and disparities bit for bit, 3.6x
faster on Aloe's volume with AVX2 (docs/benchmarks.md, "The weighted median on every core, the
confidence's least costs in vectors, ...").
"""

from __future__ import annotations

import ctypes

import numpy as np

_POINTER = ctypes.c_void_p
_INT = ctypes.c_int64


class NativeLeastCosts:
    """``least_costs`` (same arguments, same result) from the loaded library."""

    def __init__(self, library: ctypes.CDLL) -> None:
        self.function = library.qhsm_least_costs
        self.function.argtypes = (_POINTER, _POINTER, _POINTER, _INT, _INT, _INT, _INT)
        self.function.restype = ctypes.c_int

    def __call__(self, volume: np.ndarray, values: np.ndarray, indices: np.ndarray) -> object:
        """None once ``values`` and ``indices`` hold each pixel's least costs; NotImplemented
        (numba's kernel then) when the shapes do not agree or too many costs are kept."""
        count, rows, width = volume.shape
        if values.shape != indices.shape or values.shape[1:] != (rows, width):
            return NotImplemented
        status = self.function(
            volume.ctypes.data, values.ctypes.data, indices.ctypes.data, count, rows, width,
            values.shape[0],
        )  # fmt: skip
        return None if status == 0 else NotImplemented
