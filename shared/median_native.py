"""OpenCV's colour-weighted median (``cv2.ximgproc.weightedMedianFilter``) in C
(``median_native.c``, built and loaded by :mod:`shared.native`), on strips of columns at once:
:func:`shared.filters.weighted_median` calls it for whole maps when the library is built. The
same medians bit for bit; Aloe's median 0.19 -> 0.12 s on two cores (docs/benchmarks.md, "The
weighted median on every core").

Why not OpenCV's filter per strip: it keeps state in statics (two threads running it crash the
process), and its k-means would see only a strip's colours. Here the guide's colours are
clustered once, by the same k-means call OpenCV makes (:meth:`NativeMedian.features`), and each
strip's columns are filtered with the whole image's clusters; a column's median depends only
on the columns within the radius, so the strips together are the whole map's filter.
"""

from __future__ import annotations

import ctypes
from typing import Final

import cv2
import numpy as np

from shared.threads import each_beside

#: OpenCV's feature indexing: colours cut to 6 bits a channel, at most 256 clusters of them.
COLOUR_BITS: Final = 6
CLUSTERS: Final = 256
#: Its k-means: at most 2 iterations (OpenCV's floor for a count of 0), one attempt, k-means++.
KMEANS_CRITERIA: Final = (cv2.TERM_CRITERIA_MAX_ITER | cv2.TERM_CRITERIA_EPS, 0, 10000.0)

_POINTER = ctypes.c_void_p
_INT = ctypes.c_int64


class NativeMedian:
    """The weighted median of 8-bit maps (WMF_EXP weights, no mask) from the loaded library."""

    def __init__(self, library: ctypes.CDLL) -> None:
        self.weights = library.qhsm_median_weights
        self.weights.argtypes = (_POINTER, _INT, _INT, ctypes.c_float, _POINTER)
        self.weights.restype = None
        self.columns = library.qhsm_weighted_median
        self.columns.argtypes = (_POINTER, _POINTER, _POINTER, *[_INT] * 6, _POINTER)
        self.columns.restype = ctypes.c_int

    def features(self, guide: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
        """Each pixel's feature index (h, w) uint8 and the weights between indices (n, n)
        float32, as OpenCV's ``featureIndexing`` makes them: a grey guide's levels; a colour
        guide's 6-bit colours clustered by ``cv2.kmeans`` seeded as OpenCV's filter is (global
        RNG seed 0, in the calling thread), the samples in its order (ascending colour code)."""
        centers: np.ndarray = np.zeros((1, 3), np.float32)  # a grey guide's are its levels
        if guide.ndim == 2:
            features, count, channels = guide, 256, 1
        else:
            shift = 8 - COLOUR_BITS
            low = guide.astype(np.int32) >> shift
            code = (low[..., 0] << 2 * COLOUR_BITS) | (low[..., 1] << COLOUR_BITS) | low[..., 2]
            present = np.flatnonzero(np.bincount(code.ravel(), minlength=1 << 3 * COLOUR_BITS))
            mask = (1 << COLOUR_BITS) - 1
            samples = np.stack(
                [present >> 2 * COLOUR_BITS, (present >> COLOUR_BITS) & mask, present & mask], -1
            ).astype(np.float32)
            count, channels = min(CLUSTERS, len(present)), 3
            labels = np.zeros((len(samples), 1), np.int32)  # written by k-means, not read
            centers = samples
            if count > 1:  # one colour is one cluster of weight 1: a constant grey guide's filter
                # (OpenCV gives its k-means that row as 3 samples, reads past the 1 x 1 centres)
                cv2.setRNGSeed(0)
                _, found, clustered = cv2.kmeans(
                    samples, count, labels, KMEANS_CRITERIA, 1, cv2.KMEANS_PP_CENTERS
                )
                labels, centers = np.asarray(found), np.asarray(clustered)
            index = np.zeros(1 << 3 * COLOUR_BITS, np.uint8)
            index[present] = labels.ravel()
            features = index[code]
        weights = np.empty((count, count), np.float32)
        centers = np.ascontiguousarray(centers, np.float32)
        self.weights(centers.ctypes.data, count, channels, sigma, weights.ctypes.data)
        return np.ascontiguousarray(features, np.uint8), weights

    def __call__(
        self, values: np.ndarray, guide: np.ndarray, radius: int, sigma: float, strips: int
    ) -> np.ndarray:
        """``cv2.ximgproc.weightedMedianFilter(guide, values, radius, sigma=sigma)`` of the
        8-bit map ``values`` (h, w) with the uint8 ``guide`` (h, w) or (h, w, 3), its columns
        cut into ``strips`` filtered side by side (:func:`shared.threads.each_beside`)."""
        values = np.ascontiguousarray(values, np.uint8)
        features, weights = self.features(guide, sigma)
        height, width = values.shape
        out = np.empty_like(values)
        cuts = np.linspace(0, width, max(1, min(strips, width)) + 1).astype(int)

        def strip(first: int, last: int) -> None:
            status = self.columns(
                values.ctypes.data, features.ctypes.data, weights.ctypes.data, height, width,
                radius, len(weights), first, last, out.ctypes.data,
            )  # fmt: skip
            if status:
                raise MemoryError("no memory for the weighted median's histograms")

        each_beside(strip, list(zip(cuts[:-1].tolist(), cuts[1:].tolist(), strict=True)))
        return out
