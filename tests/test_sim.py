"""Tests of the range-sensor simulator, the initial-error generators and the worlds."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from conftest import HALL

from segloc_cli.geometry import Pose2, point_segment_distances, relative_motion, wrap_angle
from segloc_cli.io.maps import read_map
from segloc_cli.io.mcap_log import read_log
from segloc_cli.io.tables import read_pose_table
from segloc_cli.sim import (
    OdometryDrift,
    SensorModel,
    beam_angles,
    cast_rays,
    drifting_odometry,
    free_space_mask,
    initial_guesses,
    paper_initial_errors,
    parse_odometry,
    random_free_poses,
    random_world,
    repeating_corridor,
    sensor_model,
    simulate_scan,
    symmetric_room,
    uniform_initial_errors,
)
from segloc_cli.world import World

# A sensor without any random effect, so ranges are the exact geometry (rounded to 1 mm).
EXACT = SensorModel(
    readings=1024, noise_cm=0.0, dropout_prob=0.0, glass_return_prob=0.0, clutter_clusters=0.0
)

WALL_X2 = np.array([[2.0, -50.0, 2.0, 50.0]])
# A 10 m × 10 m room centred on the origin, every beam from inside hits a wall.
ROOM = np.array(
    [
        [-5.0, -5.0, 5.0, -5.0],
        [5.0, -5.0, 5.0, 5.0],
        [5.0, 5.0, -5.0, 5.0],
        [-5.0, 5.0, -5.0, -5.0],
    ]
)


def room_ranges(angles_rad: np.ndarray, x: float, y: float) -> np.ndarray:
    """Exact distance from (x, y) to the walls of ROOM along each angle."""
    c, s = np.cos(angles_rad), np.sin(angles_rad)
    with np.errstate(divide="ignore"):
        tx = np.where(c > 0, (5.0 - x) / c, np.where(c < 0, (-5.0 - x) / c, np.inf))
        ty = np.where(s > 0, (5.0 - y) / s, np.where(s < 0, (-5.0 - y) / s, np.inf))
    return np.minimum(tx, ty)


def point_segment_distance(p: np.ndarray, seg: np.ndarray) -> float:
    a, b = seg[:2], seg[2:]
    u = np.clip(np.dot(p - a, b - a) / np.dot(b - a, b - a), 0.0, 1.0)
    return float(np.linalg.norm(p - (a + u * (b - a))))


# --- beam angles and ray casting -------------------------------------------------------------


def test_beam_angles_cover_the_circle_counter_clockwise_from_forward():
    angles = beam_angles(256)
    assert angles.shape == (256,)
    assert angles[0] == 0.0
    assert angles[64] == pytest.approx(np.pi / 2)
    assert angles[-1] == pytest.approx(2 * np.pi * 255 / 256)


def test_wall_at_x2_seen_from_origin_is_2_over_cos():
    angles = np.deg2rad(np.array([-80.0, -45.0, -10.0, 0.0, 30.0, 60.0, 85.0]))
    ranges = cast_rays(WALL_X2, np.zeros(2), angles)
    np.testing.assert_allclose(ranges, 2.0 / np.cos(angles), rtol=1e-12)


def test_beam_hitting_nothing_is_inf():
    angles = np.deg2rad(np.array([90.0, 120.0, 180.0, 270.0, -100.0]))
    assert np.all(np.isinf(cast_rays(WALL_X2, np.zeros(2), angles)))
    assert np.all(np.isinf(cast_rays(np.zeros((0, 4)), np.zeros(2), angles)))


def test_nearest_of_two_walls_wins_whatever_their_order():
    walls = np.array([[3.0, -10.0, 3.0, 10.0], [1.5, -10.0, 1.5, 10.0]])
    angles = np.deg2rad(np.array([0.0, 20.0, -40.0]))
    expected = 1.5 / np.cos(angles)
    np.testing.assert_allclose(cast_rays(walls, np.zeros(2), angles), expected)
    np.testing.assert_allclose(cast_rays(walls[::-1], np.zeros(2), angles), expected)


def test_short_segment_is_hit_only_within_its_ends_and_origin_is_honoured():
    # A segment from (4, 1) to (4, 3) seen from (1, 1): beams between 0° and atan2(2, 3).
    segment = np.array([[4.0, 1.0, 4.0, 3.0]])
    origin = np.array([1.0, 1.0])
    inside = np.array([0.0, 0.5 * np.arctan2(2.0, 3.0), np.arctan2(2.0, 3.0) - 1e-6])
    outside = np.array([-0.01, np.arctan2(2.0, 3.0) + 0.01, np.pi])
    np.testing.assert_allclose(cast_rays(segment, origin, inside), 3.0 / np.cos(inside))
    assert np.all(np.isinf(cast_rays(segment, origin, outside)))


def test_walls_behind_the_origin_are_not_hit():
    walls = np.array([[-0.5, -10.0, -0.5, 10.0], [2.0, -10.0, 2.0, 10.0]])
    ranges = cast_rays(walls, np.zeros(2), np.array([0.0, np.pi, 0.2]))
    np.testing.assert_allclose(ranges, [2.0, 0.5, 2.0 / np.cos(0.2)])


def test_transparent_mask_lets_a_beam_through_one_segment():
    walls = np.array([[1.0, -10.0, 1.0, 10.0], [2.5, -10.0, 2.5, 10.0]])
    angles = np.array([0.0, 0.3])
    transparent = np.array([[True, False], [False, False]])
    ranges = cast_rays(walls, np.zeros(2), angles, transparent)
    np.testing.assert_allclose(ranges, [2.5, 1.0 / np.cos(0.3)])


# --- the sensor model ------------------------------------------------------------------------


def test_sensor_model_takes_any_fan_and_refuses_impossible_ones():
    for readings, fov_deg in ((128, 360.0), (2048, 360.0), (361, 180.0), (2, 0.5), (100_000, 1)):
        assert SensorModel(readings=readings, fov_deg=fov_deg).readings == readings
    assert SensorModel().is_explorer and not SensorModel(readings=361, fov_deg=180).is_explorer
    for bad in ({"readings": 1}, {"readings": 100_001}, {"fov_deg": 0.0}, {"fov_deg": 360.5}):
        with pytest.raises(ValueError):
            SensorModel(**bad)
    with pytest.raises(ValueError):
        SensorModel(dropout_prob=1.5)


def test_sensor_choices_switch_clutter_and_glass_off_and_come_back_from_the_model():
    model = sensor_model({"readings": 181, "fov_deg": 90, "clutter": False, "glass": False})
    assert (model.clutter_clusters, model.glass_return_prob) == (0.0, 1.0)
    assert model.choices == {
        "readings": 181, "fov_deg": 90.0, "noise_cm": 1.2, "clutter": False, "glass": False
    }  # fmt: skip
    assert sensor_model({}) == SensorModel()
    assert sensor_model(SensorModel().choices) == SensorModel()
    with pytest.raises(KeyError):
        sensor_model({"beams": 3})


@pytest.mark.parametrize(("readings", "fov_deg"), [(361, 180.0), (5, 40.0), (682, 239.77)])
def test_a_narrower_fan_is_centred_ahead_with_a_beam_on_each_edge(readings, fov_deg):
    angles = np.rad2deg(beam_angles(readings, fov_deg))
    assert angles.shape == (readings,)
    assert angles[0] == pytest.approx(-fov_deg / 2, abs=1e-12)
    assert angles[-1] == pytest.approx(fov_deg / 2, abs=1e-12)
    np.testing.assert_allclose(np.diff(angles), fov_deg / (readings - 1))


class OneClusterNearTheEnd:
    """Random draws of one clutter cluster, 0.5 m wide at 1 m, from the second-last beam."""

    def poisson(self, mean):
        return 1

    def uniform(self, low, high):
        return {0.8: 1.0, 0.3: 0.5}[low]

    def integers(self, n):
        return n - 2


def test_clutter_on_a_fan_stops_at_its_edge_and_on_a_full_turn_wraps():
    """A person seen at the last beams of a fan is not also seen at its first (the fan's
    other edge, far from them); on a full turn the last beams and the first are neighbours."""
    from segloc_cli.sim import _clutter_ranges

    for fov_deg, readings in ((180.0, 181), (360.0, 360)):
        angles = beam_angles(readings, fov_deg)
        clutter = _clutter_ranges(angles, 1.0, OneClusterNearTheEnd())
        # 0.5 m at 1 m spans 0.5 rad: 29 beams 1° apart, from the second-last on.
        seen = np.flatnonzero(np.isfinite(clutter))
        if fov_deg < 360.0:
            assert seen.tolist() == [readings - 2, readings - 1]
        else:
            assert seen.tolist() == [*range(27), readings - 2, readings - 1]
        np.testing.assert_array_equal(clutter[seen], 1.0)


@pytest.mark.parametrize("fov_deg", [1e-9, 1e-3])
def test_clutter_on_a_fan_narrower_than_a_person_covers_at_most_its_beams(fov_deg):
    """A person 0.5 m wide at 1 m subtends more than the whole fan: the cluster covers the
    fan's beams from the one drawn to its edge, never more beams than the fan has."""
    from segloc_cli.sim import _clutter_ranges

    clutter = _clutter_ranges(beam_angles(3, fov_deg), 1.0, OneClusterNearTheEnd())
    assert clutter.shape == (3,)
    np.testing.assert_array_equal(clutter, [np.inf, 1.0, 1.0])


