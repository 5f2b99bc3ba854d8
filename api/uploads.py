"""Validation of job uploads. Every problem becomes an ``UploadError`` (its kind a 4xx
``api.errors.Refusal``) with a message that says what is wrong and what to do; nothing a client
sends can cause a 5xx."""

from __future__ import annotations

import io
import json
import math
import re
import tokenize
from typing import IO, Any, Protocol

import cv2
import imagesize
import numpy as np
from numpy.lib import format as npy_format
from pydantic import ValidationError

from api.errors import AdmissionError, Refusal, ServiceError
from shared.config import MatchConfig, Settings
from shared.datasets.calibration import CalibrationError, calibration_text
from shared.images import PFM_HEADER, ImageError, check_pair, decode_image, is_pfm, read_pfm
from workers.records import Cameras

NPY_MAGIC = b"\x93NUMPY"
#: Largest .npy header read (numpy's own default); anything longer is not a disparity map.
NPY_MAX_HEADER = 10_000
#: Signatures of the other accepted formats (PNG, JPEG, TIFF, BMP, PBM/PGM/PPM), whose header
#: sizes imagesize reads.
IMAGE_SIGNATURES = (
    b"\x89PNG\r\n\x1a\n",
    b"\xff\xd8",
    b"II*\x00",
    b"MM\x00*",
    b"BM",
    *(f"P{kind}".encode() for kind in range(1, 7)),
)


#: Longest job label (characters).
MAX_LABEL = 200
#: A job's tags: at most this many, each of these characters (letters, digits, ``.``, ``_``,
#: ``-``, at most 40).
MAX_TAGS = 10
TAG = re.compile(r"^[A-Za-z0-9._-]{1,40}$")
#: Longest file name kept for display (characters).
MAX_NAME = 120


class Upload(Protocol):
    """An uploaded file as the service reads it (FastAPI's ``UploadFile`` is one)."""

    @property
    def filename(self) -> str | None: ...

    @property
    def file(self) -> IO[bytes]: ...


class UploadError(AdmissionError):
    """An upload or its ``params`` refused: what is wrong with which form field."""


def one_line(text: str | None, limit: int = MAX_LABEL) -> str:
    """``text`` as one line of printable characters (control characters become spaces),
    stripped and cut to ``limit``: what job lists show."""
    if not text:
        return ""
    printable = "".join(char if char.isprintable() else " " for char in text)
    return " ".join(printable.split())[:limit]


def parse_tags(text: str | None) -> list[str]:
    """The ``tags`` form field (comma-separated) as a sorted list without repeats;
    ``UploadError`` naming a bad one."""
    tags = sorted({tag.strip() for tag in (text or "").split(",") if tag.strip()})
    bad = [tag for tag in tags if not TAG.fullmatch(tag)]
    if bad:
        raise UploadError(
            Refusal.INVALID,
            f"tags: {bad[0][:60]!r} is not a tag (1-40 letters, digits, '.', '_' or '-')",
        )
    if len(tags) > MAX_TAGS:
        raise UploadError(Refusal.INVALID, f"tags: {len(tags)} given, at most {MAX_TAGS}")
    return tags


def display_name(filename: str | None) -> str:
    """An upload's file name without any folder a client sent, for display only (the file is
    never stored under it)."""
    return one_line(re.split(r"[/\\]", filename or "")[-1], MAX_NAME)


def read_upload(upload: Upload, name: str, settings: Settings) -> bytes:
    """The file's bytes, refusing anything above ``Settings.max_upload_bytes``."""
    limit = settings.max_upload_bytes
    data = upload.file.read(limit + 1)
    if len(data) > limit:
        raise UploadError(
            Refusal.TOO_LARGE,
            f"{name}: the file is larger than the limit of {limit} bytes "
            "(QHSM_MAX_UPLOAD_BYTES); send a smaller image",
        )
    return data


