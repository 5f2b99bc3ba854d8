"""What a finished job keeps, in Redis: the part of :class:`workers.store.JobStore` that holds
the result (the full-resolution disparity and the maps beside it) and the views the web page
shows next to it; both expire with the job's record.

Keys (under ``{key_prefix}:``; see :mod:`workers.store` for the rest):

    job:{id}:result        hash of the disparity and the maps (``map:validity``,
                           ``map:confidence``), in bounded pieces (:mod:`workers.bounded`)
    job:{id}:view:{name}   the left view (``left.png``) and the ground truth
"""

from __future__ import annotations

import json

import numpy as np

from workers.arrays import array_fields, array_from, from_npy
from workers.bounded import piece_bytes, read_hash, write_hash
from workers.redis_client import as_bytes
from workers.store_base import StoreBase


class ResultStorage(StoreBase):
    """The result and the views of a job (mixed into ``JobStore``)."""

    def save_result(
        self, job_id: str, disparity: np.ndarray, maps: dict[str, np.ndarray] | None = None
    ) -> None:
        """The full-resolution disparity and the maps beside it (``validity``,
        ``confidence``), in bounded pieces of one hash (:mod:`workers.bounded`)."""
        piece = piece_bytes(self.limit)
        fields = array_fields("disparity", disparity, piece=piece)
        for name, array in (maps or {}).items():
            fields |= array_fields(f"map:{name}", array, piece=piece)
        key = self.key("job", job_id, "result")
        write_hash(self.redis, key, fields, self.limit, self.ttl, "the job's result")

    def _result_array(self, job_id: str, name: str) -> np.ndarray | None:
        """One array of the result hash, reading only its own fields (None: absent)."""
        key = self.key("job", job_id, "result")
        header = self.redis.hget(key, name)
        if header is None:
            return None
        names = [name, *(f"{name}:{n}" for n in range(json.loads(header)["pieces"]))]
        fields = read_hash(self.redis, key, self.limit, names)
        return array_from(fields, name) if len(fields) == len(names) else None

    def load_map(self, job_id: str, name: str) -> np.ndarray | None:
        """A map saved beside the result (None: the job has none, or it expired)."""
        return self._result_array(job_id, f"map:{name}")

    def load_result(self, job_id: str) -> np.ndarray | None:
        key = self.key("job", job_id, "result")
        if self.redis.type(key) == b"string":  # written whole by an earlier version
            data = self.redis.get(key)
            return None if data is None else from_npy(as_bytes(data))
        return self._result_array(job_id, "disparity")

    # views ------------------------------------------------------------------------------------

    def save_view(self, job_id: str, name: str, data: bytes) -> None:
        """Keep ``data`` for the job's web view; it expires with the result once the job ends."""
        self.redis.set(self.key("job", job_id, "view", name), data, ex=self.view_ttl)

    def load_view(self, job_id: str, name: str) -> bytes | None:
        data = self.redis.get(self.key("job", job_id, "view", name))
        return None if data is None else as_bytes(data)