def test_rays_against_thousands_of_segments_take_megabytes():
    """A plan of 20,000 segments scanned by 1024 beams: memory stays bounded (every ray
    against every segment at once would need 160 MB per array), and the ranges are those
    of the rays cast one by one."""
    import tracemalloc

    rng = np.random.default_rng(3)
    centres = rng.uniform(-50, 50, (20_000, 2))
    segments = np.hstack([centres, centres + rng.uniform(-0.5, 0.5, (20_000, 2))])
    angles = beam_angles(1024)
    tracemalloc.start()
    ranges = cast_rays(segments, (0.3, -0.2), angles)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 100e6, peak
    for k in range(0, 1024, 97):
        assert ranges[k] == cast_rays(segments, (0.3, -0.2), angles[k : k + 1])[0]


def test_scan_frame_follows_the_robot_heading():
    # Facing +y, the wall at x = 2 is on the robot's right: beam at −90° reads 2 m.
    world = World(WALL_X2, np.array(["wall"]), "wall")
    scan = simulate_scan(world, Pose2(0.0, 0.0, np.pi / 2), EXACT, np.random.default_rng(0), 3.5)
    assert scan.time_s == 3.5
    np.testing.assert_allclose(scan.angles_rad, beam_angles(1024))
    assert scan.ranges_m[768] == pytest.approx(2.0)
    assert scan.ranges_m[0] == 0.0  # facing +y the forward beam runs parallel to the wall