def declared_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) as the file's header declares them, read without decoding any pixel;
    None when the format is not one whose header we can read."""
    match = PFM_HEADER.match(data[:256])  # imagesize has no PFM
    if match:
        return int(match.group(2)), int(match.group(3))
    if not data.startswith(IMAGE_SIGNATURES):
        return None
    width, height = imagesize.get(io.BytesIO(data), exif_rotation=False)  # (-1, -1): unreadable
    return (width, height) if width >= 0 and height >= 0 else None


def check_pixels(width: int, height: int, name: str, settings: Settings) -> None:
    pixels = width * height
    if pixels > settings.max_image_pixels:
        raise UploadError(
            Refusal.TOO_LARGE,
            f"{name}: {width}x{height} = {pixels} pixels is above the limit of "
            f"{settings.max_image_pixels} (QHSM_MAX_IMAGE_PIXELS); downsample the pair first",
        )


def decode_view(data: bytes, name: str, settings: Settings) -> np.ndarray:
    """One view decoded, within the configured pixel limit.

    The limit is checked on the size the header declares before anything is decoded, so a small
    file that declares a huge image (a decompression bomb) costs neither time nor memory;
    formats whose header cannot be read that way are refused.
    """
    size = declared_size(data) if data else None
    if data and size is None:
        raise UploadError(
            Refusal.UNSUPPORTED,
            f"{name}: not a readable image (supported: PNG, PPM/PGM, JPEG, PFM, TIFF, BMP)",
        )
    if size is not None:
        check_pixels(*size, name, settings)
    try:
        image = decode_image(data, name)
    except ImageError as error:
        raise UploadError(Refusal.UNSUPPORTED, str(error)) from None
    except cv2.error:  # OpenCV's own checks (e.g. a header it reads differently)
        raise UploadError(Refusal.UNSUPPORTED, f"{name}: the image cannot be decoded") from None
    check_pixels(image.shape[1], image.shape[0], name, settings)
    return image


def decode_pair(left: bytes, right: bytes, settings: Settings) -> tuple[np.ndarray, np.ndarray]:
    left_image = decode_view(left, "left", settings)
    right_image = decode_view(right, "right", settings)
    try:
        check_pair(left_image, right_image)
    except ImageError as error:
        raise UploadError(Refusal.INVALID, str(error)) from None
    return left_image, right_image


def decode_ground_truth(data: bytes, shape: tuple[int, int]) -> np.ndarray:
    """Stored ground-truth values (disparity x gt_scale; 0 = unknown) from PNG/PGM/PFM/npy."""
    name = "ground_truth"
    if not data:
        raise UploadError(Refusal.INVALID, f"{name}: the file is empty")
    values: np.ndarray | None
    if data.startswith(NPY_MAGIC):
        values = read_npy(data, shape)
    else:
        size = declared_size(data)  # checked before decoding, as for the views
        if size is None:
            raise UploadError(
                Refusal.UNSUPPORTED,
                f"{name}: not a readable disparity map (send PNG/PGM, PFM or .npy)",
            )
        if (size[1], size[0]) != shape:
            raise UploadError(
                Refusal.INVALID,
                f"{name} is {size[0]}x{size[1]} but the views are "
                f"{shape[1]}x{shape[0]}: send the left view's ground truth at full size",
            )
        try:
            if is_pfm(data):  # the header scale is the byte order only, not a factor
                values = read_pfm(data, name)
            else:
                values = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        except (cv2.error, ImageError):
            values = None
    if values is None or not isinstance(values, np.ndarray) or values.ndim not in (2, 3):
        raise UploadError(
            Refusal.UNSUPPORTED,
            f"{name}: not a readable disparity map (send PNG/PGM, PFM or .npy)",
        )
    if values.ndim == 3:
        values = values[:, :, 0]
    if values.dtype.kind not in "uif":
        raise UploadError(Refusal.UNSUPPORTED, f"{name}: unsupported values {values.dtype}")
    if values.shape != shape:
        raise UploadError(
            Refusal.INVALID,
            f"{name} is {values.shape[1]}x{values.shape[0]} but the views are "
            f"{shape[1]}x{shape[0]}: send the left view's ground truth at full size",
        )
    values = values.astype(np.float32)
    return np.where(np.isfinite(values), values, 0.0).astype(np.float32)


def read_npy(data: bytes, shape: tuple[int, int]) -> np.ndarray:
    """A .npy ground truth, its header checked before any array is allocated: numbers only (no
    pickles), the views' size, and as many bytes as the header announces."""
    name = "ground_truth"
    stream = io.BytesIO(data)
    try:
        version = npy_format.read_magic(stream)
    except ValueError as error:
        raise UploadError(
            Refusal.UNSUPPORTED,
            f"{name}: not a readable .npy file ({error}); save it with numpy.save",
        ) from None
    readers = {
        (1, 0): npy_format.read_array_header_1_0,
        (2, 0): npy_format.read_array_header_2_0,
    }
    if version not in readers:
        raise UploadError(
            Refusal.UNSUPPORTED,
            f"{name}: not a readable .npy file (version {version[0]}.{version[1]} is not "
            "supported); save it with numpy.save",
        )
    try:
        header = readers[version](stream, max_header_size=NPY_MAX_HEADER)
    except (ValueError, SyntaxError, TypeError, tokenize.TokenError, RecursionError) as error:
        # numpy tokenizes and literal-evaluates the header: what it raises on one that does
        # not parse
        raise UploadError(
            Refusal.INVALID,
            f"{name}: not a readable .npy file, its header does not parse ({error}); save it "
            "with numpy.save",
        ) from None
    dims, fortran_order, dtype = header
    if dtype.hasobject or dtype.kind not in "uif" or dtype.subdtype is not None:
        raise UploadError(
            Refusal.UNSUPPORTED,
            f"{name}: unsupported values {dtype} (send integers or floats)",
        )
    if len(dims) not in (2, 3) or tuple(dims[:2]) != shape:
        described = "x".join(map(str, dims[1::-1] if len(dims) >= 2 else dims)) or "a scalar"
        raise UploadError(
            Refusal.INVALID,
            f"{name} is {described} but the views are {shape[1]}x{shape[0]}: "
            "send the left view's ground truth at full size",
        )
    if len(dims) == 3 and not 1 <= dims[2] <= 4:  # (h, w, 0) holds no value at all
        raise UploadError(
            Refusal.INVALID,
            f"{name} has {dims[2]} channels per pixel (shape {tuple(dims)}): send one "
            "disparity per pixel, an array of shape (height, width)",
        )
    count = math.prod(dims)
    if len(data) - stream.tell() < count * dtype.itemsize:
        raise UploadError(
            Refusal.INVALID,
            f"{name}: the .npy file is truncated (its header announces {count} values)",
        )
    values = np.frombuffer(data, dtype=dtype, count=count, offset=stream.tell())
    return values.reshape(dims, order="F" if fortran_order else "C")


