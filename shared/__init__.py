"""qhsm core: quantum-hybrid stereo matching as MRF -> QUBO over a spatial pyramid.

No Redis, Celery or HTTP here; the service in ``api/`` and ``workers/`` only distributes it.
"""

import os

# Large arrays without numpy's MADV_HUGEPAGE hint (unless the environment says otherwise; read at
# numpy's import, so this precedes it): where the kernel compacts memory on such a fault
# (transparent_hugepage/defrag "madvise", Debian's default), Aloe's `qhsm match` spent 3-6 s of
# system time in page faults for no user-time gain (docs/benchmarks.md, "Huge pages").
os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")
# numpy's BLAS on one thread (unless the environment says otherwise; read when numpy loads it):
# qhsm's one BLAS call is the luma's 3-vector product (shared.images.to_gray), after which
# OpenBLAS's other thread spins on the core the run needs: 18 % of Tsukuba's `qhsm match` CPU,
# 7 % of Aloe's, the same bytes out (docs/benchmarks.md, "BLAS on one thread"). GOTO_NUM_THREADS,
# OpenBLAS's own name: OPENBLAS_NUM_THREADS and OMP_NUM_THREADS are the budget a user gives every
# library (shared.threads), and override it.
os.environ.setdefault("GOTO_NUM_THREADS", "1")

#: qhsm's version, the one place it is written (pyproject.toml reads it at install).
__version__ = "0.1.0"