def test_glass_fully_transparent_shows_the_wall_behind_and_fully_opaque_hides_it():
    segments = np.array([[2.0, -50.0, 2.0, 50.0], [3.0, -50.0, 3.0, 50.0]])
    world = World(segments, np.array(["glass", "wall"]), "glass")
    front = np.abs(wrap_angle(beam_angles(1024))) < np.deg2rad(60.0)
    cos_a = np.cos(beam_angles(1024)[front])

    through = simulate_scan(world, Pose2(0, 0, 0), EXACT, np.random.default_rng(0), 0.0)
    np.testing.assert_allclose(through.ranges_m[front], 3.0 / cos_a, atol=0.0005 + 1e-12)

    mirror = SensorModel(noise_cm=0.0, dropout_prob=0.0, glass_return_prob=1.0, clutter_clusters=0)
    opaque = simulate_scan(world, Pose2(0, 0, 0), mirror, np.random.default_rng(0), 0.0)
    np.testing.assert_allclose(opaque.ranges_m[front], 2.0 / cos_a, atol=0.0005 + 1e-12)


def test_glass_returns_at_the_stated_rate():
    segments = np.array([[2.0, -50.0, 2.0, 50.0], [3.0, -50.0, 3.0, 50.0]])
    world = World(segments, np.array(["glass", "wall"]), "glass")
    sensor = SensorModel(
        readings=2048, noise_cm=0.0, dropout_prob=0.0, glass_return_prob=0.3, clutter_clusters=0
    )
    front = np.abs(wrap_angle(beam_angles(2048))) < np.deg2rad(60.0)
    glass_m = 2.0 / np.cos(beam_angles(2048)[front])
    rng = np.random.default_rng(5)
    on_glass = np.concatenate(
        [
            np.abs(simulate_scan(world, Pose2(0, 0, 0), sensor, rng, 0.0).ranges_m[front] - glass_m)
            < 0.001
            for _ in range(5)
        ]
    )
    sigma = np.sqrt(0.3 * 0.7 / on_glass.size)
    assert abs(on_glass.mean() - 0.3) < 4 * sigma


