"""Least-squares refinement of a pose from scan points and map segments (``refine``)."""

from __future__ import annotations

import numpy as np
import pytest

from segloc_cli.geometry import Pose2, transform_points, wrap_angle
from segloc_cli.refine import RefineParams, inlier_ratio, nearest_segments, refine_pose
from segloc_cli.sim import NOISE_FREE, random_free_poses, random_world, simulate_scan


def test_nearest_segment_and_distance_by_hand():
    segments = np.array([[0.0, 0.0, 4.0, 0.0], [5.0, -1.0, 5.0, 1.0]])
    points = np.array([[1.0, 0.5], [4.8, 0.2], [-3.0, 4.0], [7.0, 1.0]])
    index, dist = nearest_segments(points, segments)
    assert index.tolist() == [0, 1, 0, 1]
    np.testing.assert_allclose(dist, [0.5, 0.2, 5.0, 2.0])


def test_inlier_ratio_counts_points_within_the_band():
    segments = np.array([[0.0, 0.0, 4.0, 0.0]])
    # In the robot frame of pose (1, 1, 90°) the wall y = 0 is the line x = -1.
    points = np.array([[-1.0, 0.5], [-1.04, -2.0], [-0.9, 0.0], [-1.0, 3.5]])
    pose = Pose2.from_deg(1.0, 1.0, 90.0)
    assert inlier_ratio(points, segments, pose, 0.05) == pytest.approx(0.5)
    assert inlier_ratio(points, segments, pose, 0.15) == pytest.approx(0.75)


@pytest.mark.parametrize("seed", [101, 202, 303])
def test_recovers_the_pose_to_a_millimetre_from_noise_free_scans(seed):
    rng = np.random.default_rng(seed)
    world = random_world(rng)
    for truth in random_free_poses(world, 10, rng):
        true = Pose2(*truth)
        points = simulate_scan(world, true, NOISE_FREE, rng, 0.0).points()
        start = Pose2(
            true.x + rng.uniform(-0.1, 0.1),
            true.y + rng.uniform(-0.1, 0.1),
            true.theta + np.deg2rad(rng.uniform(-2.0, 2.0)),
        )
        fit = refine_pose(points, world.segments, start)
        assert np.hypot(fit.pose.x - true.x, fit.pose.y - true.y) < 1e-3
        assert abs(np.rad2deg(wrap_angle(fit.pose.theta - true.theta))) < 0.01
        assert fit.inlier_ratio == pytest.approx(1.0)


def _corridor_scan(pose: Pose2) -> tuple[np.ndarray, np.ndarray]:
    """Map of two parallel walls y = ±1 (x in [-20, 20]) and points on them, robot frame."""
    walls = np.array([[-20.0, -1.0, 20.0, -1.0], [-20.0, 1.0, 20.0, 1.0]])
    x = np.linspace(-4.0, 4.0, 41)
    world = np.concatenate(
        [np.column_stack([x, -np.ones_like(x)]), np.column_stack([x, np.ones_like(x)])]
    )
    return walls, transform_points(world, pose.inverse())


def test_a_prior_holds_the_pose_where_the_points_say_nothing():
    true = Pose2(2.0, 0.0, 0.0)
    walls, points = _corridor_scan(true)
    # The guess is 0.4 m off along the corridor and 6 cm across it.
    guess = Pose2(2.4, 0.06, np.deg2rad(1.0))
    held = refine_pose(points, walls, guess, RefineParams(prior_sigma_m=0.02, prior_sigma_deg=1.0))
    assert held.pose.x == pytest.approx(2.4, abs=1e-6)  # nothing says otherwise
    # Across it the 82 points outvote the prior, which weighs as one point.
    assert abs(held.pose.y) < 0.06 / 20
    assert abs(np.rad2deg(held.pose.theta)) < 0.05


def test_clutter_beyond_the_gate_does_not_move_the_fit():
    rng = np.random.default_rng(7)
    world = random_world(rng)
    true = Pose2(*random_free_poses(world, 1, rng, clearance_m=0.8)[0])
    points = simulate_scan(world, true, NOISE_FREE, rng, 0.0).points()
    # People around the robot: a fifth as many points again, all within 0.3 m of
    # the scanner and so at least 0.5 m from every wall.
    n = points.shape[0] // 5
    angle, radius = rng.uniform(-np.pi, np.pi, n), rng.uniform(0.1, 0.3, n)
    clutter = np.column_stack([radius * np.cos(angle), radius * np.sin(angle)])
    fit = refine_pose(np.concatenate([points, clutter]), world.segments, true)
    assert np.hypot(fit.pose.x - true.x, fit.pose.y - true.y) < 1e-3
    assert fit.inlier_ratio == pytest.approx(points.shape[0] / (points.shape[0] + n))


def test_no_points_or_no_map_returns_the_guess():
    guess = Pose2(1.0, 2.0, 0.3)
    assert refine_pose(np.zeros((0, 2)), np.array([[0.0, 0.0, 1.0, 0.0]]), guess).pose == guess
    assert refine_pose(np.ones((5, 2)), np.zeros((0, 4)), guess).pose == guess


def test_points_that_are_not_finite_take_no_part_in_the_fit():
    segments = np.array([[0.0, 0.0, 4.0, 0.0], [0.0, 0.0, 0.0, 3.0], [4.0, 0.0, 4.0, 3.0]])
    truth = Pose2(2.0, 1.0, 0.0)
    # Points on the three walls, in the robot frame of the truth, plus hostile rows.
    t = np.linspace(0.1, 0.9, 20)
    walls = np.vstack(
        [
            np.column_stack([4 * t, 0 * t]),
            np.column_stack([0 * t, 3 * t]),
            np.column_stack([4 + 0 * t, 3 * t]),
        ]
    )
    points = walls - [truth.x, truth.y]
    hostile = np.vstack([points, [[np.nan, 0.0], [np.inf, 1.0], [1e30, -1e30]]])
    guess = Pose2(2.1, 0.95, 0.02)
    clean = refine_pose(points, segments, guess)
    fit = refine_pose(hostile, segments, guess)
    assert fit.pose.x == pytest.approx(truth.x, abs=1e-6)
    assert fit.pose.y == pytest.approx(truth.y, abs=1e-6)
    assert fit.pose == clean.pose
    assert fit.inlier_ratio == pytest.approx(60 / 63)
