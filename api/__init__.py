"""HTTP API (FastAPI): upload stereo pairs, poll jobs, download disparity maps.

HTTP only: ``app`` builds the application from ``routes/``; ``server`` binds the API's socket and
runs uvicorn in a thread; ``cli`` holds ``qhsm serve``/``demo``/``submit`` and ``admin`` the
``qhsm admin`` commands. What ``serve`` starts beside the API (Redis, Celery workers) is
``workers.supervisor``'s."""