def test_range_noise_has_the_stated_sigma():
    world = World(ROOM, np.array(["wall"] * 4), "room")
    sensor = SensorModel(readings=2048, dropout_prob=0.0, clutter_clusters=0.0)
    rng = np.random.default_rng(7)
    pose = Pose2(0.7, -1.3, 0.4)
    truth = room_ranges(pose.theta + beam_angles(2048), pose.x, pose.y)
    residuals = np.concatenate(
        [simulate_scan(world, pose, sensor, rng, float(k)).ranges_m - truth for k in range(4)]
    )
    assert abs(residuals.std() - 0.012) < 0.15 * 0.012
    assert abs(residuals.mean()) < 4 * 0.012 / np.sqrt(residuals.size)


def test_ranges_are_rounded_to_the_resolution():
    world = World(WALL_X2, np.array(["wall"]), "wall")
    sensor = SensorModel(
        noise_cm=0.0, resolution_m=0.05, dropout_prob=0.0, glass_return_prob=0, clutter_clusters=0
    )
    scan = simulate_scan(world, Pose2(0, 0, 0), sensor, np.random.default_rng(0), 0.0)
    front = np.abs(wrap_angle(scan.angles_rad)) < np.deg2rad(70.0)
    expected = np.round(2.0 / np.cos(scan.angles_rad[front]) / 0.05) * 0.05
    np.testing.assert_allclose(scan.ranges_m[front], expected, atol=1e-12)
    assert len(np.unique(np.round(scan.ranges_m[front], 9))) < front.sum()


def test_no_return_within_range_max_is_written_as_zero():
    world = World(WALL_X2, np.array(["wall"]), "wall")
    sensor = SensorModel(
        noise_cm=0.0, range_max_m=2.5, dropout_prob=0.0, glass_return_prob=0, clutter_clusters=0
    )
    scan = simulate_scan(world, Pose2(0, 0, 0), sensor, np.random.default_rng(0), 0.0)
    a = wrap_angle(scan.angles_rad)
    within = (np.abs(a) < np.pi / 2) & (2.0 / np.cos(a) < 2.5 - 1e-3)
    beyond = ~((np.abs(a) < np.pi / 2) & (2.0 / np.cos(a) < 2.5 + 1e-3))
    assert scan.range_max_m == 2.5
    assert np.all(scan.ranges_m[beyond] == 0.0)
    np.testing.assert_allclose(scan.ranges_m[within], 2.0 / np.cos(a[within]), atol=0.0005)
    assert np.array_equal(scan.valid, scan.ranges_m > 0.0)


def test_dropouts_happen_at_the_stated_rate():
    world = World(ROOM, np.array(["wall"] * 4), "room")
    sensor = SensorModel(readings=2048, dropout_prob=0.2, clutter_clusters=0.0)
    rng = np.random.default_rng(11)
    lost = np.concatenate(
        [simulate_scan(world, Pose2(0, 0, 0), sensor, rng, 0.0).ranges_m == 0.0 for _ in range(5)]
    )
    sigma = np.sqrt(0.2 * 0.8 / lost.size)
    assert abs(lost.mean() - 0.2) < 4 * sigma


