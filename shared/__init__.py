"""qhsm core: quantum-hybrid stereo matching as MRF -> QUBO over a spatial pyramid.

No Redis, Celery or HTTP here; the service in ``api/`` and ``workers/`` only distributes it.
"""

__version__ = "0.1.0"
