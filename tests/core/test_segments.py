"""Row segments: tiling, stitching, one shape per level, and what stitching costs."""

from __future__ import annotations

from itertools import pairwise

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from shared.assembly import assemble
from shared.bundles import Bundle, owned_columns, segment_columns
from shared.config import MatchConfig
from shared.energy import mrf_energy
from shared.inference import (
    level_bundles,
    solve_bundles,
    solve_level_in_process,
)
from shared.pipeline import match_views, plan_run, prepare_level
from shared.solvers.exact import solve_chains
from shared.solvers.registry import resolve
from shared.synthetic import make_scene


@settings(max_examples=300, deadline=None)
@given(
    image_width=st.integers(1, 600),
    bundle_width=st.integers(8, 200),
    margin=st.integers(0, 99),
)
def test_stitching_covers_every_pixel_exactly_once(image_width, bundle_width, margin):
    margin = min(margin, (bundle_width - 1) // 2)
    segments = segment_columns(image_width, bundle_width, margin)
    owned = owned_columns(segments)
    counts = np.zeros(image_width, dtype=int)
    for (first, last), (own_first, own_last) in zip(segments, owned, strict=True):
        assert first <= own_first <= own_last <= last  # a segment labels only its own pixels
        counts[own_first:own_last] += 1
    assert np.all(counts == 1)
    if image_width > bundle_width:
        # one shape: the last segment is shifted left, not shortened
        assert {last - first for first, last in segments} == {bundle_width}
        assert segments[0][0] == 0 and segments[-1][1] == image_width
        for (_, stop), (start, _) in pairwise(segments):
            assert stop - start >= margin  # neighbours overlap by the margin at least
        # each stitched pixel is at least margin/2 away from a cut of the segment labelling it
        for (first, last), (own_first, own_last) in zip(segments, owned, strict=True):
            if first > 0:
                assert own_first - first >= margin // 2
            if last < image_width:
                assert last - own_last >= margin // 2
    else:
        assert segments == [(0, image_width)]


def test_a_margin_of_half_the_width_or_more_is_refused():
    with pytest.raises(ValueError, match="half the bundle width"):
        segment_columns(100, 16, 8)
    with pytest.raises(ValidationError, match="bundle_margin"):
        MatchConfig(bundle_width=16, bundle_margin=8)
    with pytest.raises(ValidationError, match="bundle_width"):
        MatchConfig(bundle_width=4)


def _width_setting(config: MatchConfig) -> int | str | None:
    return resolve(config).bundle_width_setting()


def test_solvers_that_cannot_use_a_width_say_so():
    assert _width_setting(MatchConfig(solver="sa")) is None  # whole rows
    assert _width_setting(MatchConfig(solver="qpu-sim")) == "auto"
    assert _width_setting(MatchConfig(solver="hybrid-sim")) is None
    with pytest.raises(ValueError, match="solves whole rows"):
        _width_setting(MatchConfig(solver="exact", bundle_width=64))
    with pytest.raises(ValueError, match="give a width in pixels"):
        _width_setting(MatchConfig(solver="sa", bundle_width="auto"))


@pytest.fixture(scope="module")
def small():
    return make_scene(24, 90, max_disparity=12, seed=4)


def _finest_level(scene, config):
    """The finest level's inputs, its coarser levels solved exactly."""
    left, right = match_views(scene.left, scene.right, config)
    _, plans = plan_run(left, right, config)
    exact = config.model_copy(update={"solver": "exact", "bundle_width": None})
    previous = None
    for plan in plans:
        inputs = prepare_level(left, right, config, plan, previous)
        if plan is plans[-1]:
            return inputs
        from shared.finishing import finish_level

        previous = finish_level(inputs, solve_level_in_process(inputs, exact), exact)
    raise AssertionError("no level")


def _rows_level(scene, solver: str, bundle_width: int, **more):
    """Row inference on segments of ``bundle_width`` (margin 12) with ``solver``: the config, the
    finest level's inputs, its costs and their row optimum."""
    config = MatchConfig(
        max_disparity=12,
        inference="rows",
        solver=solver,
        bundle_width=bundle_width,
        bundle_margin=12,
        **more,
    )
    inputs = _finest_level(scene, config)
    costs = inputs.costs(config)
    return config, inputs, costs, solve_chains(costs)


def test_every_segment_of_a_level_shares_its_shape(small):
    """With every tile sent (``certify_tiles`` off; the residual design sends 4x4 tiles)."""
    config = MatchConfig(
        max_disparity=12, solver="sa", bundle_width=32, bundle_margin=10, certify_tiles=False
    )
    inputs = _finest_level(small, config)
    bundles = level_bundles(inputs, config)
    assert {b.shape for b in bundles} == {(3, 32)}  # grid inference: tiles of 3 rows
    rows = inputs.shape[0]
    assert len(bundles) == -(-rows // 3) * len(segment_columns(90, 32, 10))  # 3-row tiles
    last = [b for b in bundles if b.row_start == 0][-1]
    assert last == Bundle(0, 3, 90 - 32, 90)


def test_stitched_exact_segments_equal_the_row_optimum_beyond_the_correlation_length(small):
    """Each segment solved exactly, then stitched: equal to the whole-row optimum once the
    margin exceeds how far a cut's influence reaches (here: a few pixels), not with none."""
    config = MatchConfig(max_disparity=12)
    inputs = _finest_level(small, config)
    costs = inputs.costs(config)
    optimum = solve_chains(costs)

    def stitched(width: int, margin: int) -> np.ndarray:
        segments = segment_columns(costs.shape[1], width, margin)
        labels = np.empty_like(optimum)
        for (first, _), (own_first, own_last) in zip(
            segments, owned_columns(segments), strict=True
        ):
            part = solve_chains(costs.columns(first, first + width))
            labels[:, own_first:own_last] = part[:, own_first - first : own_last - first]
        return labels

    assert np.array_equal(stitched(40, 16), optimum)
    assert np.array_equal(stitched(24, 10), optimum)
    # without overlap the cut's boundary effect shows: the test can tell the difference
    assert not np.array_equal(stitched(8, 0), optimum)
    assert mrf_energy(costs, stitched(8, 0)) > mrf_energy(costs, optimum)


def test_segmented_solves_through_the_pipeline_keep_the_row_optimum(small):
    """steepest-descent from the exact labels, on segments: every segment's slice of the
    optimum is a local minimum, so stitching gives the optimum back; the level's energy is
    that of the stitched rows."""
    config, inputs, costs, optimum = _rows_level(small, "steepest-descent", 30, warm_start=True)
    inputs.initial_labels = optimum
    solution = solve_level_in_process(inputs, config)
    assert solution.bundles == inputs.shape[0] * len(segment_columns(90, 30, 12))
    assert np.array_equal(solution.labels, optimum)
    assert solution.energy == pytest.approx(mrf_energy(costs, optimum))


def test_segmented_sa_matches_whole_rows_on_a_small_scene(small):
    sa_params = {"num_reads": 10, "num_sweeps": 1000}
    config, inputs, costs, optimum = _rows_level(small, "sa", 36, solver_params=sa_params)
    solution = solve_level_in_process(inputs, config)
    assert solution.energy == pytest.approx(mrf_energy(costs, solution.labels))
    assert np.mean(solution.labels == optimum) > 0.99
    assert solution.energy <= mrf_energy(costs, optimum) * 1.005


def test_assemble_refuses_a_missing_segment(small):
    config = MatchConfig(
        max_disparity=12, inference="rows", solver="sa", bundle_width=40, bundle_margin=8
    )
    inputs = _finest_level(small, config)
    bundles = level_bundles(inputs, config)
    results = solve_bundles(inputs, config, bundles)
    assemble(inputs, results, config)  # complete
    with pytest.raises(ValueError, match=r"rows missing \[0\], rows solved twice \[\]"):
        assemble(inputs, results[:1] + results[2:], config)
    with pytest.raises(ValueError, match=r"rows missing \[\], rows solved twice \[1\]"):
        assemble(inputs, [*results, results[len(segment_columns(90, 40, 8)) + 1]], config)
