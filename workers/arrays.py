"""Numpy arrays in Redis: whole as .npy bytes, or as hash fields of bounded size (optionally
zlib-compressed), so that no single write is larger than :data:`MAX_VALUE_BYTES`."""

from __future__ import annotations

import io
import json
import zlib

import numpy as np


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
#: zlib level of the uploads: the fastest (about 20 ms and 3x smaller for an 8-bit 384x288
#: colour view as float32); they are written once per job and read once per level.
UPLOAD_COMPRESSION = 1


def array_fields(name: str, array: np.ndarray, *, compress: bool = False) -> dict[str, bytes]:
    """``array`` as hash fields of at most :data:`MAX_VALUE_BYTES` each: ``name`` holds its
    .npy header (dtype, shape) and ``name:0``, ``name:1``, ... its bytes (zlib-compressed with
    ``compress``; lossless). Integer arrays travel in the narrowest dtype that holds their
    values (candidates are small disparities) and come back in their own."""
    array = np.ascontiguousarray(array)
    stored = array
    if array.dtype.kind in "iu" and array.size:
        narrow = np.promote_types(np.min_scalar_type(array.min()), np.min_scalar_type(array.max()))
        if narrow.itemsize < array.dtype.itemsize:
            stored = array.astype(narrow)
    data = stored.tobytes()
    header = {"dtype": array.dtype.str, "stored": stored.dtype.str, "shape": list(array.shape)}
    if compress:
        data = zlib.compress(data, UPLOAD_COMPRESSION)
        header["codec"] = "zlib"
    pieces = range(0, max(len(data), 1), MAX_VALUE_BYTES)
    fields = {name: json.dumps({**header, "pieces": len(pieces)}).encode()}
    for number, start in enumerate(pieces):
        fields[f"{name}:{number}"] = data[start : start + MAX_VALUE_BYTES]
    return fields


def array_from(fields: dict[bytes, bytes], name: str) -> np.ndarray:
    """The array :func:`array_fields` wrote under ``name``."""
    header = json.loads(fields[name.encode()])
    data = b"".join(fields[f"{name}:{number}".encode()] for number in range(header["pieces"]))
    if header.get("codec") == "zlib":
        data = zlib.decompress(data)
    stored = np.frombuffer(data, dtype=np.dtype(header["stored"])).reshape(header["shape"])
    return stored.astype(np.dtype(header["dtype"]))
