"""Image and disparity-map I/O. Everything crossing this module's boundary inward is float32.

Views are float32 in [0, 1] whatever their bit depth (8/16-bit PNG, PPM/PGM, JPEG, float PFM),
gray (h, w) or colour (h, w, 3) in OpenCV's BGR order; :func:`to_gray` gives Rec. 709 luma.
Disparity maps are written as Middlebury PFM (float32), 16-bit PNG
(disparity x 256, the KITTI convention: 0 only for invalid pixels, above 255.996 px refused) or
``.npy``.
"""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np

from shared.threads import each_beside

#: Rec. 709 luma weights for (R, G, B).
REC709 = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
#: 16-bit PNG disparity maps store disparity x this factor.
PNG_DISPARITY_SCALE = 256.0
DISPARITY_SUFFIXES = (".pfm", ".png", ".npy")
#: A PFM header: "PF" (colour) or "Pf" (gray), width, height, scale, then one whitespace byte.
PFM_HEADER = re.compile(rb"^(P[Ff])\s+(\d+)\s+(\d+)\s+([-+]?[0-9.]+(?:[eE][-+]?\d+)?)\s")


#: The largest disparity a 16-bit PNG holds (65535 / 256 px).
PNG_MAX_DISPARITY = 65535 / PNG_DISPARITY_SCALE


class ImageError(ValueError):
    """An input image cannot be used; the message names the file and the problem."""


class DisparityFormatError(ValueError):
    """A disparity map the requested format cannot hold (a 16-bit PNG above 255.996 px)."""


def decode_image(data: bytes, name: str) -> np.ndarray:
    """Decode image bytes to a float32 view in [0, 1]: (h, w) gray or (h, w, 3) BGR colour.

    Colour is kept (the accurate data term and the weighted median read it); alpha is dropped.
    ``name`` is only used in errors.

    Parameters
    ----------
    data : bytes
        The encoded file.
    name : str
        What to call the file in errors.

    Returns
    -------
    numpy.ndarray
        The view, float32 in [0, 1], (h, w) gray or (h, w, 3) BGR.

    Raises
    ------
    ImageError
        If the bytes are empty, not an image, or of an unsupported type or layout.
    """
    if not data:
        raise ImageError(f"{name}: the file is empty")
    if is_pfm(data):
        return to_unit_range(read_pfm(data, name), name)
    raw = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise ImageError(
            f"{name}: not a readable image (supported: PNG, PPM/PGM, JPEG, PFM, TIFF, BMP)"
        )
    return to_unit_range(raw, name)


def is_pfm(data: bytes) -> bool:
    """Whether ``data`` starts like a PFM file (``PF`` or ``Pf`` and a newline or space)."""
    return data[:2] in (b"PF", b"Pf") and data[2:3].isspace()


def read_pfm(data: bytes, name: str = "PFM") -> np.ndarray:
    """The values of a PFM file exactly as stored: (h, w) or (h, w, 3) BGR float32, top row first.

    The header's scale says the byte order by its sign (negative: little-endian) and nothing
    else: its magnitude is ignored, as Middlebury's SDK reads it. OpenCV divides the values by
    it instead, so a Middlebury 2014 ground truth with scale -0.003922 would be 255x too large.

    Raises
    ------
    ImageError
        If the header is not PFM's or the file is shorter than the header says.
    """
    header = PFM_HEADER.match(data[:256])
    if header is None:
        raise ImageError(f"{name}: not a PFM file (its header is not 'Pf|PF width height scale')")
    kind, width, height, scale = header.groups()
    channels = 3 if kind == b"PF" else 1
    columns, rows = int(width), int(height)
    try:
        order = "<" if float(scale) < 0 else ">"
    except ValueError:
        raise ImageError(f"{name}: PFM scale {scale!r} is not a number") from None
    count = columns * rows * channels
    body = data[header.end() :]
    if columns == 0 or rows == 0 or len(body) < 4 * count:
        raise ImageError(
            f"{name}: the PFM header announces {columns}x{rows}x{channels} floats but the file "
            f"holds {len(body) // 4}"
        )
    values = np.frombuffer(body, dtype=f"{order}f4", count=count).astype(np.float32)
    image = values.reshape(rows, columns, channels)[::-1]  # stored bottom row first
    if channels == 1:
        return np.ascontiguousarray(image[:, :, 0])
    return np.ascontiguousarray(image[:, :, ::-1])  # RGB as stored, BGR as OpenCV gives


