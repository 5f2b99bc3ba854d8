"""Validation of job uploads. Every problem becomes an ``UploadError`` with a 4xx status and a
message that says what is wrong and what to do; nothing a client sends can cause a 5xx."""

from __future__ import annotations

import json
from typing import Any

import cv2
import numpy as np
from fastapi import UploadFile, status
from pydantic import ValidationError

from shared.config import MatchConfig, Settings
from shared.images import ImageError, check_pair, decode_image

NPY_MAGIC = b"\x93NUMPY"


class UploadError(Exception):
    def __init__(self, status_code: int, message: str):
        super().__init__(message)
        self.status_code = status_code
        self.message = message


def read_upload(upload: UploadFile, name: str, settings: Settings) -> bytes:
    """The file's bytes, refusing anything above ``Settings.max_upload_bytes``."""
    limit = settings.max_upload_bytes
    data = upload.file.read(limit + 1)
    if len(data) > limit:
        raise UploadError(
            status.HTTP_413_CONTENT_TOO_LARGE,
            f"{name}: the file is larger than the limit of {limit} bytes "
            "(QHSM_MAX_UPLOAD_BYTES); send a smaller image",
        )
    return data


def decode_view(data: bytes, name: str, settings: Settings) -> np.ndarray:
    """One view as float32 gray in [0, 1], within the configured pixel limit."""
    try:
        image = decode_image(data, name)
    except ImageError as error:
        raise UploadError(status.HTTP_415_UNSUPPORTED_MEDIA_TYPE, str(error)) from None
    pixels = image.shape[0] * image.shape[1]
    if pixels > settings.max_image_pixels:
        raise UploadError(
            status.HTTP_413_CONTENT_TOO_LARGE,
            f"{name}: {image.shape[1]}x{image.shape[0]} = {pixels} pixels is above the limit of "
            f"{settings.max_image_pixels} (QHSM_MAX_IMAGE_PIXELS); downsample the pair first",
        )
    return image


def decode_pair(left: bytes, right: bytes, settings: Settings) -> tuple[np.ndarray, np.ndarray]:
    left_image = decode_view(left, "left", settings)
    right_image = decode_view(right, "right", settings)
    try:
        check_pair(left_image, right_image)
    except ImageError as error:
        raise UploadError(status.HTTP_422_UNPROCESSABLE_CONTENT, str(error)) from None
    return left_image, right_image


def decode_ground_truth(data: bytes, shape: tuple[int, int]) -> np.ndarray:
    """Stored ground-truth values (disparity x gt_scale; 0 = unknown) from PNG/PGM/PFM/npy."""
    name = "ground_truth"
    if not data:
        raise UploadError(status.HTTP_422_UNPROCESSABLE_CONTENT, f"{name}: the file is empty")
    try:
        if data.startswith(NPY_MAGIC):
            import io

            values = np.load(io.BytesIO(data), allow_pickle=False)
        else:
            values = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except ValueError:
        values = None
    if values is None or not isinstance(values, np.ndarray) or values.ndim not in (2, 3):
        raise UploadError(
            status.HTTP_415_UNSUPPORTED_MEDIA_TYPE,
            f"{name}: not a readable disparity map (send PNG/PGM, PFM or .npy)",
        )
    if values.ndim == 3:
        values = values[:, :, 0]
    if values.dtype.kind not in "uif":
        raise UploadError(
            status.HTTP_415_UNSUPPORTED_MEDIA_TYPE, f"{name}: unsupported values {values.dtype}"
        )
    if values.shape != shape:
        raise UploadError(
            status.HTTP_422_UNPROCESSABLE_CONTENT,
            f"{name} is {values.shape[1]}x{values.shape[0]} but the views are "
            f"{shape[1]}x{shape[0]}: send the left view's ground truth at full size",
        )
    values = values.astype(np.float32)
    return np.where(np.isfinite(values), values, 0.0).astype(np.float32)


def parse_config(params: str | None) -> MatchConfig:
    """``params`` JSON (MatchConfig fields, as for ``qhsm match``) -> a validated config."""
    if params is None or not params.strip():
        return MatchConfig()
    try:
        raw: Any = json.loads(params)
    except json.JSONDecodeError as error:
        raise UploadError(
            status.HTTP_400_BAD_REQUEST, f"params: not valid JSON ({error.msg} at {error.pos})"
        ) from None
    if not isinstance(raw, dict):
        raise UploadError(
            status.HTTP_422_UNPROCESSABLE_CONTENT,
            'params: expected a JSON object such as {"solver": "exact", "max_disparity": 16}',
        )
    try:
        return MatchConfig.model_validate(raw)
    except ValidationError as error:
        problems = "; ".join(
            f"{'.'.join(map(str, e['loc'])) or 'params'}: {e['msg']}" for e in error.errors()
        )
        raise UploadError(status.HTTP_422_UNPROCESSABLE_CONTENT, f"params: {problems}") from None
