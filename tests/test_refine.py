"""Least-squares refinement of a pose from scan points and map segments (``refine``)."""

from __future__ import annotations

import numpy as np
import pytest

from segloc_cli.geometry import (
    Pose2,
    point_segment_distances,
    rotation,
    transform_points,
    wrap_angle,
)
from segloc_cli.method.refine import (
    Refinement,
    RefineParams,
    inlier_ratio,
    nearest_segments,
    refine_pose,
    support,
)
from segloc_cli.method.spatial import SegmentGrid
from segloc_cli.sim import NOISE_FREE, SensorModel, random_free_poses, random_world, simulate_scan


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


def _numpy_fit(points: np.ndarray, segments: np.ndarray, initial: Pose2, p: RefineParams):
    """The fit written step by step in numpy, brute force over the segments: the reference
    the compiled fit must repeat (same gates, weights, prior, stopping rules and result)."""
    radii = np.hypot(points[:, 0], points[:, 1])
    reach = float(radii[np.isfinite(radii)].max(initial=0.0)) + 2.0 * p.gate_m
    segments = segments[point_segment_distances([initial.x, initial.y], segments)[0] <= reach]
    d = segments[:, 2:4] - segments[:, 0:2]
    length = np.hypot(d[:, 0], d[:, 1])
    normals = np.column_stack([-d[:, 1], d[:, 0]]) / np.where(length > 0, length, 1.0)[:, None]
    gates = [p.gate_m]
    while gates[-1] / 2.0 > p.final_gate_m:
        gates.append(gates[-1] / 2.0)
    if gates[-1] > p.final_gate_m:
        gates.append(p.final_gate_m)
    prior = np.zeros(3)
    if p.prior_sigma_m is not None:
        prior[:2] = (p.point_sigma_m / p.prior_sigma_m) ** 2
    if p.prior_sigma_deg is not None:
        prior[2] = (p.point_sigma_m / np.deg2rad(p.prior_sigma_deg)) ** 2
    pose = initial.as_array()
    for gate in gates:
        for _ in range(p.steps_per_round):
            rotated = points @ rotation(pose[2]).T
            world = rotated + pose[:2]
            # No candidate lists: every point against every segment near the guess.
            dist = point_segment_distances(world, segments)
            index = np.argmin(np.where(np.isnan(dist), np.inf, dist), axis=1)
            nearest = dist[np.arange(len(points)), index]
            use = nearest <= gate
            if np.count_nonzero(use) < p.min_points:
                break
            normal = normals[index[use]]
            residual = np.sum(normal * (world[use] - segments[index[use], 0:2]), axis=1)
            jacobian = np.column_stack(
                [normal, normal[:, 0] * -rotated[use, 1] + normal[:, 1] * rotated[use, 0]]
            )
            weight = 1.0 / (1.0 + (residual / (0.5 * gate)) ** 2)
            jw = jacobian * weight[:, None]
            offset = pose - initial.as_array()
            offset[2] = wrap_angle(offset[2])
            hessian = jw.T @ jacobian + np.diag(prior + 1e-6)
            step = np.linalg.solve(hessian, -jw.T @ residual - prior * offset)
            pose = pose + step
            pose[2] = wrap_angle(pose[2])
            if np.hypot(step[0], step[1]) < 1e-5 and abs(step[2]) < 1e-6:
                break
    fitted = Pose2(*(float(v) for v in pose))
    dist = point_segment_distances(transform_points(points, fitted), segments).min(axis=1)
    inliers = dist <= p.final_gate_m
    rms = float(np.sqrt(np.mean(dist[inliers] ** 2))) if inliers.any() else float("nan")
    score = float(np.mean(np.clip(1.0 - (dist / p.final_gate_m) ** 2, 0.0, 1.0)))
    return Refinement(fitted, float(np.mean(inliers)), rms, len(points), score)


def _apart(segments: np.ndarray, gap_m: float = 0.01) -> np.ndarray:
    """The segments (M, 4) shortened by ``gap_m`` at each end, so that no two share an end.

    A point beyond the shared end of two segments is equally far from both, and which of
    the two a difference in the last bit picks moves the fit by up to its stopping
    tolerance (steps of 1e-5 m); apart, every point has one nearest segment.
    """
    d = segments[:, 2:4] - segments[:, 0:2]
    length = np.hypot(d[:, 0], d[:, 1])[:, None]
    unit = d / length
    return np.hstack([segments[:, 0:2] + gap_m * unit, segments[:, 2:4] - gap_m * unit])


