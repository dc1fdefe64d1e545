"""The two stages together (``Localizer``) on hand-made maps."""

from __future__ import annotations

import numpy as np
import pytest

from segloc_cli.estimates import STATUS_OK, STATUS_TOO_FEW_SEGMENTS
from segloc_cli.geometry import Pose2, segment_orientations, wrap_angle
from segloc_cli.method.align import align
from segloc_cli.method.extract import extract_segments
from segloc_cli.method.localize import (
    Estimate,
    LocalizeParams,
    Localizer,
    localize_scans,
    point_spread_m,
    usable_points,
)
from segloc_cli.method.tracking import track_scans
from segloc_cli.scan import Scan
from segloc_cli.sim import NOISE_FREE, random_free_poses, random_world, simulate_scan


def _pieces(x1, y1, x2, y2, n):
    """A wall stored as n equal pieces, as built maps often hold it."""
    t = np.linspace(0.0, 1.0, n + 1)
    xs, ys = x1 + t * (x2 - x1), y1 + t * (y2 - y1)
    return np.column_stack([xs[:-1], ys[:-1], xs[1:], ys[1:]])


def _stroke(x, y, length, angle_deg):
    a = np.deg2rad(angle_deg)
    return [x, y, x + length * np.cos(a), y + length * np.sin(a)]


# The scan sees a 3 m wall along x and two 2 m walls along y (robot at the origin, heading
# 0). The map holds those walls in 1 m pieces, plus, 100 m away, clutter at 10° and 100°
# whose lengths (3 m and 2 m) match the scan's walls exactly.
LOCAL = np.array([[1.0, -1.0, 4.0, -1.0], [2.0, 0.0, 2.0, 2.0], [-1.0, 1.0, -1.0, 3.0]])
NEAR = np.vstack(
    [
        _pieces(1.0, -1.0, 4.0, -1.0, 3),
        _pieces(2.0, 0.0, 2.0, 2.0, 2),
        _pieces(-1.0, 1.0, -1.0, 3.0, 2),
    ]
)
FAR = np.array(
    [_stroke(100.0 + 5 * k, 0.0, 3.0, 10.0) for k in range(3)]
    + [_stroke(100.0 + 5 * k, 10.0, 2.0, 100.0) for k in range(3)]
)
MAP = np.vstack([NEAR, FAR])


def test_distant_segments_cannot_outvote_the_walls_in_reach():
    localizer = Localizer.on_map(MAP)
    guess = Pose2(0.3, -0.2, np.deg2rad(4.0))
    # With every map segment voting, the product vote is 3·3 + 2·2 + 2·2 = 17 at 10°, where
    # the clutter lines up, against 3·1 + 2·1 + 2·1 = 7 at the true 0° (walls in 1 m pieces).
    everything = align(localizer.prepared.rtable, LOCAL, prior_rad=guess.theta, window_deg=20.0)
    assert np.rad2deg(everything.best_rad) == pytest.approx(10.0, abs=1e-9)
    assert everything.peak_votes[0] == pytest.approx(17.0)
    # Only the segments the scan can reach (its 4.2 m radius plus the search's 2·√2·1.5 m)
    # take part in the localizer's vote: the walls win.
    est = localizer.localize(LOCAL, guess)
    assert est.status == STATUS_OK
    assert abs(np.rad2deg(wrap_angle(est.align_theta_rad))) <= 0.5


def test_clutter_orientations_are_what_the_example_says():
    np.testing.assert_allclose(np.rad2deg(segment_orientations(FAR)), [10] * 3 + [100] * 3)


def test_too_few_local_segments_get_a_status_not_a_pose():
    est = Localizer.on_map(MAP).localize(LOCAL[:1], Pose2(0.0, 0.0, 0.0))
    assert est.status == STATUS_TOO_FEW_SEGMENTS
    assert np.isnan(est.pose.x) and est.n_local_segments == 1