def load_view(path: str | Path) -> np.ndarray:
    """Read the image file ``path`` as a float32 view in [0, 1], colour kept, as
    :func:`decode_image` does; a missing or unusable file is an :class:`ImageError`."""
    path = Path(path)
    if not path.is_file():
        raise ImageError(f"{path}: no such file")
    return decode_image(path.read_bytes(), str(path))


def load_image(path: str | Path) -> np.ndarray:
    """Read the image file ``path`` (any :func:`load_view` reads) as (h, w) float32 grayscale in
    [0, 1]."""
    return to_gray(load_view(path))


def to_unit_range(raw: np.ndarray, name: str = "image") -> np.ndarray:
    """An OpenCV-decoded array (BGR order, any depth) as float32 in [0, 1], gray or BGR.

    Parameters
    ----------
    raw : numpy.ndarray
        uint8, uint16 or float pixels, 1, 3 or 4 channels.
    name : str, optional
        What to call the image in errors.

    Returns
    -------
    numpy.ndarray
        float32 in [0, 1]: (h, w) from one channel, (h, w, 3) BGR from three or four.

    Raises
    ------
    ImageError
        If the image is empty or of an unsupported type or layout.
    """
    if raw.size == 0 or raw.shape[0] == 0 or raw.shape[1] == 0:
        raise ImageError(f"{name}: the image has no pixels")
    if raw.dtype == np.uint8:
        scaled = raw.astype(np.float32) / 255.0
    elif raw.dtype == np.uint16:
        scaled = raw.astype(np.float32) / 65535.0
    elif raw.dtype in (np.float32, np.float64):
        scaled = np.nan_to_num(raw.astype(np.float32))
        high = float(scaled.max()) if scaled.size else 0.0
        if high > 1.0:  # float images in 0..255 (or larger): normalise by the range used
            scaled = scaled / high
        scaled = np.clip(scaled, 0.0, 1.0)
    else:
        raise ImageError(f"{name}: unsupported pixel type {raw.dtype}")
    if scaled.ndim == 2:
        return np.ascontiguousarray(scaled)
    if scaled.ndim == 3 and scaled.shape[2] in (3, 4):
        return np.ascontiguousarray(scaled[:, :, :3])
    if scaled.ndim == 3 and scaled.shape[2] == 1:
        return np.ascontiguousarray(scaled[:, :, 0])
    raise ImageError(f"{name}: unsupported image layout {raw.shape}")


def to_gray(view: np.ndarray) -> np.ndarray:
    """Rec. 709 luma of a BGR view (gray views are returned as they are).

    Parameters
    ----------
    view : numpy.ndarray
        (h, w) or (h, w, 3) BGR.

    Returns
    -------
    numpy.ndarray
        (h, w) float32.
    """
    if view.ndim == 2:
        return view
    return np.ascontiguousarray(view @ REC709[::-1], dtype=np.float32)