@pytest.mark.parametrize("seed", range(8))
def test_the_compiled_fit_repeats_the_numpy_fit(seed):
    rng = np.random.default_rng(1000 + seed)
    world = random_world(rng)
    segments = _apart(world.segments)
    params = [RefineParams(), RefineParams(prior_sigma_m=0.1, prior_sigma_deg=2.0)][seed % 2]
    for truth in random_free_poses(world, 4, rng):
        true = Pose2(*truth)
        points = simulate_scan(world, true, SensorModel(), rng, 0.0).points()
        start = Pose2(
            true.x + rng.uniform(-0.3, 0.3),
            true.y + rng.uniform(-0.3, 0.3),
            true.theta + np.deg2rad(rng.uniform(-5.0, 5.0)),
        )
        expected = _numpy_fit(points, segments, start, params)
        fit = refine_pose(points, segments, start, params)
        assert fit.pose.x == pytest.approx(expected.pose.x, abs=1e-9)
        assert fit.pose.y == pytest.approx(expected.pose.y, abs=1e-9)
        assert fit.pose.theta == pytest.approx(expected.pose.theta, abs=1e-9)
        assert fit.inlier_ratio == expected.inlier_ratio
        assert fit.rms_m == pytest.approx(expected.rms_m, abs=1e-9)
        assert fit.score == pytest.approx(expected.score, abs=1e-9)
        assert fit.n_points == expected.n_points


def test_the_map_index_changes_nothing():
    """Fits and verdicts through a grid of the map are bit for bit those without it."""
    rooms = [random_world(np.random.default_rng(500 + k)) for k in range(4)]
    segments = np.concatenate(
        [room.segments + [22.0 * (k % 2), 16.0 * (k // 2)] * 2 for k, room in enumerate(rooms)]
    )
    rng = np.random.default_rng(5)
    for cell_m in (0.5, 4.0):
        grid = SegmentGrid(segments, cell_m=cell_m)
        for truth in random_free_poses(rooms[3], 5, rng):
            true = Pose2(truth[0] + 22.0, truth[1] + 16.0, truth[2])
            points = simulate_scan(rooms[3], Pose2(*truth), SensorModel(), rng, 0.0).points()
            start = Pose2(true.x + 0.25, true.y - 0.2, true.theta + 0.05)
            for params in (RefineParams(), RefineParams(prior_sigma_m=0.2, prior_sigma_deg=3.0)):
                plain = refine_pose(points, segments, start, params)
                assert refine_pose(points, segments, start, params, index=grid) == plain
            for band in (0.05, 0.3):
                assert support(points, segments, true, band, index=grid) == support(
                    points, segments, true, band
                )
            world_points = transform_points(points, true)
            for bound in (0.05, 0.5):
                found, dist = nearest_segments(world_points, segments, index=grid, within_m=bound)
                brute, brute_dist = nearest_segments(world_points, segments, within_m=bound)
                np.testing.assert_array_equal(found, brute)
                np.testing.assert_array_equal(dist, brute_dist)


def test_an_index_of_another_map_is_refused():
    segments = np.array([[0.0, 0.0, 4.0, 0.0], [0.0, 0.0, 0.0, 3.0]])
    grid = SegmentGrid(segments[:1])
    with pytest.raises(ValueError, match="index"):
        refine_pose(np.ones((10, 2)), segments, Pose2(0.0, 0.0, 0.0), index=grid)


def test_nearest_within_a_bound_leaves_farther_points_unpaired():
    segments = np.array([[0.0, 0.0, 4.0, 0.0], [5.0, -1.0, 5.0, 1.0]])
    points = np.array([[1.0, 0.5], [4.8, 0.2], [-3.0, 4.0], [np.nan, 0.0]])
    grid = SegmentGrid(segments, cell_m=1.0)
    for index in (None, grid):
        found, dist = nearest_segments(points, segments, index=index, within_m=0.6)
        assert found.tolist() == [0, 1, -1, -1]
        np.testing.assert_allclose(dist, [0.5, 0.2, np.inf, np.inf])