def test_clutter_only_shortens_ranges_and_sits_between_0p8_and_5_m():
    world = World(ROOM, np.array(["wall"] * 4), "room")
    sensor = SensorModel(noise_cm=0.0, dropout_prob=0.0, clutter_clusters=6.0)
    pose = Pose2(1.0, 2.0, -0.3)
    truth = room_ranges(pose.theta + beam_angles(1024), pose.x, pose.y)
    rng = np.random.default_rng(3)
    shortened = 0
    for _ in range(10):
        ranges = simulate_scan(world, pose, sensor, rng, 0.0).ranges_m
        assert np.all(ranges <= truth + 0.0005)
        short = ranges < truth - 0.01
        assert np.all((ranges[short] >= 0.8 - 0.0005) & (ranges[short] <= 5.0 + 0.0005))
        shortened += short.sum()
    assert shortened > 0


def test_same_seed_same_scan_and_other_seed_other_scan():
    world = World(ROOM, np.array(["wall", "glass", "wall", "wall"]), "room")
    pose = Pose2(0.5, 0.5, 1.0)
    a = simulate_scan(world, pose, SensorModel(), np.random.default_rng(42), 1.0)
    b = simulate_scan(world, pose, SensorModel(), np.random.default_rng(42), 1.0)
    c = simulate_scan(world, pose, SensorModel(), np.random.default_rng(43), 1.0)
    assert np.array_equal(a.ranges_m, b.ranges_m)
    assert not np.array_equal(a.ranges_m, c.ranges_m)


# --- initial errors and guesses --------------------------------------------------------------


def test_paper_initial_errors_are_table_1_of_the_paper():
    # Reina & Gonzalez (2000), Table 1, initial error columns: x cm, y cm, heading deg.
    table_1 = [
        (182.2, 36.0, -9.75),
        (-63.7, 49.5, -15.6),
        (-91.2, 168.5, 7.82),
        (33.2, -131.8, -17.3),
        (-10.9, -14.7, -19.9),
        (47.2, -168.2, 14.1),
        (16.2, 38.7, -6.71),
        (74.4, -75.1, 16.4),
        (-56.3, 18.1, 3.7),
        (-46.5, -133.6, 0.5),
    ]
    errors = paper_initial_errors(12)
    assert errors.shape == (12, 3)
    for k in range(12):
        x_cm, y_cm, theta_deg = table_1[k % 10]
        np.testing.assert_allclose(errors[k], [x_cm / 100, y_cm / 100, np.deg2rad(theta_deg)])


def test_uniform_initial_errors_stay_within_and_fill_their_bounds():
    errors = uniform_initial_errors(4000, 1.5, 20.0, np.random.default_rng(0))
    assert errors.shape == (4000, 3)
    assert np.all(np.abs(errors[:, :2]) <= 1.5)
    assert np.all(np.abs(errors[:, 2]) <= np.deg2rad(20.0))
    assert np.all(errors.max(axis=0) > 0.97 * np.array([1.5, 1.5, np.deg2rad(20.0)]))
    assert np.all(errors.min(axis=0) < -0.97 * np.array([1.5, 1.5, np.deg2rad(20.0)]))


def test_initial_guess_is_truth_minus_error_with_heading_wrapped():
    true_poses = np.array([[1.0, 2.0, 0.1], [0.0, 0.0, 3.0]])
    errors = np.array([[0.5, -0.25, 0.2], [-1.0, 2.0, -0.5]])
    guesses = initial_guesses(true_poses, errors)
    np.testing.assert_allclose(guesses[0], [0.5, 2.25, -0.1])
    np.testing.assert_allclose(guesses[1], [1.0, -2.0, 3.5 - 2 * np.pi])
    # "surveyed minus guess" gives the error back
    np.testing.assert_allclose(true_poses[:, :2] - guesses[:, :2], errors[:, :2])
    np.testing.assert_allclose(wrap_angle(true_poses[:, 2] - guesses[:, 2]), errors[:, 2])


