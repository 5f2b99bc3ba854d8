"""Level inputs and solved bundles in Redis: the part of :class:`workers.store.JobStore` the
level tasks use (plan, write, read and assemble one pyramid level).

Keys (under ``{key_prefix}:``; see :mod:`workers.store` for the rest):

    job:{id}:level:{k}         hash of .npy arrays: the ``LevelInputs`` a worker needs
    job:{id}:level:views:{s}   hash of .npy arrays: the images of the levels downsampled by s
    job:{id}:level:{k}:solved  hash "{first row}" -> JSON bundle result (labels, energy, timing)
    job:{id}:level:{k}:phase   what preparing the level is doing, in words (the job status's)

A level's images are read from Redis once per process and job (an LRU of :data:`IMAGES_KEPT`
jobs), since every level of a job and downsampling shares them.
"""

from __future__ import annotations

import json
from collections import OrderedDict
from collections.abc import Mapping

import numpy as np
import redis

from shared.bundles import bundle_key
from shared.level_inputs import LevelInputs
from shared.pyramid import LevelPlan
from workers.arrays import array_fields, array_from
from workers.bounded import batches, not_stored, piece_bytes, read_hash, write_hash
from workers.redis_client import as_bytes, text
from workers.store_base import StoreBase

#: Level inputs live this long at most (they are deleted as soon as the level is assembled).
LEVEL_INPUTS_GRACE = 3600
IMAGES_KEPT = 2  # jobs' level images one process keeps


class LevelInputsMissingError(LookupError):
    """The level's inputs are gone (job finished, cancelled or expired)."""