# --- scans too poor to pin a pose ------------------------------------------------------------

ROOM_SEED = 5


def _room_and_scan():
    """A random room (no symmetry), a free pose in it and a noise-free 1024-beam scan there."""
    rng = np.random.default_rng(ROOM_SEED)
    world = random_world(rng)
    truth = Pose2(*random_free_poses(world, 1, rng)[0])
    return world, truth, simulate_scan(world, truth, NOISE_FREE, rng, 0.0)


def _near(truth: Pose2) -> Pose2:
    return Pose2(truth.x + 0.3, truth.y - 0.2, truth.theta + np.deg2rad(3.0))


def _readings(scan: Scan, keep: np.ndarray) -> Scan:
    return Scan(scan.time_s, scan.angles_rad[keep], scan.ranges_m[keep], scan.range_max_m)


def test_point_spread_by_hand():
    assert point_spread_m(np.array([[0.0, 0.0], [1.0, 1.0], [3.0, 3.0]])) == pytest.approx(0.0)
    cross = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 2.0], [0.0, -2.0]])
    # Covariance diag(0.5, 2): the smaller spread is √0.5 whatever the rotation.
    assert point_spread_m(cross) == pytest.approx(np.sqrt(0.5))
    turned = cross @ np.array([[0.6, -0.8], [0.8, 0.6]])
    assert point_spread_m(turned) == pytest.approx(np.sqrt(0.5))
    assert point_spread_m(np.zeros((1, 2))) == 0.0


def test_usable_points_drop_rows_that_are_not_finite():
    points = np.array([[1.0, 2.0], [np.nan, 0.0], [0.0, np.inf], [3.0, 4.0]])
    np.testing.assert_array_equal(usable_points(points), [[1.0, 2.0], [3.0, 4.0]])
    assert usable_points(None) is None


def test_a_normal_scan_is_still_ok():
    world, truth, scan = _room_and_scan()
    (row,) = localize_scans([scan], [_near(truth)], [0], Localizer.on_map(world.segments))
    assert row["status"] == STATUS_OK
    assert np.hypot(row["x_m"] - truth.x, row["y_m"] - truth.y) < 1e-3


def test_non_finite_points_are_left_out_not_counted_against_the_scan():
    world, truth, scan = _room_and_scan()
    points = scan.points()
    points[::5] = np.nan
    est = Localizer.on_map(world.segments).localize(extract_segments(scan), _near(truth), points)
    assert est.status == STATUS_OK
    assert est.inlier_ratio == pytest.approx(1.0)


def test_two_readings_are_too_few_segments_never_ok():
    world, truth, scan = _room_and_scan()
    two = _readings(scan, np.flatnonzero(scan.valid)[[100, 400]])
    localizer = Localizer.on_map(world.segments, global_search=True)
    (row,) = localize_scans([two], [_near(truth)], [0], localizer)
    assert row["status"] == STATUS_TOO_FEW_SEGMENTS
    assert row["n_local_segments"] == 0
    (row,) = localize_scans([two], None, [0], localizer)
    assert row["status"] == STATUS_TOO_FEW_SEGMENTS


def test_nineteen_readings_on_three_walls_are_too_few_points():
    """Three segments' worth of readings but under ``min_points``: the stages may run, the
    status still says the scan is too poor."""
    world, truth, scan = _room_and_scan()
    points = scan.points()[:19]
    local = np.array([[1.0, 0.0, 2.0, 0.0], [0.0, 1.0, 0.0, 2.0], [-1.0, 0.0, -2.0, 0.5]])
    est = Localizer.on_map(world.segments).localize(local, _near(truth), points)
    assert est.status == STATUS_TOO_FEW_SEGMENTS