def _finite_number(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"{text} is out of range")
    return value


def _no_constant(name: str) -> float:
    raise ValueError(f"{name} is not a number this service accepts")


#: Longest ``params`` form field: a job's config is kept in its record, rewritten at every step.
MAX_PARAMS_CHARS = 64 * 1024


def parse_config(params: str | None) -> MatchConfig:
    """``params`` JSON (MatchConfig fields, as for ``qhsm match``) -> a validated config."""
    if params is None or not params.strip():
        return MatchConfig.model_validate({})  # every field from the default preset
    if len(params) > MAX_PARAMS_CHARS:
        raise UploadError(
            Refusal.INVALID,
            f"params: {len(params)} characters, above the limit of {MAX_PARAMS_CHARS}; send "
            "only the MatchConfig fields you change",
        )
    try:
        raw: Any = json.loads(params, parse_float=_finite_number, parse_constant=_no_constant)
    except json.JSONDecodeError as error:
        raise UploadError(
            Refusal.MALFORMED, f"params: not valid JSON ({error.msg} at {error.pos})"
        ) from None
    except ValueError as error:  # NaN, Infinity or a float that overflows (1e400)
        raise UploadError(Refusal.INVALID, f"params: {error}; numbers must be finite") from None
    except RecursionError:
        raise UploadError(
            Refusal.INVALID,
            "params: nested too deeply; send the MatchConfig fields as a flat JSON object",
        ) from None
    if not isinstance(raw, dict):
        raise UploadError(
            Refusal.INVALID,
            'params: expected a JSON object such as {"solver": "exact", "max_disparity": 16}',
        )
    try:
        return MatchConfig.model_validate(raw)
    except RecursionError:
        raise UploadError(Refusal.INVALID, "params: nested too deeply") from None
    except ValidationError as error:
        problems = "; ".join(
            f"{'.'.join(map(str, e['loc']))}: {e['msg']}" if e["loc"] else e["msg"]
            for e in error.errors()
        )
        raise UploadError(Refusal.INVALID, f"params: {problems}") from None


#: A ground truth's scale: stored value per disparity pixel. Outside this range the scaled
#: errors lose all precision or overflow (an infinite RMSE).
GT_SCALE_RANGE = (1e-3, 1e6)
#: Widest ignored frame, pixels (above any image side the pixel limit allows evaluating).
MAX_GT_BORDER = 10_000


#: Largest calibration file read at submit (a Middlebury calib.txt is ~200 bytes, KITTI's ~1 KB).
MAX_CALIB_BYTES = 64 * 1024


def cameras_of(
    focal: float | None,
    baseline: float | None,
    doffs: float | None,
    calib: Upload | None = None,
) -> Cameras | None:
    """The cameras given at submit: a calibration file (Middlebury's calib.txt or KITTI's), or
    focal and baseline together (doffs optional), or none of them."""
    if calib is not None:
        if focal is not None or baseline is not None or doffs is not None:
            raise ServiceError(
                Refusal.INVALID, "give either calib or focal/baseline/doffs, not both"
            )
        data = calib.file.read(MAX_CALIB_BYTES + 1)
        if len(data) > MAX_CALIB_BYTES:
            raise ServiceError(
                Refusal.TOO_LARGE, f"calib: above {MAX_CALIB_BYTES} bytes; not a calibration file"
            )
        try:
            calibration = calibration_text(data.decode("utf-8"), "calib")
            return Cameras.of(calibration)
        except (UnicodeDecodeError, CalibrationError, ValidationError) as error:
            reason = "not UTF-8 text" if isinstance(error, UnicodeDecodeError) else str(error)
            if isinstance(error, ValidationError):
                reason = "calib: its focal length and baseline must be > 0"
            raise ServiceError(Refusal.INVALID, reason) from None
    if focal is None and baseline is None:
        if doffs is not None:
            raise ServiceError(Refusal.INVALID, "doffs needs focal and baseline")
        return None
    if focal is None or baseline is None:
        raise ServiceError(
            Refusal.INVALID, "depth needs both focal (px) and baseline; one of them is missing"
        )
    return Cameras(focal=focal, baseline=baseline, doffs=doffs or 0.0)
