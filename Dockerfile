# One image for every role; the role is the command (see docker-compose.yml):
#   qhsm api --host 0.0.0.0                     the HTTP API
#   celery -A workers worker -Q exact,sa        a worker bound to some queues
#   celery -A workers flower                    Flower (the compose profile "monitoring")
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    QHSM_DATA_DIR=/data

WORKDIR /app
COPY pyproject.toml README.md constraints.txt ./
COPY shared ./shared
COPY api ./api
COPY workers ./workers
# the versions CI passed with (constraints.txt; .ci/refresh-constraints rewrites it)
RUN pip install ".[gurobi,monitoring]" -c constraints.txt \
    && useradd --create-home --uid 10001 qhsm \
    && mkdir -p /data \
    && chown qhsm /data
# The matcher's kernels compiled ahead of time (`qhsm build-kernels`, into the qhsm user's cache),
# so that processes start without numba's set-up. The compiler goes again; should the build fail,
# the image still works with the kernels just-in-time (the same maps).
RUN apt-get update -qq \
    && apt-get install -y -qq --no-install-recommends gcc libc6-dev \
    && (su qhsm -c "qhsm build-kernels" || echo "qhsm build-kernels failed: kernels stay just-in-time") \
    && apt-get purge -y -qq gcc libc6-dev && apt-get autoremove -y -qq \
    && rm -rf /var/lib/apt/lists/*

USER qhsm
VOLUME ["/data"]
EXPOSE 8000
CMD ["qhsm", "api", "--host", "0.0.0.0", "--port", "8000"]
