"""Tracking along a simulated path with drifting odometry (``track_scans``)."""

from __future__ import annotations

from itertools import pairwise

import numpy as np
import pytest
from conftest import HALL

from segloc_cli.estimates import STATUS_LOST, STATUS_OK, STATUS_RECOVERED
from segloc_cli.geometry import Pose2, wrap_angle
from segloc_cli.io.maps import read_world
from segloc_cli.method.localize import Localizer
from segloc_cli.method.spatial import SegmentGrid
from segloc_cli.method.tracking import track_scans
from segloc_cli.sim import SensorModel, free_space_mask, random_world, simulate_scan

STEP_M = 0.25


def _path_through(waypoints: np.ndarray, world) -> list[Pose2]:
    """Poses every STEP_M along straight legs between waypoints, kept where free."""
    poses = []
    for a, b in pairwise(waypoints):
        n = max(1, int(np.hypot(*(b[:2] - a[:2])) / STEP_M))
        for k in range(n):
            f = k / n
            theta = a[2] + f * wrap_angle(b[2] - a[2])
            poses.append(np.array([*(a[:2] + f * (b[:2] - a[:2])), theta]))
    poses = np.array(poses)
    free = free_space_mask(world, poses[:, :2], 0.3)
    return [Pose2(*p) for p in poses[free]]


def _odometry(truth: list[Pose2], rng, slip: dict[int, Pose2] | None = None) -> list[Pose2]:
    """Dead reckoning: true increments with 2 % scale error, noise and optional slips."""
    odom = [Pose2(0.0, 0.0, 0.0)]
    for k in range(1, len(truth)):
        step = truth[k - 1].inverse().compose(truth[k])
        noisy = Pose2(
            step.x * 1.02 + rng.normal(0, 0.005),
            step.y * 1.02 + rng.normal(0, 0.005),
            step.theta + np.deg2rad(0.3) + rng.normal(0, np.deg2rad(0.2)),
        )
        if slip and k in slip:
            noisy = noisy.compose(slip[k])
        odom.append(odom[-1].compose(noisy))
    return odom


@pytest.fixture(scope="module")
def hall():
    world = read_world(HALL / "world.json")
    waypoints = np.loadtxt(HALL / "poses.csv", delimiter=",", skiprows=1)[:, 2:5]
    waypoints[:, 2] = np.deg2rad(waypoints[:, 2])
    truth = _path_through(waypoints[:5], world)
    rng = np.random.default_rng(11)
    scans = [simulate_scan(world, p, SensorModel(), rng, 0.1 * k) for k, p in enumerate(truth)]
    return world, truth, scans


def _track(world, truth, scans, odom, first_guess, localizer=None):
    localizer = localizer or Localizer.on_map(world.segments)
    rows = list(track_scans(scans, odom, first_guess, range(1, len(scans) + 1), localizer))
    est = np.array([[r["x_m"], r["y_m"], np.deg2rad(r["theta_deg"])] for r in rows])
    true = np.array([p.as_array() for p in truth])
    pos_err = np.hypot(*(est[:, :2] - true[:, :2]).T)
    head_err = np.abs(np.rad2deg(wrap_angle(est[:, 2] - true[:, 2])))
    return [r["status"] for r in rows], pos_err, head_err, rows


def test_tracking_follows_the_path_despite_odometry_drift(hall):
    world, truth, scans = hall
    odom = _odometry(truth, np.random.default_rng(1))
    # Dead reckoning alone drifts by decimetres over the path...
    dead = [truth[0].compose(odom[0].inverse().compose(o)) for o in odom]
    drift = max(np.hypot(d.x - t.x, d.y - t.y) for d, t in zip(dead, truth, strict=True))
    assert drift > 0.2
    # ... while tracking stays on it, from a first guess 40 cm and 8° off.
    first = Pose2(truth[0].x + 0.3, truth[0].y - 0.26, truth[0].theta + np.deg2rad(8))
    status, pos_err, head_err, _ = _track(world, truth, scans, odom, first)
    assert len(truth) >= 40
    assert status == [STATUS_OK] * len(truth)
    assert pos_err.max() < 0.02 and head_err.max() < 0.3


def test_a_slip_is_flagged_and_recovered_by_a_wider_search(hall):
    world, truth, scans = hall
    # At step 12 the odometry claims a 0.8 m sideways jump that never happened.
    odom = _odometry(truth, np.random.default_rng(2), slip={12: Pose2(0.0, 0.8, 0.0)})
    status, pos_err, head_err, rows = _track(world, truth, scans, odom, truth[0])
    assert status[12] == STATUS_RECOVERED
    assert np.hypot(rows[12]["init_x_m"] - truth[12].x, rows[12]["init_y_m"] - truth[12].y) > 0.7
    assert all(s == STATUS_OK for k, s in enumerate(status) if k != 12)
    assert pos_err.max() < 0.02 and head_err.max() < 0.3