def test_a_fan_on_one_ray_is_not_ok():
    """Every beam at the same angle (a file whose start and end angles are equal): the points
    lie on one ray, which fixes no pose, whatever the search finds."""
    world, truth, scan = _room_and_scan()
    ray = Scan(0.0, np.zeros(len(scan)), scan.ranges_m, scan.range_max_m)
    assert point_spread_m(ray.points()) == pytest.approx(0.0, abs=1e-9)
    localizer = Localizer.on_map(world.segments, global_search=True)
    (row,) = localize_scans([ray], [_near(truth)], [0], localizer)
    assert row["status"] == STATUS_TOO_FEW_SEGMENTS
    (row,) = localize_scans([ray], None, [0], localizer)
    assert row["status"] == STATUS_TOO_FEW_SEGMENTS


def test_one_wall_seen_alone_is_not_ok():
    """Points along one straight wall pin a heading and one offset, not a pose."""
    wall = np.column_stack([np.linspace(-3.0, 3.0, 200), np.full(200, 2.0)])
    local = np.array([[-3.0, 2.0, -1.0, 2.0], [-1.0, 2.0, 1.0, 2.0], [1.0, 2.0, 3.0, 2.0]])
    est = Localizer.on_map(MAP).localize(local, Pose2(0.0, 0.0, 0.0), wall)
    assert est.status == STATUS_TOO_FEW_SEGMENTS


def test_tracking_carries_the_guess_through_a_scan_too_poor_to_match():
    world, truth, scan = _room_and_scan()
    sparse = _readings(scan, np.flatnonzero(scan.valid)[::100])  # 11 readings
    assert sparse.points().shape[0] < LocalizeParams().min_points
    odometry = [truth, truth, truth]
    rows = list(
        track_scans([scan, sparse, scan], odometry, _near(truth), [0, 1, 2],
                    Localizer.on_map(world.segments))
    )  # fmt: skip
    assert [r["status"] for r in rows] == [STATUS_OK, STATUS_TOO_FEW_SEGMENTS, STATUS_OK]
    # The sparse scan's row holds the dead-reckoning guess: the previous estimate, unmoved.
    assert (rows[1]["x_m"], rows[1]["y_m"]) == (rows[1]["init_x_m"], rows[1]["init_y_m"])
    assert rows[1]["x_m"] == pytest.approx(rows[0]["x_m"])
    assert np.hypot(rows[2]["x_m"] - truth.x, rows[2]["y_m"] - truth.y) < 1e-3


class _PointsOnlyMatcher:
    """A matcher that reads the scan's points only and needs a guess: it answers the guess
    and notes the segments it was handed."""

    uses_segments = False
    supports_global = False

    def __init__(self, segments_world):
        self.segments_world = segments_world
        self.handed: list[np.ndarray] = []

    def localize(self, segments_robot, initial, points_robot):
        self.handed.append(segments_robot)
        return Estimate(pose=initial, status=STATUS_OK, n_local_segments=0)

    def localize_global(self, segments_robot, points_robot):
        raise AssertionError("never asked: it does not support a global search")


def test_a_matcher_that_uses_no_segments_gets_none_extracted():
    world, truth, scan = _room_and_scan()
    matcher = _PointsOnlyMatcher(world.segments)
    (row,) = localize_scans([scan], [_near(truth)], [7], matcher)
    assert [h.shape for h in matcher.handed] == [(0, 4)]
    assert (row["pose_id"], row["x_m"], row["status"]) == (7, _near(truth).x, STATUS_OK)
    assert extract_segments(scan).shape[0] > 0  # the scan has segments to extract


def test_a_global_run_needs_a_matcher_that_supports_it():
    world, _, scan = _room_and_scan()
    with pytest.raises(ValueError, match="needs an initial guess"):
        next(localize_scans([scan], None, [1], _PointsOnlyMatcher(world.segments)))


MOUNT = Pose2(0.22, 0.05, np.deg2rad(30.0))
"""A scanner 22 cm ahead of the robot's origin and 5 cm left, turned 30°."""


