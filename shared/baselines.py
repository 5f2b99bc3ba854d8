"""Baselines the paper's method is compared with.

* Heidari et al.: one full-resolution level, every disparity 0..max a candidate, the linear
  regulariser s|dp - dq|, each row solved to optimality. A row with a convex pairwise term is
  solved exactly by one minimum cut (Ishikawa 2003): every pixel gets a column of K - 1 nodes
  u_1..u_{K-1} with u_i on the source side iff d >= i; the unary cost D(i) sits on the edge that
  is cut when d == i, infinite reverse edges keep each column cut exactly once, and edges of
  capacity s between u_i of horizontal neighbours pay s for every level between their labels,
  i.e. s|dp - dq|. The costs are the pipeline's own (:func:`shared.energy.level_costs`), so the
  row DP (:func:`shared.solvers.exact.solve_chains`) must reach the same energy; ``heidari``
  checks that on every row it solves unless told not to.
* OpenCV StereoSGBM, the classical method a user would pick instead (the settings of issue 17:
  colour, 5 x 5 blocks, 8 paths), with the pixels it leaves invalid (occlusions, the left
  margin, uniqueness failures) filled from the background side.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from shared.config import LevelConfig, MatchConfig, Regularizer
from shared.energy import Costs, level_costs, row_energies
from shared.filters import fill_from_background
from shared.pyramid import initial_candidates
from shared.solvers.exact import solve_chains

#: Bound on the entries of one block's K x K pairwise arrays (memory of ``level_costs``).
BLOCK_PAIR_ENTRIES = 8_000_000
#: Relative energy tolerance of the min-cut / DP cross-check (float round-off only).
CROSS_CHECK_RTOL = 1e-9


@dataclass
class BaselineResult:
    """Full-resolution left-view disparity (float32, px), wall time and what the method reports."""

    disparity: np.ndarray
    seconds: float
    info: dict = field(default_factory=dict)


def heidari_config(max_disparity: int, level: LevelConfig | None = None) -> MatchConfig:
    """The Heidari et al. formulation as a ``MatchConfig`` of the one pipeline.

    One full-resolution level whose candidates are all disparities 0..max (hence at most 63:
    ``LevelConfig`` allows 64 candidates), the linear regulariser, no median or bilateral
    filtering. ``level`` supplies the slope (default: the paper's full-resolution level).

    Parameters
    ----------
    max_disparity : int
        Largest disparity, px (at most 63).
    level : LevelConfig, optional
        The MRF parameters to take the slope from.

    Returns
    -------
    MatchConfig
    """
    base = level or LevelConfig()
    # model_validate: the preset fills the fields this leaves out, which a type checker cannot see
    return MatchConfig.model_validate(
        {
            "preset": "paper",
            "levels": [base.model_copy(update={"downsample": 1, "candidates": max_disparity + 1})],
            "max_disparity": max_disparity,
            "regularizer": Regularizer.LINEAR,
            "median": False,
            "bilateral": False,
            "solver": "exact",
            "bundle_height": 1,
        }
    )


def linear_slopes(costs: Costs) -> np.ndarray:
    """The slope s of every horizontal edge, (h, w - 1), after checking the costs are s|l - m|.

    Raises ``ValueError`` unless the candidates are 0..K-1 at every pixel and the horizontal
    pairwise costs are linear in the label difference (what the min-cut construction needs).

    Parameters
    ----------
    costs : Costs
        The MRF of a block of rows.

    Returns
    -------
    numpy.ndarray
        Slopes (h, w - 1), float64.

    Raises
    ------
    ValueError
        If the costs are not of the form the min-cut construction needs.
    """
    height, width, labels = costs.unary.shape
    if not np.array_equal(
        costs.candidates, np.broadcast_to(np.arange(labels), (*costs.shape, labels))
    ):
        raise ValueError("the min-cut baseline needs candidates 0..K-1 at every pixel")
    if labels < 2 or width < 2:
        return np.zeros((height, max(width - 1, 0)))
    slopes = costs.pair_h[:, :, 0, 1]
    distance = np.abs(np.subtract.outer(np.arange(labels), np.arange(labels)))
    expected = slopes[:, :, None, None] * distance
    if not np.allclose(costs.pair_h, expected, rtol=1e-9, atol=1e-12):
        raise ValueError("the min-cut baseline needs a linear pairwise term s|dp - dq|")
    if np.any(costs.unary < 0) or np.any(slopes < 0):
        raise ValueError("the min-cut baseline needs non-negative costs")
    return slopes


def minimum_cut_rows(costs: Costs) -> np.ndarray:
    """Optimal labels (h, w) of every row of ``costs`` (each row a chain), by one minimum cut.

    Vertical edges are ignored, exactly as in the row DP. Rows share the graph but no edges, so
    the cut of the graph is the sum of the rows' optimal cuts.

    Parameters
    ----------
    costs : Costs
        The MRF of a block of rows (linear pairwise term, see :func:`linear_slopes`).

    Returns
    -------
    numpy.ndarray
        Candidate index (h, w), int32, of every pixel.
    """
    slopes = linear_slopes(costs)
    unary = costs.unary
    height, width, labels = unary.shape
    if labels == 1:
        return np.zeros((height, width), dtype=np.int32)
    infinite = float(unary.sum() + slopes.sum() * labels + 1.0)
    try:
        import maxflow
    except ImportError as exc:  # PyMaxflow is in the optional `bench` extra
        raise ImportError(
            "the Heidari baseline needs PyMaxflow: pip install 'qhsm[bench]'"
        ) from exc

    graph = maxflow.GraphFloat()
    nodes = graph.add_grid_nodes((height, width, labels - 1))  # node i: "label >= i + 1"
    graph.add_grid_tedges(nodes[:, :, 0], unary[:, :, 0], np.zeros((height, width)))
    graph.add_grid_tedges(nodes[:, :, -1], np.zeros((height, width)), unary[:, :, -1])
    if labels > 2:  # cutting u_i -> u_{i+1} means label i + 1
        graph.add_edges(
            nodes[:, :, :-1].ravel(),
            nodes[:, :, 1:].ravel(),
            np.ascontiguousarray(unary[:, :, 1:-1]).ravel(),
            np.full(height * width * (labels - 2), infinite),
        )
    if width > 1:
        capacity = np.repeat(slopes[:, :, None], labels - 1, axis=2).ravel()
        graph.add_edges(nodes[:, :-1].ravel(), nodes[:, 1:].ravel(), capacity, capacity)
    graph.maxflow()
    on_source_side = ~graph.get_grid_segments(nodes)
    return on_source_side.sum(axis=2).astype(np.int32)


def _row_blocks(height: int, width: int, labels: int) -> list[tuple[int, int]]:
    rows = max(1, BLOCK_PAIR_ENTRIES // max(1, width * labels * labels))
    return [(start, min(start + rows, height)) for start in range(0, height, rows)]


def heidari(
    left: np.ndarray, right: np.ndarray, max_disparity: int, cross_check: bool = True
) -> BaselineResult:
    """Heidari et al. on a rectified pair (float32 gray): exact per-row min-cut of the linear MRF.

    With ``cross_check`` every block of rows is also solved by the row DP and the two optima are
    compared; a disagreement beyond float round-off raises ``AssertionError`` (a bug, not data).
    ``info`` holds the total energy, the cut time alone and the largest DP gap seen.

    Parameters
    ----------
    left, right : numpy.ndarray
        The views (h, w), float32 gray in [0, 1].
    max_disparity : int
        Largest disparity, px (at most 63).
    cross_check : bool, optional
        Also solve every block by the row DP and compare the energies.

    Returns
    -------
    BaselineResult

    Raises
    ------
    AssertionError
        If ``cross_check`` finds the two optima apart beyond round-off.
    """
    config = heidari_config(max_disparity)
    level = config.levels[0]
    candidates = initial_candidates(left.shape, level.candidates, max_disparity)
    labels = np.empty(left.shape, dtype=np.int32)
    energy = cut_seconds = dp_seconds = worst_gap = 0.0
    started = time.perf_counter()
    height, width = left.shape
    for start, stop in _row_blocks(height, width, level.candidates):
        costs = level_costs(
            left[start:stop], right[start:stop], candidates[start:stop], level, config.regularizer
        )
        cut_started = time.perf_counter()
        block = minimum_cut_rows(costs)
        cut_seconds += time.perf_counter() - cut_started
        labels[start:stop] = block
        block_energy = row_energies(costs, block)
        energy += float(block_energy.sum())
        if cross_check:
            dp_started = time.perf_counter()
            dp_energy = row_energies(costs, solve_chains(costs))
            dp_seconds += time.perf_counter() - dp_started
            gap = np.abs(block_energy - dp_energy) / np.maximum(np.abs(dp_energy), 1e-12)
            worst_gap = max(worst_gap, float(gap.max()))
            if worst_gap > CROSS_CHECK_RTOL:
                raise AssertionError(
                    f"min-cut and row DP disagree on rows {start}..{stop}: relative gap {worst_gap}"
                )
    seconds = time.perf_counter() - started - dp_seconds
    disparity = np.take_along_axis(candidates, labels[:, :, None], axis=2)[:, :, 0]
    info = {
        "energy": energy,
        "cut_seconds": cut_seconds,
        "candidates": level.candidates,
        "slope": level.slope,
    }
    if cross_check:
        info.update(dp_seconds=dp_seconds, dp_max_relative_gap=worst_gap)
    return BaselineResult(disparity=disparity.astype(np.float32), seconds=seconds, info=info)


# --- OpenCV StereoSGBM ---------------------------------------------------------------------

#: The SGBM baseline of issue 17, the one every comparison uses: 5 x 5 blocks on the colour views,
#: OpenCV's recommended penalties for three channels (P1 = 8 cn b^2, P2 = 32 cn b^2), a 1-px
#: left-right check, uniqueness 10 %, speckle filter 100 px / 2 px, and the full 8-path mode.
SGBM_PARAMETERS: dict[str, int] = {
    "blockSize": 5,
    "P1": 8 * 3 * 5 * 5,
    "P2": 32 * 3 * 5 * 5,
    "disp12MaxDiff": 1,
    "uniquenessRatio": 10,
    "speckleWindowSize": 100,
    "speckleRange": 2,
    "mode": cv2.STEREO_SGBM_MODE_HH,
}


def sgbm_matcher(max_disparity: int) -> cv2.StereoSGBM:
    """The baseline's OpenCV matcher for disparities 0..``max_disparity``.

    Parameters
    ----------
    max_disparity : int
        Largest disparity, px; OpenCV searches 0..N - 1 with N the next multiple of 16 above it.

    Returns
    -------
    cv2.StereoSGBM
        Configured with :data:`SGBM_PARAMETERS`.
    """
    return cv2.StereoSGBM.create(
        minDisparity=0,
        numDisparities=16 * int(np.ceil((max_disparity + 1) / 16)),
        **SGBM_PARAMETERS,
    )


def sgbm(left: np.ndarray, right: np.ndarray, max_disparity: int) -> BaselineResult:
    """OpenCV semi-global block matching, the baseline (:data:`SGBM_PARAMETERS`).

    The views go in as OpenCV reads them (8-bit, colour kept); the map comes out as OpenCV
    computes it over its search range (:func:`sgbm_matcher`, not clipped to ``max_disparity``),
    with the pixels it marks invalid (occlusions, the left margin, uniqueness and left-right
    failures) filled by :func:`shared.filters.fill_from_background` (rows without a valid pixel
    become 0).

    Parameters
    ----------
    left, right : numpy.ndarray
        The views (h, w, 3) BGR or (h, w), float32 in [0, 1].
    max_disparity : int
        Largest disparity, px.

    Returns
    -------
    BaselineResult
        ``info``: the fraction of pixels filled and OpenCV's number of disparities.
    """
    started = time.perf_counter()
    matcher = sgbm_matcher(max_disparity)
    to_uint8 = lambda image: np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)  # noqa: E731
    raw = matcher.compute(to_uint8(left), to_uint8(right)).astype(np.float32) / 16.0
    valid = raw >= 0
    disparity = fill_from_background(raw, valid, empty=0.0)
    return BaselineResult(
        disparity=disparity,
        seconds=time.perf_counter() - started,
        info={
            "invalid_fraction": float(1.0 - valid.mean()),
            "num_disparities": matcher.getNumDisparities(),
        },
    )