@pytest.mark.parametrize("slip_deg", [25.0, -25.0])
def test_a_heading_slip_is_recovered(hall, slip_deg):
    # Odometry claims a turn that never happened, beyond the fit's reach and the
    # plain jump limit (15°) but within the first widening (30°).
    world, truth, scans = hall
    slip = {12: Pose2(0.0, 0.0, np.deg2rad(slip_deg))}
    odom = _odometry(truth, np.random.default_rng(6), slip=slip)
    status, pos_err, head_err, rows = _track(world, truth, scans, odom, truth[0])
    assert status[12] == STATUS_RECOVERED
    assert abs(rows[12]["init_theta_deg"] - np.rad2deg(truth[12].theta)) > 20.0
    assert all(s == STATUS_OK for k, s in enumerate(status) if k != 12)
    assert pos_err.max() < 0.02 and head_err.max() < 0.3


def test_a_slip_beyond_the_first_widening_is_found_by_the_next(hall):
    world, truth, scans = hall
    # A 50° phantom turn: the first recovery search reaches 30°, the next one 60°.
    odom = _odometry(truth, np.random.default_rng(7), slip={12: Pose2(0.0, 0.0, np.deg2rad(50))})
    status, pos_err, head_err, _ = _track(world, truth, scans, odom, truth[0])
    assert status[12] == STATUS_LOST
    assert status[13] == STATUS_RECOVERED
    assert all(s == STATUS_OK for k, s in enumerate(status) if k not in (12, 13))
    found = np.arange(len(status)) != 12
    assert pos_err[found].max() < 0.02 and head_err[found].max() < 0.3


def test_a_scan_that_matches_nothing_is_lost_and_the_track_goes_on(hall):
    world, truth, scans = hall
    odom = _odometry(truth, np.random.default_rng(3))
    # Scan 20 comes from another building: no match may be accepted for it.
    elsewhere = random_world(np.random.default_rng(99))
    stranger = simulate_scan(
        elsewhere, Pose2(5.0, 5.0, 0.0), SensorModel(), np.random.default_rng(4), 2.0
    )
    scans = [*scans[:20], stranger, *scans[21:]]
    status, pos_err, head_err, rows = _track(world, truth, scans, odom, truth[0])
    assert status[20] == STATUS_LOST
    # A lost scan reports the dead-reckoning guess, and the next scans are found again.
    assert (rows[20]["x_m"], rows[20]["y_m"]) == (rows[20]["init_x_m"], rows[20]["init_y_m"])
    assert all(s == STATUS_OK for k, s in enumerate(status) if k != 20)
    ok = np.arange(len(status)) != 20
    assert pos_err[ok].max() < 0.02 and head_err[ok].max() < 0.3


def test_the_map_grid_changes_no_tracked_pose(hall):
    """Tracking through the localizer's fine grid of the map repeats, bit for bit, tracking
    that tests every segment (a grid of one cell), recovery searches included."""
    from dataclasses import replace

    world, truth, scans = hall
    odom = _odometry(truth, np.random.default_rng(2), slip={12: Pose2(0.0, 0.8, 0.0)})
    one_cell = SegmentGrid(world.segments, cell_m=np.inf)
    localizer = Localizer.on_map(world.segments)
    plain = Localizer(replace(localizer.prepared, near_index=one_cell))
    assert plain.with_params(plain.params).prepared.near_index is one_cell
    *_, rows = _track(world, truth, scans, odom, truth[0], localizer)
    *_, expected = _track(world, truth, scans, odom, truth[0], plain)
    assert [r["status"] for r in rows].count(STATUS_RECOVERED) == 1
    for row, reference in zip(rows, expected, strict=True):
        np.testing.assert_equal({**row, "runtime_ms": 0.0}, {**reference, "runtime_ms": 0.0})


def test_tracking_an_off_centre_scanner_follows_the_robot(hall):
    """Scans taken by a scanner 22 cm ahead of the robot's origin and turned 15°, with the
    robot's odometry: the track is the robot's path, not the scanner's."""
    from dataclasses import replace

    world, truth, _ = hall
    mount = Pose2(0.22, 0.0, np.deg2rad(15.0))
    rng = np.random.default_rng(12)
    scans = [
        replace(simulate_scan(world, p.compose(mount), SensorModel(), rng, 0.1 * k), mount=mount)
        for k, p in enumerate(truth)
    ]
    odom = _odometry(truth, np.random.default_rng(1))
    first = Pose2(truth[0].x + 0.3, truth[0].y - 0.26, truth[0].theta + np.deg2rad(8))
    status, pos_err, head_err, _ = _track(world, truth, scans, odom, first)
    assert status == [STATUS_OK] * len(truth)
    assert pos_err.max() < 0.02 and head_err.max() < 0.3
