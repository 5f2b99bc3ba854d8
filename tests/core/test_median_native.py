"""OpenCV's weighted median in C (``shared/median_native.c``, issue 28): the very medians of
``cv2.ximgproc.weightedMedianFilter`` for 8-bit maps, whatever the strips its columns are cut
into, and strips filtered at the same time (OpenCV's own filter crashes run that way)."""

from __future__ import annotations

import shutil
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared import filters, kernels, native
from shared.kernel_build import compiler_command
from shared.median_native import NativeMedian

COMPILER = compiler_command() or ["cc"]
pytestmark = pytest.mark.skipif(
    shutil.which(COMPILER[0]) is None, reason=f"no C compiler ({COMPILER[0]}) to build it with"
)


@pytest.fixture(scope="module", params=["native", "generic"])
def median(request, tmp_path_factory) -> NativeMedian:
    """Built for this CPU's x86-64 level, and for the generic target (no ``-march``)."""
    cpu = kernels.target_cpu() if request.param == "native" else ""
    path = tmp_path_factory.mktemp("native") / "median.so"
    library = native.load(native.compile_library(COMPILER, path, cpu, "median"), "median")
    assert library is not None
    return NativeMedian(library)


def _opencv(guide: np.ndarray, values: np.ndarray, radius: int, sigma: float) -> np.ndarray:
    cv2.setRNGSeed(0)  # its k-means' seed, as shared.filters sets it
    return cv2.ximgproc.weightedMedianFilter(guide, values, radius, sigma=sigma)


def _case(seed: int, height: int, width: int, values: str, colours: str):
    rng = np.random.default_rng(seed)
    shape = (height, width)
    if values == "few":  # a few disparities: ties, unused values the cut passes
        disparity = rng.choice(rng.integers(0, 256, 3), shape)
    elif values == "steps":  # a map's plateaus and edges
        disparity = np.cumsum(rng.integers(0, 2, shape), axis=1) * 7 % 256
    else:
        disparity = rng.integers(0, 256, shape)
    if colours == "grey":
        guide = rng.integers(0, 256, shape)
    elif colours == "one":  # a single colour: one cluster
        guide = np.broadcast_to(rng.integers(0, 256, 3), (*shape, 3))
    elif colours == "few":  # fewer 6-bit colours than clusters
        guide = rng.choice([0, 4, 130, 255], (*shape, 3))
    else:  # more colours than clusters: k-means merges them
        guide = rng.integers(0, 256, (*shape, 3))
    return np.ascontiguousarray(disparity, np.uint8), np.ascontiguousarray(guide, np.uint8)


@settings(max_examples=80, deadline=None)
@given(
    seed=st.integers(0, 2**16),
    height=st.integers(1, 45),
    width=st.integers(1, 45),
    values=st.sampled_from(["few", "steps", "many"]),
    colours=st.sampled_from(["grey", "one", "few", "many"]),
    radius=st.integers(1, 12),
    sigma=st.sampled_from([1.0, 5.0, 25.5, 100.0]),
    strips=st.integers(1, 4),
)
def test_the_c_median_is_opencvs_in_any_strips(
    median, seed, height, width, values, colours, radius, sigma, strips
):
    disparity, guide = _case(seed, height, width, values, colours)
    # OpenCV's filter reads past its k-means centres when a colour guide has one colour only
    # (a different map from one call to the next); a constant grey guide is what it means
    reference = guide[..., 0] if colours == "one" else guide
    np.testing.assert_array_equal(
        median(disparity, guide, radius, sigma, strips),
        _opencv(reference, disparity, radius, sigma),
    )


def test_strips_filtered_at_the_same_time_are_the_whole_filter(median):
    """Two threads in the library at once (ctypes lets go of the GIL): no shared state."""
    disparity, guide = _case(7, 120, 160, "steps", "many")
    features, weights = median.features(guide, 25.5)
    out = np.zeros_like(disparity)
    cuts = [(0, 40), (40, 85), (85, 160)]
    with ThreadPoolExecutor(3) as pool:
        status = list(
            pool.map(
                lambda cut: median.columns(
                    disparity.ctypes.data, features.ctypes.data, weights.ctypes.data, 120,
                    160, 9, len(weights), *cut, out.ctypes.data,
                ),
                cuts * 4,  # each strip four times over, concurrently
            )
        )  # fmt: skip
    assert status == [0] * 12
    np.testing.assert_array_equal(out, _opencv(guide, disparity, 9, 25.5))


def test_the_filter_takes_opencvs_path_without_the_library(monkeypatch):
    """``shared.filters.weighted_median`` calls the C median when it is built, OpenCV's
    otherwise: the same map either way."""
    if kernels.native_median is None:
        pytest.skip("the C kernels are not built here (qhsm build-kernels)")
    rng = np.random.default_rng(3)
    disparity = np.cumsum(rng.integers(0, 2, (50, 70)), axis=1).astype(np.float32) + 12
    guide = rng.random((50, 70, 3)).astype(np.float32)
    built = filters.weighted_median(disparity, guide, 9, 25.5)
    monkeypatch.setattr(kernels, "native_median", None)
    np.testing.assert_array_equal(filters.weighted_median(disparity, guide, 9, 25.5), built)


def test_a_guide_opencv_refuses_is_refused_as_before():
    """Four channels: OpenCV's error, not a filter of three of them."""
    guide = np.random.default_rng(4).random((10, 12, 4)).astype(np.float32)
    with pytest.raises(cv2.error):
        filters.weighted_median(np.ones((10, 12), np.float32), guide, 3, 25.5)