def test_drifting_odometry_starts_at_its_origin_and_errs_within_its_bounds():
    """Odometry of a square walk: no drift gives the true motions from the origin; with
    drift, every step's error stays within its share of the step and the error grows."""
    legs = [(x, 0.0, 0.0) for x in np.arange(0.0, 4.0, 0.5)]
    legs += [(4.0, y, np.pi / 2) for y in np.arange(0.0, 4.0, 0.5)]
    truth = np.array([(x + 2.0, y - 1.0, t) for x, y, t in legs])
    still = drifting_odometry(truth, OdometryDrift(0.0, 0.0, 0.0), np.random.default_rng(1))
    np.testing.assert_allclose(still, relative_motion(truth[:1].repeat(len(truth), 0), truth),
                               atol=1e-12)  # fmt: skip
    drift = OdometryDrift(5.0, 10.0, 2.0)
    odometry = drifting_odometry(truth, drift, np.random.default_rng(1))
    np.testing.assert_array_equal(odometry[0], [0.0, 0.0, 0.0])
    true_steps = relative_motion(truth[:-1], truth[1:])
    steps = relative_motion(odometry[:-1], odometry[1:])
    length = np.hypot(*true_steps[:, :2].T)
    off = steps - true_steps
    assert np.all(np.abs(off[:, :2]) <= 0.05 * length[:, None] + 1e-12)
    turn_bound = 0.1 * np.abs(true_steps[:, 2]) + np.deg2rad(2.0) * length
    assert np.all(np.abs(wrap_angle(off[:, 2])) <= turn_bound + 1e-12)
    assert np.hypot(*(odometry[-1, :2] - still[-1, :2])) > 0.01  # it does drift
    # It draws what uniform guesses draw: what the generator gives next is the same.
    a, b = np.random.default_rng(7), np.random.default_rng(7)
    drifting_odometry(truth, drift, a)
    uniform_initial_errors(len(truth), 0.0, 0.0, b)
    assert a.random() == b.random()


@pytest.mark.parametrize("text", ["drift:1", "drift:-1,2,0.5", "drift:2,2,46", "odometry"])
def test_odometry_drift_text_is_refused_saying_what_is_taken(text):
    assert parse_odometry("drift") == OdometryDrift()
    assert parse_odometry(OdometryDrift(3, 4, 1).text) == OdometryDrift(3.0, 4.0, 1.0)
    with pytest.raises(ValueError, match="DISTANCE_PCT,TURN_PCT,DEG_PER_M"):
        parse_odometry(text)


# --- random worlds ---------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_free_poses_are_inside_the_room_and_clear(seed):
    rng = np.random.default_rng(seed)
    world = random_world(rng)
    assert world.segments.shape[1] == 4
    assert set(world.materials.tolist()) <= {"wall", "glass"}
    poses = random_free_poses(world, 15, rng, clearance_m=0.6)
    assert poses.shape == (15, 3)
    assert np.all((poses[:, 2] >= -np.pi) & (poses[:, 2] < np.pi))
    angles = np.linspace(0.0, 2 * np.pi, 360, endpoint=False)
    for x, y, _ in poses:
        clearance = min(point_segment_distance(np.array([x, y]), s) for s in world.segments)
        assert clearance >= 0.6
        ranges = cast_rays(world.segments, np.array([x, y]), angles)
        assert np.all(np.isfinite(ranges)), "a pose outside the walls sees out"
        assert ranges.max() > 4.0, "a pose shut inside an obstacle sees only it"


@pytest.mark.parametrize("seed", [3, 4])
def test_random_world_shows_walls_of_several_orientations(seed):
    rng = np.random.default_rng(seed)
    world = random_world(rng)
    angles = np.linspace(0.0, 2 * np.pi, 720, endpoint=False)
    seg = world.segments
    direction = np.arctan2(seg[:, 3] - seg[:, 1], seg[:, 2] - seg[:, 0]) % np.pi
    for x, y, _ in random_free_poses(world, 5, rng):
        ranges = cast_rays(seg, np.array([x, y]), angles)
        hits = np.column_stack([x + ranges * np.cos(angles), y + ranges * np.sin(angles)])
        nearest = [np.argmin([point_segment_distance(h, s) for s in seg]) for h in hits[::4]]
        seen = np.unique(np.round(np.rad2deg(direction[nearest]) / 15.0) % 12)
        assert seen.size >= 3


