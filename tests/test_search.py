"""Score rasters, the hypothesis search, the confidence verdict and global localization."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from segloc_cli.confidence import (
    STATUS_AMBIGUOUS,
    STATUS_LOST,
    STATUS_OK,
    ConfidenceParams,
    judge,
)
from segloc_cli.extract import extract_segments
from segloc_cli.field import coarse_bound, score_raster
from segloc_cli.geometry import Pose2, point_segment_distances, wrap_angle
from segloc_cli.io.maps import World
from segloc_cli.localize import STATUS_TOO_FEW_SEGMENTS, LocalizeParams, Localizer
from segloc_cli.search import HypothesisSearch, distinct
from segloc_cli.sim import NOISE_FREE, random_free_poses, random_world, simulate_scan


def _errors(pose: Pose2, truth: Pose2) -> tuple[float, float]:
    """Position (m) and heading (°) error."""
    return (
        float(np.hypot(pose.x - truth.x, pose.y - truth.y)),
        abs(float(np.rad2deg(wrap_angle(pose.theta - truth.theta)))),
    )


def test_score_raster_values_by_hand():
    raster = score_raster(np.array([[0.0, 0.0, 1.0, 0.0]]), cell_m=0.05, radius_m=0.1, margin_m=0.2)
    np.testing.assert_allclose(raster.origin, [-0.2, -0.2])
    points = np.array([[0.5, 0.0], [0.5, 0.05], [0.5, -0.1], [1.05, 0.0], [0.5, 0.3], [9.0, 9.0]])
    # On the wall 1; 5 cm away 1 − 0.25; at the radius and beyond 0; 5 cm past its end 0.75;
    # outside the raster 0.
    np.testing.assert_allclose(raster.lookup(points), [1.0, 0.75, 0.0, 0.75, 0.0, 0.0], atol=1e-6)


@settings(max_examples=40, deadline=None)
@given(
    st.integers(min_value=2, max_value=6),
    st.integers(min_value=1, max_value=30),
    st.integers(min_value=1, max_value=30),
    st.integers(min_value=0, max_value=2**31),
)
def test_coarse_bound_bounds_every_shift_within_a_block(factor, nx, ny, seed):
    fine = np.random.default_rng(seed).random((nx, ny)).astype(np.float32)
    bound = coarse_bound(fine, factor)
    for b in range(nx):
        for c in range(ny):
            for u in range(factor):
                for v in range(factor):
                    inside = b + u < nx and c + v < ny
                    value = fine[b + u, c + v] if inside else 0.0
                    assert bound[b // factor, c // factor] >= value


def test_distinct_poses():
    a = Pose2.from_deg(0.0, 0.0, 0.0)
    assert not distinct([a], Pose2.from_deg(0.2, 0.2, 2.0), 0.3, 3.0)
    assert distinct([a], Pose2.from_deg(0.3, 0.3, 0.0), 0.3, 3.0)
    assert distinct([a], Pose2.from_deg(0.0, 0.0, 4.0), 0.3, 3.0)
    assert not distinct([a], Pose2.from_deg(0.0, 0.0, 359.0), 0.3, 3.0)


@pytest.mark.parametrize(
    ("inliers", "runner_up", "status"),
    [(0.9, 0.0, STATUS_OK), (0.9, 0.85, STATUS_AMBIGUOUS), (0.45, 0.0, STATUS_LOST)],
)
def test_judge(inliers, runner_up, status):
    assert judge(inliers, runner_up, ConfidenceParams(0.5, 0.1)) == status


@pytest.mark.parametrize("seed", [7101, 7202])
def test_search_ranks_the_true_pose_first_from_far_off(seed):
    """From 1.8 m and 18° away, the best grid pose lies within a cell and a degree of the truth."""
    rng = np.random.default_rng(seed)
    world = random_world(rng)
    search = HypothesisSearch(world.segments)
    for truth in random_free_poses(world, 4, rng):
        true = Pose2(*truth)
        points = simulate_scan(world, true, NOISE_FREE, rng, 0.0).points()
        sign = rng.choice([-1.0, 1.0], 3)
        guess = Pose2(true.x + sign[0] * 1.8, true.y + sign[1] * 1.8, true.theta + sign[2] * 0.314)
        best = search.around(points, guess, 20.0)[0]
        position, heading = _errors(best.pose, true)
        assert position <= 0.05 and heading <= 1.0
        assert best.score > 0.9


@pytest.mark.parametrize("seed", [7303, 7404])
def test_global_localization_in_a_world_without_symmetry(seed):
    rng = np.random.default_rng(seed)
    world = random_world(rng)
    localizer = Localizer(world.segments)
    for truth in random_free_poses(world, 3, rng):
        true = Pose2(*truth)
        scan = simulate_scan(world, true, NOISE_FREE, rng, 0.0)
        est = localizer.localize_global(extract_segments(scan), scan.points())
        position, heading = _errors(est.pose, true)
        assert position < 1e-3 and heading < 0.01
        assert est.status == STATUS_OK
        assert est.inlier_ratio == pytest.approx(1.0)


def test_global_localization_with_too_few_segments_keeps_the_pose_but_not_the_trust():
    """A local map too small for the two stages does not stop the search: the points find the
    pose, which the row keeps, but the status says the scan was too poor to trust it."""
    rng = np.random.default_rng(5)
    world = random_world(rng)
    true = Pose2(*random_free_poses(world, 1, rng)[0])
    scan = simulate_scan(world, true, NOISE_FREE, rng, 0.0)
    local = extract_segments(scan)
    localizer = Localizer(world.segments, LocalizeParams(min_segments=local.shape[0] + 1))
    est = localizer.localize_global(local, scan.points())
    position, heading = _errors(est.pose, true)
    assert position < 1e-3 and heading < 0.01
    assert est.status == STATUS_TOO_FEW_SEGMENTS
    assert np.isnan(est.align_theta_rad)  # stage 1 did not run


def test_global_localization_in_a_symmetric_room_is_ambiguous():
    """A bare 8 m × 5 m room looks the same from a pose and its half-turn about the centre."""
    corners = np.array([[0.0, 0.0], [8.0, 0.0], [8.0, 5.0], [0.0, 5.0]])
    room = World(np.hstack([corners, np.roll(corners, -1, axis=0)]))
    true = Pose2.from_deg(2.5, 1.5, 30.0)
    twin = Pose2.from_deg(8.0 - 2.5, 5.0 - 1.5, 30.0 - 180.0)
    scan = simulate_scan(room, true, NOISE_FREE, np.random.default_rng(1), 0.0)
    est = Localizer(room.segments).localize_global(extract_segments(scan), scan.points())
    assert est.status == STATUS_AMBIGUOUS
    found = sorted([est.pose, est.runner_up], key=lambda pose: _errors(pose, true)[0])
    for pose, expected in zip(found, (true, twin), strict=True):
        position, heading = _errors(pose, expected)
        assert position < 1e-3 and heading < 0.01
    assert est.runner_up_ratio == pytest.approx(est.inlier_ratio)


def test_distance_raster_visits_every_cell_within_reach():
    """Walking each segment column by column gives the distances of a full scan of the grid."""
    rng = np.random.default_rng(3)
    segments = np.vstack(
        [
            rng.uniform(0.0, 6.0, (12, 4)),
            [[1.0, 1.0, 1.0, 5.0], [0.5, 2.0, 5.5, 2.0], [3.0, 3.0, 3.0 + 1e-12, 4.0]],
        ]
    )
    raster = score_raster(segments, cell_m=0.05, radius_m=0.1, margin_m=0.1)
    nx, ny = raster.score.shape
    centres = raster.origin + 0.05 * np.stack(
        np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij"), axis=-1
    ).reshape(-1, 2)
    d = point_segment_distances(centres, segments).min(axis=1)
    expected = np.clip(1.0 - (np.minimum(d, 0.1).astype(np.float32) / 0.1) ** 2, 0.0, 1.0)
    np.testing.assert_allclose(raster.score.reshape(-1), expected, atol=2e-6)


def test_raster_past_its_cell_budget_takes_coarser_cells():
    wall = np.array([[0.0, 0.0, 10.0, 0.0]])
    raster = score_raster(wall, cell_m=0.05, radius_m=0.1, margin_m=0.1, max_cells=700)
    # 5 cm: 205 × 5 cells; 6.25 cm: 165 × 5; 7.8125 cm: 133 × 5 = 665.
    assert raster.score.shape == (133, 5)
    assert raster.cell_m == pytest.approx(0.05 * 1.25**2)
    # The radius grew with the cell (to 2 cells): one cell off the wall scores 1 − (1/2)².
    points = np.array([[5.0, 0.0], [5.0, raster.cell_m], [5.0, 3 * raster.cell_m]])
    np.testing.assert_allclose(raster.lookup(points), [1.0, 0.75, 0.0], atol=1e-6)


def test_lookup_of_points_that_are_not_finite_or_far_is_zero():
    raster = score_raster(np.array([[0.0, 0.0, 1.0, 0.0]]), cell_m=0.05, radius_m=0.1, margin_m=0.2)
    points = np.array([[np.nan, 0.0], [0.5, np.inf], [1e30, 0.0], [-1e300, 0.0], [0.5, 0.0]])
    np.testing.assert_array_equal(raster.lookup(points), [0.0, 0.0, 0.0, 0.0, 1.0])


def test_bounds_in_batches_find_the_same_poses(monkeypatch):
    """Bounding a few headings at a time (as a large map's global search does) and cutting
    each batch to its best blocks finds the same hypotheses as bounding all at once."""
    import segloc_cli.search as search_module

    rng = np.random.default_rng(7303)
    world = random_world(rng)
    true = Pose2(*random_free_poses(world, 1, rng)[0])
    points = simulate_scan(world, true, NOISE_FREE, rng, 0.0).points()
    whole = HypothesisSearch(world.segments).everywhere(points)
    monkeypatch.setattr(search_module, "MAX_BOUND_CELLS", 5000)
    monkeypatch.setattr(search_module, "FULL_SORT_CELLS", 100)
    batched = HypothesisSearch(world.segments).everywhere(points)
    assert [h.pose for h in batched] == [h.pose for h in whole]
    assert [h.score for h in batched] == pytest.approx([h.score for h in whole])
