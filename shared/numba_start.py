"""numba's start without SciPy, for the thread that preloads the kernels
(:func:`shared.kernels.preload`).

Why: numba's first compile or cache load sets up its target, whose ``numba.np.arraymath`` asks
``ensure_blas()`` whether ``scipy.linalg.cython_blas`` imports (0.2 s of CPU with SciPy's own
imports), and ``import numba`` tries ``import scipy`` for a version check. Both take an
ImportError as "no SciPy": the only effect is that ``np.correlate`` / ``np.convolve`` in
jitted code (none of ours) use numba's own loop instead of BLAS' dot; ``np.dot`` and
``np.linalg`` ask ``ensure_blas()`` again when they are compiled, in whichever thread compiles
them. Other threads import SciPy as usual meanwhile.
"""

from __future__ import annotations

import contextlib
import importlib.machinery
import sys
import threading
from collections.abc import Iterator, Sequence
from types import ModuleType


class _NoScipy:
    """A ``sys.meta_path`` finder refusing SciPy and its submodules to one thread."""

    def __init__(self, thread: int) -> None:
        self.thread = thread

    def find_spec(
        self, name: str, path: Sequence[str] | None, target: ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        if threading.get_ident() == self.thread and name.partition(".")[0] == "scipy":
            raise ModuleNotFoundError(f"{name}: not imported by numba's preload", name=name)
        return None  # the other finders decide


@contextlib.contextmanager
def without_scipy() -> Iterator[None]:
    """SciPy unimportable in the calling thread for the block (a module already imported
    stays usable). ``sys.meta_path`` is replaced, never changed in place: another thread may be
    iterating the old list in an import."""
    finder = _NoScipy(threading.get_ident())
    sys.meta_path = [finder, *sys.meta_path]
    try:
        yield
    finally:
        sys.meta_path = [f for f in sys.meta_path if f is not finder]