def test_random_world_depends_on_the_seed_only():
    a = random_world(np.random.default_rng(10))
    b = random_world(np.random.default_rng(10))
    c = random_world(np.random.default_rng(11))
    assert np.array_equal(a.segments, b.segments)
    assert a.segments.shape != c.segments.shape or not np.allclose(a.segments, c.segments)


def test_random_world_is_not_mirror_or_point_symmetric():
    world = random_world(np.random.default_rng(0))
    seg = world.segments
    cx = (seg[:, [0, 2]].min() + seg[:, [0, 2]].max()) / 2
    cy = (seg[:, [1, 3]].min() + seg[:, [1, 3]].max()) / 2
    ends = seg.reshape(-1, 2)
    images = {
        "mirror x": np.column_stack([2 * cx - ends[:, 0], ends[:, 1]]),
        "mirror y": np.column_stack([ends[:, 0], 2 * cy - ends[:, 1]]),
        "half turn": np.column_stack([2 * cx - ends[:, 0], 2 * cy - ends[:, 1]]),
    }
    for name, image in images.items():
        gaps = np.min(np.linalg.norm(image[:, None, :] - ends[None, :, :], axis=2), axis=1)
        assert np.mean(gaps > 0.1) > 0.3, name


# --- the shipped hall ------------------------------------------------------------------------


def load_hall() -> World:
    document = json.loads((HALL / "world.json").read_text(encoding="utf-8"))
    assert document["format"] == "segloc-world" and document["units"] == "m"
    return World(np.array(document["segments"]), np.array(document["materials"]), "hall")


def test_hall_is_a_large_hall_with_glass_and_columns():
    world = load_hall()
    seg = world.segments
    assert seg[:, [0, 2]].max() - seg[:, [0, 2]].min() >= 20.0
    assert "glass" in world.materials.tolist()
    lengths = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1])
    assert np.sum(lengths < 0.2) >= 8 * 4  # short column faces