def as_pair_of_same_kind(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both views in colour, or both gray when either is gray.

    Parameters
    ----------
    left, right : numpy.ndarray
        The two views.

    Returns
    -------
    tuple of numpy.ndarray
        ``(left, right)``, both colour or both gray.
    """
    if left.ndim != right.ndim:
        return to_gray(left), to_gray(right)
    return left, right


def check_pair(
    left: np.ndarray, right: np.ndarray, names: tuple[str, str] = ("left", "right")
) -> None:
    """Raise ``ImageError`` unless the two views have the same size.

    Parameters
    ----------
    left, right : numpy.ndarray
        The two views.
    names : tuple of str, optional
        What to call them in the error.

    Raises
    ------
    ImageError
        If their heights or widths differ.
    """
    if left.shape[:2] != right.shape[:2]:
        raise ImageError(
            f"{names[0]} is {left.shape[1]}x{left.shape[0]} but {names[1]} is "
            f"{right.shape[1]}x{right.shape[0]}: a rectified stereo pair has two views of one size"
        )


def load_pair(left: str | Path, right: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read the rectified stereo pair ``left``, ``right`` as two float32 views of the same size,
    both colour or both gray; a missing or unusable file, or different sizes, are an
    :class:`ImageError`."""
    # the two decodes side by side (OpenCV releases the GIL): Art x3's 1.5 MP PNGs take 50 ms each
    left_image, right_image = each_beside(load_view, [(left,), (right,)])
    check_pair(left_image, right_image, (str(left), str(right)))
    return as_pair_of_same_kind(left_image, right_image)


def load_mask(path: str | Path) -> np.ndarray:
    """Read the mask image ``path`` as (h, w) bool, True where the value is > 0 (palette PNGs
    decoded through their palette); an unreadable file is an :class:`ImageError`."""
    raw = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if raw is None:
        raise ImageError(f"{path}: not a readable mask image")
    return raw > 0


def load_disparity_values(path: str | Path) -> np.ndarray:
    """Read raw disparity/ground-truth values as float32 without rescaling (scale applied later).

    ``.npy`` and ``.pfm`` carry real disparities (a PFM's header scale is its byte order only,
    :func:`read_pfm`); integer images carry their stored values.

    Parameters
    ----------
    path : str or Path
        ``.npy``, ``.pfm`` or an integer image.

    Returns
    -------
    numpy.ndarray
        (h, w) float32, non-finite values as 0.

    Raises
    ------
    ImageError
        If the file cannot be read as an image.
    """
    path = Path(path)
    if path.suffix.lower() == ".npy":
        return np.load(path).astype(np.float32)
    raw: np.ndarray | None
    if path.suffix.lower() == ".pfm" and path.is_file():
        raw = read_pfm(path.read_bytes(), str(path))
    else:
        raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise ImageError(f"{path}: not a readable disparity image")
    if raw.ndim == 3:
        raw = raw[:, :, 0]
    values = raw.astype(np.float32)
    return np.where(np.isfinite(values), values, 0.0).astype(np.float32)


def png_disparity(disparity: np.ndarray) -> np.ndarray:
    """KITTI's 16-bit PNG values of a disparity map: round(d x 256), 0 only where the pixel is
    invalid (not finite or negative), so a valid 0 px is written as 1 (1/256 px).

    Raises
    ------
    DisparityFormatError
        If a disparity exceeds :data:`PNG_MAX_DISPARITY` (never clipped silently).
    """
    valid = np.isfinite(disparity) & (disparity >= 0)
    top = float(disparity[valid].max()) if valid.any() else 0.0
    if top > PNG_MAX_DISPARITY + 0.5 / PNG_DISPARITY_SCALE:
        raise DisparityFormatError(
            f"the disparity reaches {top:.2f} px, above the {PNG_MAX_DISPARITY:.3f} px a 16-bit "
            "PNG holds (x256, KITTI's convention); write .pfm or .npy instead"
        )
    scaled = np.rint(np.where(valid, disparity, 0.0) * PNG_DISPARITY_SCALE)
    return np.where(valid, np.clip(scaled, 1, 65535), 0).astype(np.uint16)


def disparity_bytes(disparity: np.ndarray, fmt: str) -> bytes:
    """Encode a disparity map as ``pfm``, ``png`` (16-bit, x256) or ``npy`` bytes.

    Parameters
    ----------
    disparity : numpy.ndarray
        Disparity map (h, w).
    fmt : str
        ``pfm``, ``png`` or ``npy`` (a leading dot is accepted).

    Returns
    -------
    bytes
        The encoded file.

    Raises
    ------
    ValueError
        If the format is unknown.
    DisparityFormatError
        If the map does not fit a 16-bit PNG (:func:`png_disparity`).
    """
    fmt = fmt.lower().lstrip(".")
    disparity = np.asarray(disparity, dtype=np.float32)
    if fmt == "pfm":
        ok, buf = cv2.imencode(".pfm", disparity)
    elif fmt == "png":
        ok, buf = cv2.imencode(".png", png_disparity(disparity))
    elif fmt == "npy":
        import io

        stream = io.BytesIO()
        np.save(stream, disparity)
        return stream.getvalue()
    else:
        raise ValueError(f"unknown disparity format {fmt!r}; use one of pfm, png, npy")
    if not ok:
        raise RuntimeError(f"OpenCV could not encode a {fmt} disparity map")
    return buf.tobytes()


def save_disparity(disparity: np.ndarray, path: str | Path) -> Path:
    """Write a disparity map; the format follows the extension (.pfm, .png, .npy).

    Parameters
    ----------
    disparity : numpy.ndarray
        Disparity map (h, w).
    path : str or Path
        Output file; its parent directories are created.

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    ValueError
        If the extension is not one of ``.pfm``, ``.png``, ``.npy``.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in DISPARITY_SUFFIXES:
        raise ValueError(f"{path}: unsupported output extension; use one of {DISPARITY_SUFFIXES}")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(disparity_bytes(disparity, suffix))
    return path


def save_maps(
    validity: np.ndarray | None,
    confidence: np.ndarray | None,
    output: str | Path,
    provenance: np.ndarray | None = None,
) -> dict[str, str]:
    """Write a run's maps beside its disparity ``output`` (``d.pfm`` -> ``d.valid.png``: 255
    where the left-right check confirmed the pixel, 0 where it was filled from the background;
    ``d.confidence.pfm``: float in [0, 1]; ``d.provenance.png``: which stage decided each
    pixel, colour-coded, :mod:`shared.provenance_map`); the files written, by name (those the
    run has)."""
    stem = Path(output).with_suffix("")
    written: dict[str, str] = {}
    if provenance is not None:
        from shared.provenance_map import png

        written["provenance"] = f"{stem}.provenance.png"
        Path(written["provenance"]).write_bytes(png(provenance))
    if validity is not None:
        written["validity"] = f"{stem}.valid.png"
        cv2.imwrite(written["validity"], np.where(validity, 255, 0).astype(np.uint8))
    if confidence is not None:
        written["confidence"] = str(save_disparity(confidence, f"{stem}.confidence.pfm"))
    return written


def load_disparity(path: str | Path) -> np.ndarray:
    """Read a disparity map written by :func:`save_disparity` (PNG is divided by 256).

    Parameters
    ----------
    path : str or Path
        A ``.pfm``, ``.png`` or ``.npy`` disparity map.

    Returns
    -------
    numpy.ndarray
        Disparities (h, w), float32, pixels.
    """
    path = Path(path)
    values = load_disparity_values(path)
    if path.suffix.lower() == ".png":
        return values / PNG_DISPARITY_SCALE
    return values


def colorize(disparity: np.ndarray, max_disparity: float | None = None) -> np.ndarray:
    """Colour-map a disparity map (near = warm) as an 8-bit BGR image for previews.

    Parameters
    ----------
    disparity : numpy.ndarray
        Disparity map (h, w).
    max_disparity : float, optional
        The value shown as the warmest colour; default: the map's maximum.

    Returns
    -------
    numpy.ndarray
        (h, w, 3) uint8 BGR.
    """
    top = float(max_disparity if max_disparity else max(float(np.max(disparity)), 1.0))
    scaled = np.clip(np.asarray(disparity, dtype=np.float32) / top, 0.0, 1.0)
    return cv2.applyColorMap((scaled * 255).astype(np.uint8), cv2.COLORMAP_TURBO)


def preview_png(disparity: np.ndarray, max_disparity: float | None = None) -> bytes:
    """PNG bytes of :func:`colorize`.

    Parameters
    ----------
    disparity : numpy.ndarray
        Disparity map (h, w).
    max_disparity : float, optional
        As in :func:`colorize`.

    Returns
    -------
    bytes
        The PNG file.
    """
    ok, buf = cv2.imencode(".png", colorize(disparity, max_disparity))
    if not ok:
        raise RuntimeError("OpenCV could not encode the preview")
    return buf.tobytes()
