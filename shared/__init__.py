"""qhsm core: quantum-hybrid stereo matching as MRF -> QUBO over a spatial pyramid.

No Redis, Celery or HTTP here; the service in ``api/`` and ``workers/`` only distributes it.
"""

import os

# Large arrays without numpy's MADV_HUGEPAGE hint (unless the environment says otherwise; read at
# numpy's import, so this precedes it): where the kernel compacts memory on such a fault
# (transparent_hugepage/defrag "madvise", Debian's default), Aloe's `qhsm match` spent 3-6 s of
# system time in page faults for no user-time gain (docs/benchmarks.md, "Huge pages").
os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")

#: qhsm's version, the one place it is written (pyproject.toml reads it at install).
__version__ = "0.1.0"