def test_hall_poses_are_on_the_floor_and_clear_of_everything():
    world = load_hall()
    with (HALL / "poses.csv").open(encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["pose_id", "time_s", "x_m", "y_m", "theta_deg"]
    assert [int(r["pose_id"]) for r in rows] == list(range(1, 11))
    assert [float(r["time_s"]) for r in rows] == [float(k) for k in range(1, 11)]
    xy = np.array([[float(r["x_m"]), float(r["y_m"])] for r in rows])
    angles = np.linspace(0.0, 2 * np.pi, 360, endpoint=False)
    for p in xy:
        assert min(point_segment_distance(p, s) for s in world.segments) >= 0.6
        assert np.all(np.isfinite(cast_rays(world.segments, p, angles)))
    assert np.all(free_space_mask(world, xy, 0.6))
    headings = np.array([float(r["theta_deg"]) for r in rows])
    assert np.ptp(headings) > 180.0


# --- the hall's mapping run: the map is made without the test scans ---------------------------


def read_poses_csv(path) -> np.ndarray:
    """Rows (N, 5) of a pose CSV: pose_id, time_s, x_m, y_m, theta_deg."""
    with path.open(encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["pose_id", "time_s", "x_m", "y_m", "theta_deg"]
    return np.array([[float(v) for v in row.values()] for row in rows])


def test_hall_mapping_run_covers_the_hall_away_from_the_test_poses():
    world = load_hall()
    mapping = read_poses_csv(HALL / "mapping_poses.csv")
    tests = read_poses_csv(HALL / "poses.csv")
    assert 60 <= len(mapping) <= 150
    assert mapping[:, 0].tolist() == list(range(1, len(mapping) + 1))
    assert np.all(np.diff(mapping[:, 1]) > 0)
    assert np.all(free_space_mask(world, mapping[:, 2:4], 0.5))
    gaps = np.linalg.norm(mapping[:, None, 2:4] - tests[None, :, 2:4], axis=2)
    assert gaps.min() >= 0.5
    # Spread over the hall: scans in every 6 m × 4 m block of the 24 m × 16 m floor.
    blocks = {(int(x // 6.0), int(y // 4.0)) for x, y in mapping[:, 2:4] if x < 24 and y < 16}
    assert blocks == {(i, j) for i in range(4) for j in range(4)}
    assert np.ptp(mapping[:, 4]) > 180.0


def test_hall_mapping_log_is_the_mapping_run_with_its_own_noise_and_seed():
    mapping = read_poses_csv(HALL / "mapping_poses.csv")
    survey = read_pose_table(HALL / "mapping" / "survey.csv")
    np.testing.assert_allclose(survey.poses[:, :2], mapping[:, 2:4], atol=1e-9)
    np.testing.assert_allclose(np.rad2deg(survey.poses[:, 2]), mapping[:, 4], atol=1e-9)
    log = read_log(HALL / "mapping" / "log.mcap")
    assert len(log.scans) == len(mapping)
    np.testing.assert_allclose([s.time_s for s in log.scans], mapping[:, 1])
    test_log = read_log(HALL / "log.mcap")
    assert (log.sensor["seed"], log.sensor["noise_cm"]) == ("1000", "1.5")
    assert (test_log.sensor["seed"], test_log.sensor["noise_cm"]) == ("2000", "1.2")


def test_hall_map_covers_what_the_test_poses_see():
    """Of the world's solid surface seen from each test pose, nearly all lies on the map."""
    world = load_hall()
    solid = world.segments[world.materials != "glass"]
    segments_map = read_map(HALL / "map.json")
    angles = np.linspace(0.0, 2 * np.pi, 720, endpoint=False)
    for pose in read_poses_csv(HALL / "poses.csv"):
        ranges = cast_rays(solid, pose[2:4], angles)
        hit = np.isfinite(ranges)
        points = pose[2:4] + ranges[hit, None] * np.column_stack(
            [np.cos(angles[hit]), np.sin(angles[hit])]
        )
        near = point_segment_distances(points, segments_map).min(axis=1) < 0.05
        assert near.mean() >= 0.9, pose[0]


def _same_lines(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two sets of segments (M, 4) hold the same lines, whichever way each runs."""

    def canonical(segments):
        ends = segments.reshape(-1, 2, 2)
        flipped = (ends[:, 0, 0] > ends[:, 1, 0]) | (
            (ends[:, 0, 0] == ends[:, 1, 0]) & (ends[:, 0, 1] > ends[:, 1, 1])
        )
        ends = np.where(flipped[:, None, None], ends[:, ::-1], ends)
        return np.round(ends.reshape(-1, 4), 6)

    return {tuple(r) for r in canonical(a)} == {tuple(r) for r in canonical(b)}


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_symmetric_room_is_its_own_half_turn(seed):
    world = symmetric_room(np.random.default_rng(seed))
    ends = world.segments.reshape(-1, 2)
    centre = (ends.min(axis=0) + ends.max(axis=0)) / 2.0
    turned = (2.0 * centre - ends).reshape(-1, 4)
    assert _same_lines(turned, world.segments)
    assert len(world.segments) > 4  # not only the four walls


def test_a_repeating_corridor_looks_the_same_one_period_on():
    world = repeating_corridor(np.random.default_rng(4), length_m=60.0)
    segments = world.segments
    xs = np.unique(np.round(segments[(segments[:, 0] == segments[:, 2])][:, 0], 9))
    jambs = xs[(xs > 0) & (xs < 60.0)]
    period = np.diff(jambs[0::2])
    np.testing.assert_allclose(period, period[0], atol=1e-9)  # doors at one period
    # Away from the end walls, every wall shifted by a period is a wall of the corridor.
    far = (segments[:, [0, 2]].min(axis=1) > 10.0) & (segments[:, [0, 2]].max(axis=1) < 40.0)
    shifted = segments[far] + np.array([period[0], 0.0, period[0], 0.0])
    walls = {tuple(r) for r in np.round(segments, 6)}
    assert far.sum() > 20
    assert all(tuple(r) in walls for r in np.round(shifted, 6))