class LevelStorage(StoreBase):
    """Level inputs and solved bundles of a job's pyramid levels (mixed into ``JobStore``)."""

    _images: OrderedDict[tuple[str, str], tuple[np.ndarray, ...]]

    def save_level(self, job_id: str, inputs: LevelInputs, started: float) -> None:
        """Write a level's inputs once; every worker of the level reads them (by reference).
        In bounded commands (:mod:`workers.bounded`): :class:`DataNotStoredError` when Redis
        refuses them."""
        piece = piece_bytes(self.limit)
        fields = {
            "plan": inputs.plan.model_dump_json().encode(),
            "views": str(inputs.views).encode(),
            "started": repr(started).encode(),
            "prepared": json.dumps(inputs.prepared).encode(),
            "images": str(inputs.plan.downsample).encode(),
        }
        # a bin level's windows travel as each pixel's first candidate (K times smaller)
        arrays = (
            {"first": inputs.first}
            if inputs.first is not None
            else {"candidates": inputs.candidate_labels()}
        )
        if inputs.initial_labels is not None:
            arrays["initial_labels"] = inputs.initial_labels
        if inputs.pooled is not None:  # a coarse grid's costs (shared.coarse_grid)
            arrays["pooled"] = inputs.pooled
        if inputs.coarse_bins is not None:  # what the level's coarse-to-fine prior reads
            arrays["coarse_bins"] = inputs.coarse_bins
        for name, array in arrays.items():
            fields.update(array_fields(name, array, piece=piece))
        key = self.key("job", job_id, "level", inputs.plan.index)
        # a level's images depend on the job and the downsampling only (bin pyramid: one copy)
        images = self.key("job", job_id, "level", "views", inputs.plan.downsample)
        ttl = self.settings.task_visibility_timeout + LEVEL_INPUTS_GRACE
        what = f"the inputs of level {inputs.plan.index + 1}"
        if not self.redis.exists(images):  # once per job and downsampling
            views = {
                field: value
                for name in ("left", "right")
                for field, value in array_fields(name, getattr(inputs, name), piece=piece).items()
            }
            write_hash(self.redis, images, views, self.limit, ttl, what)
        else:
            self.redis.expire(images, ttl)
        write_hash(self.redis, key, fields, self.limit, ttl, what)

    def save_prepared(self, job_id: str, index: int, prepared: dict) -> None:
        """Record what planning the level's bundles chose (``LevelInputs.prepared``)."""
        key = self.key("job", job_id, "level", index)
        self.redis.hset(key, "prepared", json.dumps(prepared))

    def load_level(self, job_id: str, index: int) -> tuple[LevelInputs, float]:
        """The level's inputs and when the level was started (epoch seconds)."""
        fields = read_hash(self.redis, self.key("job", job_id, "level", index), self.limit)
        if not fields:
            raise LevelInputsMissingError(f"job {job_id}: inputs of level {index} are gone")
        left, right = self._level_images(job_id, fields)
        plan = LevelPlan.model_validate_json(fields[b"plan"])
        first = array_from(fields, "first") if b"first" in fields else None
        inputs = LevelInputs(
            plan=plan,
            views=int(fields[b"views"]),
            left=left,
            right=right,
            candidates=array_from(fields, "candidates") if first is None else None,
            first=first,
            initial_labels=(
                array_from(fields, "initial_labels") if b"initial_labels" in fields else None
            ),
            prepared=json.loads(fields.get(b"prepared", b"{}")),
            pooled=array_from(fields, "pooled") if b"pooled" in fields else None,
            coarse_bins=array_from(fields, "coarse_bins") if b"coarse_bins" in fields else None,
        )
        return inputs, float(fields[b"started"])

    def _level_images(
        self, job_id: str, fields: Mapping[bytes | str, bytes | str]
    ) -> tuple[np.ndarray, ...]:
        """A level's images: this process's (read-only) copy when another level of the job had
        them, else from Redis."""
        cache_key = (job_id, text(fields[b"images"]))
        if cache_key not in self._images:
            images = self.key("job", job_id, "level", "views", cache_key[1])
            stored = read_hash(self.redis, images, self.limit)
            if not stored:
                raise LevelInputsMissingError(f"job {job_id}: the images of its levels are gone")
            self._images[cache_key] = tuple(array_from(stored, n) for n in ("left", "right"))
            for image in self._images[cache_key]:  # shared by the job's levels
                image.setflags(write=False)
        self._images.move_to_end(cache_key)
        if len(self._images) > IMAGES_KEPT:
            self._images.popitem(last=False)
        return self._images[cache_key]

    def has_level(self, job_id: str, index: int) -> bool:
        return bool(self.redis.exists(self.key("job", job_id, "level", index)))

    def drop_level(self, job_id: str, index: int) -> None:
        level = self.key("job", job_id, "level", index)
        self.redis.delete(level, f"{level}:solved", f"{level}:solved:labels", f"{level}:phase")

    def set_phase(self, job_id: str, index: int, phase: str) -> None:
        """What preparing level ``index`` is doing now (:mod:`shared.activity`), e.g. its
        embedding search: shown in the job's status until the level's bundles fan out."""
        ttl = self.settings.task_visibility_timeout + LEVEL_INPUTS_GRACE
        self.redis.set(self.key("job", job_id, "level", index, "phase"), phase, ex=ttl)

    def phase(self, job_id: str, index: int) -> str | None:
        """The last :meth:`set_phase` of the level (None: none, or the level is gone)."""
        found = self.redis.get(self.key("job", job_id, "level", index, "phase"))
        return None if found is None else text(found)

    def save_bundles(self, job_id: str, index: int, bundles: list[dict]) -> None:
        """Solved bundles (JSON, keyed by first row): the fan-in assembles the level from these,
        whichever task, re-sent or redelivered, solved them (idempotent). In bounded commands:
        a bundle whose JSON is above a piece (a whole view's labels) keeps its labels in
        pieces of their own, written before the bundle (a reader that sees it finds them)."""
        if not bundles:
            return
        key = self.key("job", job_id, "level", index, "solved")
        piece = piece_bytes(self.limit)
        entries: dict[str, bytes] = {}
        labels: dict[str, bytes] = {}
        for bundle in bundles:
            name = bundle_key([*bundle["rows"], *bundle.get("columns", [0])])
            encoded = json.dumps(bundle).encode()
            if len(encoded) > piece:
                raw_labels = bundle["labels"].encode()
                parts = range(0, len(raw_labels), piece)
                for number, start in enumerate(parts):
                    labels[f"{name}:{number}"] = raw_labels[start : start + piece]
                moved = {**bundle, "labels": None, "labels_pieces": len(parts)}
                encoded = json.dumps(moved).encode()
            entries[name] = encoded
        ttl = self.settings.task_visibility_timeout + LEVEL_INPUTS_GRACE
        try:
            for target, fields in ((f"{key}:labels", labels), (key, entries)):
                for batch in batches(fields, self.limit):
                    self.redis.hset(target, mapping=batch)  # type: ignore[arg-type]
                if fields:
                    self.redis.expire(target, ttl)
        except redis.ResponseError as error:
            total = sum(map(len, entries.values())) + sum(map(len, labels.values()))
            raise not_stored(f"the solved bundles of level {index + 1}", total, error) from error

    def solved_bundles(self, job_id: str, index: int) -> dict[str, dict]:
        """The level's solved bundles by ``bundle_key`` (read in bounded replies)."""
        key = self.key("job", job_id, "level", index, "solved")
        found = {
            text(name): json.loads(value)
            for name, value in read_hash(self.redis, key, self.limit).items()
        }
        for name, bundle in found.items():
            if "labels_pieces" in bundle:
                names = [f"{name}:{number}" for number in range(bundle.pop("labels_pieces"))]
                parts = read_hash(self.redis, f"{key}:labels", self.limit, names)
                joined = b"".join(as_bytes(parts[n.encode()]) for n in names)
                bundle["labels"] = joined.decode("ascii")
        return found

    def solved_rows(self, job_id: str, index: int) -> set[str]:
        """``bundle_key`` of the level's solved bundles (without their labels)."""
        return {
            text(key) for key in self.redis.hkeys(self.key("job", job_id, "level", index, "solved"))
        }

    def solved_count(self, job_id: str, index: int) -> int:
        return int(self.redis.hlen(self.key("job", job_id, "level", index, "solved")))