@pytest.mark.parametrize("refined", [False, True], ids=["two-stage", "refined"])
def test_an_off_centre_scanner_s_scans_localize_the_robot(refined):
    """Scans taken by the mounted scanner at known robot poses (noise, dropouts, people) come
    out at the robot's pose within the simulated tests' 2 cm and 0.3°, from guesses ±1.5 m
    and ±20° off the robot; the same scans unmounted would give the scanner's pose, 23 cm
    and 30° away."""
    from dataclasses import replace

    from segloc_cli.sim import SensorModel, uniform_initial_errors

    rng = np.random.default_rng(7001)
    world = random_world(rng)
    localizer = Localizer.on_map(world.segments)
    truth = random_free_poses(world, 20, rng)
    errors = uniform_initial_errors(20, 1.5, 20.0, rng)
    for pose, error in zip(truth, errors, strict=True):
        robot = Pose2(*pose)
        scan = simulate_scan(world, robot.compose(MOUNT), SensorModel(), rng, 0.0)
        mounted = replace(scan, mount=MOUNT)
        guess = Pose2(robot.x - error[0], robot.y - error[1], robot.theta - error[2])
        points = mounted.points() if refined else None
        est = localizer.localize(extract_segments(mounted), guess, points).pose
        assert np.hypot(est.x - robot.x, est.y - robot.y) < 0.02
        assert abs(np.rad2deg(wrap_angle(est.theta - robot.theta))) < 0.3
        unmounted = localizer.localize(
            extract_segments(scan), guess, scan.points() if refined else None
        ).pose
        assert np.hypot(unmounted.x - robot.x, unmounted.y - robot.y) > 0.2


@pytest.mark.parametrize("guided", [True, False], ids=["guided", "global"])
@pytest.mark.parametrize("poor", ["two readings", "one ray", "nineteen readings", "sparse"])
def test_a_scan_too_poor_to_pin_a_pose_gets_no_confidence(poor, guided):
    """The pose found for such a scan stays in its row, untrusted: no probability of being
    the right place beside it (the model gave 0.92 for nineteen readings), nor beside its
    other hypotheses."""
    world, truth, scan = _room_and_scan()
    valid = np.flatnonzero(scan.valid)
    scans = {
        "two readings": _readings(scan, valid[[100, 400]]),
        "one ray": Scan(0.0, np.zeros(len(scan)), scan.ranges_m, scan.range_max_m),
        "nineteen readings": _readings(scan, valid[:19]),
        "sparse": _readings(scan, valid[::100]),
    }
    localizer = Localizer.on_map(world.segments, global_search=True)
    guesses = [_near(truth)] if guided else None
    (row,) = localize_scans([scans[poor]], guesses, [0], localizer)
    assert row["status"] == STATUS_TOO_FEW_SEGMENTS
    assert np.isfinite(row["x_m"]), "the pose found is kept for the user to see"
    assert np.isnan(row["confidence"])
    assert row["hypotheses"] and all(np.isnan(h["confidence"]) for h in row["hypotheses"])


def test_one_wall_seen_alone_gets_no_confidence_nor_does_a_tracked_poor_scan():
    wall = np.column_stack([np.linspace(-3.0, 3.0, 200), np.full(200, 2.0)])
    local = np.array([[-3.0, 2.0, -1.0, 2.0], [-1.0, 2.0, 1.0, 2.0], [1.0, 2.0, 3.0, 2.0]])
    est = Localizer.on_map(MAP).localize(local, Pose2(0.0, 0.0, 0.0), wall)
    assert est.status == STATUS_TOO_FEW_SEGMENTS and np.isnan(est.confidence)
    world, truth, scan = _room_and_scan()
    sparse = _readings(scan, np.flatnonzero(scan.valid)[::100])
    rows = list(track_scans([scan, sparse], [truth, truth], _near(truth), [0, 1],
                            Localizer.on_map(world.segments)))  # fmt: skip
    assert rows[1]["status"] == STATUS_TOO_FEW_SEGMENTS and np.isnan(rows[1]["confidence"])
