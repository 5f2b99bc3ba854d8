"""Numpy arrays in Redis: whole as .npy bytes, or as hash fields of bounded size, so that no
single write is larger than :data:`MAX_VALUE_BYTES`; images in their integer form."""

from __future__ import annotations

import io
import json
from collections.abc import Mapping

import numpy as np

from workers.redis_client import as_bytes


def npy(array: np.ndarray) -> bytes:
    """``array`` as .npy bytes (never pickled)."""
    stream = io.BytesIO()
    np.save(stream, np.ascontiguousarray(array), allow_pickle=False)
    return stream.getvalue()


def from_npy(data: bytes) -> np.ndarray:
    """The array of .npy bytes (pickles refused)."""
    return np.load(io.BytesIO(data), allow_pickle=False)


#: Largest value one write puts in Redis (each is a record of its append-only file): a level's
#: arrays are written in pieces of at most this many bytes.
MAX_VALUE_BYTES = 4 * 2**20
#: (divisor, integer type) of the images arrays are decoded from (``shared.images``: 8- and
#: 16-bit views divided by 255 or 65535; ground truths of integer values): a float32 array that
#: is exactly such integers / divisor is stored as those integers (4x or 2x smaller, checked
#: bit for bit, so lossless).
IMAGE_LEVELS = ((255.0, np.uint8), (1.0, np.uint8), (1.0, np.uint16), (65535.0, np.uint16))
#: Elements tried before the whole array (most arrays fail on the first few).
SAMPLE = 4096


def _as_integers(array: np.ndarray) -> tuple[np.ndarray, float] | None:
    """``(integers, divisor)`` whose quotient, computed as :mod:`shared.images` computes it
    (``integers.astype(float32) / divisor``), is ``array`` bit for bit; None when none is."""
    if array.dtype != np.float32 or not array.size:
        return None
    flat = array.reshape(-1)
    for divisor, kind in IMAGE_LEVELS:
        top = np.iinfo(kind).max
        for part in (flat[:SAMPLE], flat):
            scaled = np.rint(part * np.float32(divisor))
            if not (scaled.min() >= 0 and scaled.max() <= top):  # NaN fails too
                break
            integers = scaled.astype(kind)
            back = integers.astype(np.float32) / np.float32(divisor)
            if not np.array_equal(back.view(np.uint32), part.view(np.uint32)):
                break
        else:
            return integers.reshape(array.shape), divisor
    return None


def array_fields(
    name: str, array: np.ndarray, *, images: bool = False, piece: int = MAX_VALUE_BYTES
) -> dict[str, bytes]:
    """``array`` as hash fields of at most ``piece`` bytes each: ``name`` holds its
    .npy header (dtype, shape) and ``name:0``, ``name:1``, ... its bytes. Integer arrays travel
    in the narrowest dtype that holds their values (candidates are small disparities) and come
    back in their own. With ``images`` (the uploads), float32 images travel as the integers
    they were decoded from (:data:`IMAGE_LEVELS`: 4x smaller for 8-bit views; zlib on top
    took twice that time again on Tsukuba for 1.3x less, so it is not used); lossless."""
    array = np.ascontiguousarray(array)
    stored = array
    if array.dtype.kind in "iu" and array.size:
        narrow = np.promote_types(np.min_scalar_type(array.min()), np.min_scalar_type(array.max()))
        if narrow.itemsize < array.dtype.itemsize:
            stored = array.astype(narrow)
    header: dict = {"dtype": array.dtype.str, "shape": list(array.shape)}
    if images and (found := _as_integers(array)) is not None:
        stored, header["divisor"] = found
    header["stored"] = stored.dtype.str
    data = stored.tobytes()
    pieces = range(0, max(len(data), 1), piece)
    fields = {name: json.dumps({**header, "pieces": len(pieces)}).encode()}
    for number, start in enumerate(pieces):
        fields[f"{name}:{number}"] = data[start : start + piece]
    return fields


#: What :func:`array_fields` writes in a header; anything else was written by a newer version,
#: whose arrays this one cannot be trusted to read.
HEADER_KEYS = {"dtype", "stored", "shape", "pieces", "divisor"}


def array_from(fields: Mapping[bytes | str, bytes | str], name: str) -> np.ndarray:
    """The array :func:`array_fields` wrote under ``name`` (``fields``: the hash as read)."""
    header = json.loads(fields[name.encode()])
    if unknown := set(header) - HEADER_KEYS:
        raise ValueError(f"array {name!r} was stored with {sorted(unknown)}: a newer version")
    pieces = range(header["pieces"])
    data = b"".join(as_bytes(fields[f"{name}:{number}".encode()]) for number in pieces)
    stored = np.frombuffer(data, dtype=np.dtype(header["stored"])).reshape(header["shape"])
    array = stored.astype(np.dtype(header["dtype"]))
    if "divisor" in header:
        array /= np.float32(header["divisor"])
    return array
