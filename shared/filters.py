"""Post-processing of disparity maps: a median filter per level; at the end a bilateral filter
(the paper; its "No B" / "No M No B" ablations switch them off) or the accurate preset's
left-right check, background fill and colour-weighted median."""

from __future__ import annotations

import cv2
import numpy as np

from shared import kernels
from shared.threads import threads


def median(disparity: np.ndarray, size: int = 7) -> np.ndarray:
    """Median filter with edge replication.

    Level disparities are integers; OpenCV's fast median needs uint8 above size 5, so maps that
    fit in uint8 take that path and anything else (fractions, > 255) goes through SciPy.

    Parameters
    ----------
    disparity : numpy.ndarray
        Disparity map (h, w).
    size : int, optional
        Odd window side; 1 or less returns the map unchanged.

    Returns
    -------
    numpy.ndarray
        Filtered map (h, w), float32.
    """
    if size <= 1:
        return disparity
    disparity = np.asarray(disparity, np.float32)
    as_bytes = disparity.astype(np.uint8)
    if np.array_equal(as_bytes, disparity):
        padded = cv2.copyMakeBorder(as_bytes, *(size // 2,) * 4, cv2.BORDER_REPLICATE)
        pad = size // 2
        return cv2.medianBlur(padded, size)[pad:-pad, pad:-pad].astype(np.float32)
    from scipy import ndimage  # slow to import; only needed off the fast path

    return ndimage.median_filter(disparity, size=size, mode="nearest")


def bilateral(
    disparity: np.ndarray, diameter: int, sigma_color: float, sigma_space: float
) -> np.ndarray:
    """Edge-preserving smoothing of the disparity map (sigma_color in disparity pixels).

    Parameters
    ----------
    disparity : numpy.ndarray
        Disparity map (h, w).
    diameter : int
        Pixel neighbourhood diameter.
    sigma_color : float
        Range sigma, disparity pixels.
    sigma_space : float
        Spatial sigma, pixels.

    Returns
    -------
    numpy.ndarray
        Filtered map (h, w), float32.
    """
    return cv2.bilateralFilter(
        np.asarray(disparity, np.float32), diameter, sigma_color, sigma_space
    )


def left_right_check(left: np.ndarray, right: np.ndarray, tolerance: float = 1.0) -> np.ndarray:
    """Where the left view's disparity is confirmed by the right view's (bool, (h, w)).

    Left pixel (y, x) with disparity d matches right pixel (y, x - d); it passes when that pixel
    lies inside the image and its own disparity differs from d by at most ``tolerance``.

    Parameters
    ----------
    left, right : numpy.ndarray
        Disparity maps (h, w) of the left and the right view.
    tolerance : float, optional
        Largest accepted difference, pixels.

    Returns
    -------
    numpy.ndarray
        Mask (h, w), True where the left disparity is confirmed.
    """
    height, width = left.shape
    target = np.arange(width)[None, :] - np.rint(left).astype(np.int64)
    inside = target >= 0
    rows = np.arange(height)[:, None]
    back = right[rows, np.clip(target, 0, width - 1)]
    return inside & (np.abs(left - back) <= tolerance)


def fill_from_background(
    disparity: np.ndarray, valid: np.ndarray, empty: float | None = None
) -> np.ndarray:
    """Replace invalid pixels by the smaller of the nearest valid disparities to their left and
    right on the row (occluded pixels belong to the farther surface); rows with no valid pixel
    are left as they are, or set to ``empty`` when given.

    Parameters
    ----------
    disparity : numpy.ndarray
        Disparity map (h, w).
    valid : numpy.ndarray
        Mask (h, w) of the pixels to keep.
    empty : float, optional
        Value for rows without a valid pixel; ``None`` keeps them.

    Returns
    -------
    numpy.ndarray
        Filled map (h, w), float32.
    """
    height, width = disparity.shape
    columns = np.broadcast_to(np.arange(width), (height, width))
    left_index = np.maximum.accumulate(np.where(valid, columns, -1), axis=1)
    right_index = np.minimum.accumulate(np.where(valid, columns, width)[:, ::-1], axis=1)[:, ::-1]
    rows = np.arange(height)[:, None]
    inf = np.float32(np.inf)
    from_left = np.where(left_index >= 0, disparity[rows, np.maximum(left_index, 0)], inf)
    from_right = np.where(
        right_index < width, disparity[rows, np.minimum(right_index, width - 1)], inf
    )
    nearest = np.minimum(from_left, from_right)
    if empty is not None:
        nearest = np.where(np.isfinite(nearest), nearest, np.float32(empty))
    return np.where(valid | ~np.isfinite(nearest), disparity, nearest).astype(np.float32)


def weighted_median(
    disparity: np.ndarray, guide: np.ndarray, radius: int, sigma: float
) -> np.ndarray:
    """Colour-weighted median (OpenCV ximgproc): each pixel takes the median of its window's
    disparities weighted by colour similarity to it in ``guide`` (float32 [0, 1], gray or BGR;
    ``sigma`` on the 0..255 scale), which snaps edges of the map to edges of the image.

    Parameters
    ----------
    disparity : numpy.ndarray
        Disparity map (h, w).
    guide : numpy.ndarray
        The view (h, w) or (h, w, 3), float32 in [0, 1].
    radius : int
        Window radius, pixels.
    sigma : float
        Colour similarity scale on 0..255.

    Returns
    -------
    numpy.ndarray
        Filtered map (h, w), float32.
    """
    guide8 = np.clip(np.rint(guide * 255.0), 0, 255).astype(np.uint8)
    values = np.asarray(disparity, np.float32)
    lowest = float(values.min()) if values.size else 0.0
    # Whole disparities at most 255 apart go in as 8 bits above the least: the same medians,
    # without OpenCV's sort of every pixel (a third of the call). The float path ranks the
    # distinct values (each its own rank: at most 256 of them) and the 8-bit one takes each
    # value as its rank: the same order, the same least rank (the median's cut stops there),
    # and a rank no pixel holds adds nothing as the cut passes it.
    whole = (
        bool(values.size)
        and values.max() - lowest <= 255
        and np.array_equal(values, np.rint(values))
    )
    source = (values - np.float32(lowest)).astype(np.uint8) if whole else values
    grey_or_colour = guide8.ndim == 2 or guide8.shape[2] == 3  # what OpenCV's filter takes
    if whole and grey_or_colour and kernels.native_median is not None:  # on every core
        median = kernels.native_median(source, guide8, radius, sigma, threads())
        return median + np.float32(lowest)
    # A colour guide is quantised by k-means seeded from OpenCV's global RNG: seed it, or the
    # same pair gives a different map on every call (up to several pixels apart).
    cv2.setRNGSeed(0)
    # sigma by keyword: the fourth positional parameter is ``dst``, which ignored it (always 25.5)
    median = cv2.ximgproc.weightedMedianFilter(guide8, source, radius, sigma=sigma)
    return median + np.float32(lowest) if whole else median.astype(np.float32)


def subpixel(disparity: np.ndarray, volume: np.ndarray) -> np.ndarray:
    """Refine integer disparities by the vertex of the parabola through the costs at d - 1, d,
    d + 1 of ``volume`` (D + 1, h, w); pixels at the ends of the range or without a convex fit
    keep their value. The offset is at most half a pixel.

    Parameters
    ----------
    disparity : numpy.ndarray
        Integer-valued disparities (h, w).
    volume : numpy.ndarray
        Costs (D + 1, h, w) at every disparity 0..D.

    Returns
    -------
    numpy.ndarray
        Refined disparities (h, w), float32.
    """
    top = volume.shape[0] - 1
    d = np.clip(np.rint(disparity).astype(np.intp), 0, top)
    inner = (d > 0) & (d < top)
    rows, columns = np.indices(d.shape)
    below = volume[np.maximum(d - 1, 0), rows, columns]
    at = volume[d, rows, columns]
    above = volume[np.minimum(d + 1, top), rows, columns]
    curvature = below - 2.0 * at + above
    usable = inner & (curvature > 1e-6)
    offset = np.where(usable, (below - above) / (2.0 * np.where(usable, curvature, 1.0)), 0.0)
    return (d + np.clip(offset, -0.5, 0.5)).astype(np.float32)


#: Least costs per pixel that :func:`cost_confidence` needs: one of any four disparities lies
#: more than 1 px from the chosen one.
RIVALS = 4


def cost_confidence(
    volume: np.ndarray,
    disparity: np.ndarray,
    least: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """How clearly the cost volume prefers each pixel's disparity over every distinct one, in
    [0, 1]: (c_alt - c_d) / c_alt, c_d the cost at the rounded disparity and c_alt the least
    cost more than 1 px away (a peak-ratio measure: 0 where another disparity is as cheap,
    1 where the chosen one costs nothing and every other something).

    c_alt is the least of the pixel's :data:`RIVALS` least costs (:func:`least_costs`) that lie
    more than 1 px away: at most three of them lie within 1 px, and a cheaper far cost would be
    among them. They do not depend on the map, so a caller can take them beforehand
    (``least``), beside the filters that make the map.

    Parameters
    ----------
    volume : numpy.ndarray
        Costs (D + 1, h, w), lower is better, non-negative.
    disparity : numpy.ndarray
        The map (h, w), px.
    least : tuple of numpy.ndarray, optional
        The volume's :func:`least_costs` (computed here when not given).

    Returns
    -------
    numpy.ndarray
        (h, w) float32.
    """
    top = volume.shape[0] - 1
    chosen = np.clip(np.rint(disparity), 0, top).astype(np.intp)
    own = np.take_along_axis(volume, chosen[None], axis=0)[0]
    indices, values = least_costs(volume) if least is None else least
    others = np.where(np.abs(indices - chosen) > 1, values, np.inf).min(axis=0)
    margin = np.where(np.isfinite(others), others - own, 0.0)
    confidence = np.divide(margin, others, out=np.zeros_like(margin), where=others > 0)
    return np.clip(confidence, 0.0, 1.0).astype(np.float32)


def least_costs(volume: np.ndarray, count: int = RIVALS) -> tuple[np.ndarray, np.ndarray]:
    """Each pixel's ``count`` least costs of a (D, h, w) volume, ascending, and their
    disparities (of equal costs the lower first; +inf and 0 where D < ``count``): one pass plane
    after plane (:func:`lowest`'s reason), by the compiled kernel when it runs without numba's
    import, else by NumPy, the same comparisons in the same order.

    Parameters
    ----------
    volume : numpy.ndarray
        (D, h, w) costs, no NaN.
    count : int, optional
        Costs kept per pixel.

    Returns
    -------
    indices, values : numpy.ndarray
        (count, h, w): the disparities (int32) and their costs (the volume's dtype).
    """
    values = np.full((count, *volume.shape[1:]), np.inf, dtype=volume.dtype)
    indices = np.zeros(values.shape, dtype=np.int32)
    if (
        volume.dtype == np.float32
        and volume.flags.c_contiguous
        and kernels.ready(kernels.least_costs)
    ):
        kernels.least_costs(volume, values, indices)
        return indices, values
    for disparity, plane in enumerate(volume):  # each plane's cost goes in after its equals
        place = (values <= plane).sum(axis=0)
        for slot in range(count - 1, -1, -1):
            values[slot] = np.where(place == slot, plane, values[slot])
            indices[slot] = np.where(place == slot, disparity, indices[slot])
            if slot:  # the slots from the new cost on move down one
                values[slot] = np.where(place < slot, values[slot - 1], values[slot])
                indices[slot] = np.where(place < slot, indices[slot - 1], indices[slot])
    return indices, values


def lowest(volume: np.ndarray, outside: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``volume.argmin(axis=0)`` and ``volume.min(axis=0)`` of a (D, h, w) volume, one disparity
    plane at a time: numpy's reductions over the first axis walk it pixel by pixel (the views'
    check spent a third of its time in them); by the compiled kernel when it runs without
    numba's import (:func:`shared.kernels.ready`), else by NumPy, the same comparisons in the
    same order. With ``outside``, the minimum over the disparities more than 1 from it, +inf
    where there is none (the index is then meaningless).

    Parameters
    ----------
    volume : numpy.ndarray
        (D, h, w) costs, no NaN.
    outside : numpy.ndarray, optional
        (h, w) disparities whose neighbourhood (+-1) is left out.

    Returns
    -------
    index, minimum : numpy.ndarray
        (h, w): the first disparity reaching the minimum (intp), and the minimum.
    """
    minimum = np.full(volume.shape[1:], np.inf, dtype=volume.dtype)
    index = np.zeros(volume.shape[1:], dtype=np.intp)
    if (
        volume.dtype == np.float32
        and volume.flags.c_contiguous
        and kernels.ready(kernels.lowest_costs)
    ):
        # the same comparisons in one compiled pass (a NumPy pass per plane and test: 3-6x slower)
        near = outside is not None
        excluded = np.ascontiguousarray(outside, dtype=np.intp) if near else index
        kernels.lowest_costs(volume, excluded, near, index, minimum)
        return index, minimum
    for disparity, plane in enumerate(volume):
        lower = plane < minimum
        if outside is not None:
            lower &= np.abs(outside - disparity) > 1
        np.copyto(minimum, plane, where=lower)
        index[lower] = disparity
    return index, minimum
