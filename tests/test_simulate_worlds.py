"""``segloc simulate`` on the user's own building: a map (built, or imported from a plan) taken
as a world of one material, the world file's keys and its ``sensor``, the sensor chosen by
options (beams, field of view, noise, clutter, glass), the run file that repeats it, and bad
input in one line. docs/simulation.md's world example runs in test_readme_commands.py."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest
from test_cli import assert_one_line_error, run_cli
from test_plans import draw_office

from segloc_cli.errors import InputError
from segloc_cli.io.maps import read_map, write_map
from segloc_cli.io.mcap_log import read_log
from segloc_cli.sim import cast_rays

ROOT = Path(__file__).resolve().parents[1]

# An 8 m × 5 m room with a wall stub and a pillar, metres, world frame.
ROOM = np.array(
    [
        [0.0, 0.0, 8.0, 0.0],
        [8.0, 0.0, 8.0, 5.0],
        [8.0, 5.0, 0.0, 5.0],
        [0.0, 5.0, 0.0, 0.0],
        [5.0, 0.0, 5.0, 2.0],
        [2.0, 3.0, 2.6, 3.0],
        [2.6, 3.0, 2.6, 3.6],
        [2.6, 3.6, 2.0, 3.6],
        [2.0, 3.6, 2.0, 3.0],
    ]
)
# Poses in the room, x m, y m, heading degrees.
ROOM_POSES = np.array([[1.0, 1.0, 0.0], [6.5, 1.2, 90.0], [4.0, 4.2, 200.0], [7.0, 4.0, -45.0]])
# Exact geometry but for the 1 mm rounding of the ranges.
EXACT = ("--noise-cm", "0", "--no-clutter")
RESOLUTION_SLACK_M = 0.0006


def write_poses(path: Path, poses: np.ndarray) -> Path:
    rows = [f"{k + 1},{x:.17g},{y:.17g},{t:.17g}" for k, (x, y, t) in enumerate(poses)]
    path.write_text("pose_id,x_m,y_m,theta_deg\n" + "\n".join(rows) + "\n", encoding="utf-8")
    return path


def write_world(path: Path, segments: np.ndarray, **keys) -> Path:
    document = {"format": "segloc-world", "version": 1, "segments": segments.tolist(), **keys}
    path.write_text(json.dumps(document), encoding="utf-8")
    return path


def simulate(capsys, world: Path, poses: Path, out: Path, *options) -> list:
    """The scans ``segloc simulate`` writes (failing the test if it does not succeed)."""
    result = run_cli(capsys, "simulate", world, "--poses", poses, "--out", out, *options)
    assert result.code == 0, result.err
    return read_log(out / "log.mcap").scans


def true_ranges(segments: np.ndarray, pose, angles_rad: np.ndarray) -> np.ndarray:
    """Exact ranges (N,) from ``pose`` (x m, y m, heading degrees) along robot-frame beams."""
    return cast_rays(segments, pose[:2], np.deg2rad(pose[2]) + angles_rad)


def assert_exact_scans(scans, segments: np.ndarray, poses: np.ndarray) -> None:
    """Every valid reading of ``scans`` lies where its beam meets ``segments``, and every
    beam that meets them within 30 m reads it unless it dropped out (0.5 % of readings)."""
    assert len(scans) == len(poses)
    for scan, pose in zip(scans, poses, strict=True):
        expected = true_ranges(segments, pose, scan.angles_rad)
        valid = scan.valid
        np.testing.assert_allclose(
            scan.ranges_m[valid], expected[valid], atol=RESOLUTION_SLACK_M, rtol=0
        )
        assert valid.sum() >= 0.97 * np.sum(expected < 30.0)


# --- maps as worlds ------------------------------------------------------------------------


def test_a_map_file_is_simulated_as_walls_of_the_default_material(tmp_path, capsys):
    write_map(tmp_path / "map.json", ROOM, {"drawn": "by hand"})
    poses = write_poses(tmp_path / "poses.csv", ROOM_POSES)
    scans = simulate(capsys, tmp_path / "map.json", poses, tmp_path / "walls", *EXACT)
    assert_exact_scans(scans, ROOM, ROOM_POSES)
    assert read_log(tmp_path / "walls" / "log.mcap").sensor["world"] == "map"

    # Made of glass, the same room lets nine beams in ten through every wall it meets.
    glass = simulate(
        capsys, tmp_path / "map.json", poses, tmp_path / "glass", *EXACT, "--material", "glass"
    )
    returned = np.mean([scan.valid.mean() for scan in glass])
    assert 0.05 < returned < 0.3, returned


def test_a_plan_imported_by_map_import_is_simulated(tmp_path, capsys):
    draw_office(tmp_path / "office.dxf")
    plan_map = tmp_path / "office.json"
    result = run_cli(capsys, "map", "import", tmp_path / "office.dxf", "--out", plan_map)
    assert result.code == 0, result.err
    poses = np.array([[2.0, 5.5, 0.0], [13.0, 5.0, 90.0], [4.5, 10.5, -120.0]])
    scans = simulate(capsys, plan_map, write_poses(tmp_path / "p.csv", poses), tmp_path / "o")
    # With the default sensor, noise and clutter: most readings lie on the plan's walls.
    segments = read_map(plan_map)
    for scan, pose in zip(scans, poses, strict=True):
        expected = true_ranges(segments, pose, scan.angles_rad)
        on_wall = np.abs(scan.ranges_m - expected) < 0.05
        assert on_wall[scan.valid].mean() > 0.9
        assert scan.valid.mean() > 0.9


# --- the sensor chosen ---------------------------------------------------------------------


@pytest.mark.parametrize(("readings", "fov_deg"), [(361, 180.0), (181, 90.0), (1000, 360.0)])
def test_readings_and_field_of_view_give_that_many_beams_over_that_angle(
    readings, fov_deg, tmp_path, capsys
):
    world = write_world(tmp_path / "room.json", ROOM)
    poses = write_poses(tmp_path / "poses.csv", ROOM_POSES)
    options = ("--readings", str(readings), "--fov-deg", str(fov_deg), *EXACT)
    scans = simulate(capsys, world, poses, tmp_path / "out", *options)
    for scan in scans:
        angles = np.rad2deg(scan.angles_rad)
        assert len(angles) == readings
        step = fov_deg / readings if fov_deg == 360.0 else fov_deg / (readings - 1)
        np.testing.assert_allclose(np.diff(angles), step, rtol=1e-9)
        if fov_deg == 360.0:  # a full turn from straight ahead, one step short of it
            assert (angles[0], angles[-1]) == pytest.approx((0.0, 360.0 - step), abs=1e-9)
        else:  # a fan centred straight ahead, a beam on each edge
            assert (angles[0], angles[-1]) == pytest.approx((-fov_deg / 2, fov_deg / 2), abs=1e-9)
    # The ranges are those of the beams' own directions.
    assert_exact_scans(scans, ROOM, ROOM_POSES)
    sensor = read_log(tmp_path / "out" / "log.mcap").sensor
    assert sensor["readings"] == str(readings)


def test_clutter_off_gives_no_clutter_returns(tmp_path, capsys):
    world = write_world(tmp_path / "room.json", ROOM)
    poses_array = np.tile(ROOM_POSES, (8, 1))
    poses = write_poses(tmp_path / "poses.csv", poses_array)
    common = ("--noise-cm", "0", "--seed", "5")
    with_clutter = simulate(capsys, world, poses, tmp_path / "on", *common)
    without = simulate(capsys, world, poses, tmp_path / "off", *common, "--no-clutter")
    assert_exact_scans(without, ROOM, poses_array)
    # With clutter, the same scans hold returns well short of the walls: people at 0.8-5 m.
    short = [
        (true_ranges(ROOM, pose, scan.angles_rad) - scan.ranges_m)[scan.valid] > 0.1
        for scan, pose in zip(with_clutter, poses_array, strict=True)
    ]
    assert sum(s.sum() for s in short) > 20
    assert read_log(tmp_path / "off" / "log.mcap").sensor["clutter"] == "off"


def glass_room(tmp_path: Path, **keys) -> Path:
    """A room whose wall at x = 4 has a glass pane from y = 1 to 4, with a wall behind it at
    x = 6: beams through the pane read about 6 m, beams that it returns about 4 m."""
    segments = np.vstack([ROOM[:4], [[4.0, 0.0, 4.0, 1.0], [4.0, 1.0, 4.0, 4.0]]])
    segments = np.vstack([segments, [[4.0, 4.0, 4.0, 5.0], [6.0, 0.0, 6.0, 5.0]]])
    materials = ["wall"] * 4 + ["wall", "glass", "wall", "wall"]
    return write_world(tmp_path / "glass.json", segments, materials=materials, **keys)


def pane_readings(scans) -> np.ndarray:
    """How far ahead (m) the beams from (2, 2.5) facing +x that reach the pane (within ±36°
    of straight ahead: its edges are 36.9° off) hit something, every valid reading."""
    angles = scans[0].angles_rad
    toward_pane = np.abs(np.arctan2(np.sin(angles), np.cos(angles))) < np.deg2rad(36)
    ranges = np.concatenate([s.ranges_m[toward_pane & s.valid] for s in scans])
    return np.abs(ranges * np.cos(np.concatenate([angles[toward_pane & s.valid] for s in scans])))


def test_glass_off_makes_glass_walls_opaque(tmp_path, capsys):
    world = glass_room(tmp_path)
    poses = write_poses(tmp_path / "poses.csv", np.tile([[2.0, 2.5, 0.0]], (5, 1)))
    through = pane_readings(simulate(capsys, world, poses, tmp_path / "on", *EXACT))
    opaque = pane_readings(simulate(capsys, world, poses, tmp_path / "off", *EXACT, "--no-glass"))
    # x of the point each beam hit, relative to the scanner at x = 2: 2 m (pane) or 4 m.
    assert np.mean(np.isclose(through, 4.0, atol=0.01)) > 0.8
    np.testing.assert_allclose(opaque, 2.0, atol=0.01)
    assert read_log(tmp_path / "off" / "log.mcap").sensor["glass"] == "opaque"


def test_the_world_files_sensor_chooses_and_options_override_it(tmp_path, capsys):
    sensor = {"readings": 91, "fov_deg": 90, "noise_cm": 0, "clutter": False, "glass": False}
    world = glass_room(tmp_path, sensor=sensor)
    poses = write_poses(tmp_path / "poses.csv", np.tile([[2.0, 2.5, 0.0]], (3, 1)))
    scans = simulate(capsys, world, poses, tmp_path / "world")
    assert {len(s) for s in scans} == {91}
    assert np.rad2deg(scans[0].angles_rad[[0, -1]]) == pytest.approx([-45.0, 45.0])
    np.testing.assert_allclose(pane_readings(scans), 2.0, atol=0.01)  # glass off, no noise

    # An option given wins over the world file; what is not given still comes from it.
    scans = simulate(capsys, world, poses, tmp_path / "options", "--readings", "31")
    assert {len(s) for s in scans} == {31}
    assert np.rad2deg(scans[0].angles_rad[[0, -1]]) == pytest.approx([-45.0, 45.0])

    # The run file records the sensor as simulated, and repeats the run.
    recorded = tomllib.loads((tmp_path / "options" / "log.run.toml").read_text())["simulate"]
    assert {k: recorded[k] for k in ("readings", "fov-deg", "noise-cm", "clutter", "glass")} == {
        "readings": 31, "fov-deg": 90.0, "noise-cm": 0.0, "clutter": False, "glass": False
    }  # fmt: skip
    again = tmp_path / "again"
    config = ("--config", tmp_path / "options" / "log.run.toml")
    repeated = simulate(capsys, world, poses, again, *config)
    first = read_log(tmp_path / "options" / "log.mcap").scans
    for a, b in zip(first, repeated, strict=True):
        np.testing.assert_array_equal(a.ranges_m, b.ranges_m)
        np.testing.assert_array_equal(a.angles_rad, b.angles_rad)


def test_the_hall_is_simulated_as_it_was(tmp_path, capsys):
    """The shipped hall log, made again by its own command, holds the same scans, guesses and
    sensor settings: the defaults have not moved."""
    hall = ROOT / "datasets" / "hall"
    options = ("--readings", "1024", "--noise-cm", "1.2", "--seed", "2000")
    scans = simulate(capsys, hall / "world.json", hall / "poses.csv", tmp_path, *options)
    shipped, again = read_log(hall / "log.mcap"), read_log(tmp_path / "log.mcap")
    assert again.sensor == shipped.sensor
    np.testing.assert_array_equal(again.odom_poses, shipped.odom_poses)
    for a, b in zip(shipped.scans, scans, strict=True):
        np.testing.assert_array_equal(a.ranges_m, b.ranges_m)
        np.testing.assert_array_equal(a.angles_rad, b.angles_rad)


# --- bad input -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("keys", "fragment"),
    [
        ({"colour": "grey"}, "unknown key 'colour' in a world file"),
        ({"material": ["wall"] * 9}, "did you mean 'materials'?"),
        ({"materials": ["wall"] * 8 + ["brick"]}, "segment 8 has unknown material 'brick'"),
        ({"units": "cm"}, "`units` is 'cm'; a world file is in metres"),
        ({"frame": "map"}, "`frame` is 'map'"),
        ({"sensor": {"fov_deg": 400}}, "sensor.fov_deg must be above 0 and at most 360, got 400"),
        ({"sensor": {"fov_deg": 0}}, "sensor.fov_deg must be above 0"),
        ({"sensor": {"readings": 1}}, "sensor.readings must be 2 to 100000, got 1"),
        ({"sensor": {"readings": 10.5}}, "`sensor.readings` must be a whole number, got 10.5"),
        ({"sensor": {"fov": 180}}, "unknown key 'fov' in `sensor`"),
        ({"sensor": {"clutter": "no"}}, "`sensor.clutter` must be true or false, got 'no'"),
        ({"sensor": {"noise_cm": -1}}, "sensor.noise_cm must be 0 to 100, got -1"),
        ({"sensor": {"noise_cm": 101}}, "sensor.noise_cm must be 0 to 100, got 101"),
        ({"sensor": [361, 180]}, "`sensor` must be an object of readings, fov_deg"),
    ],
)
def test_a_bad_world_file_is_one_line(keys, fragment, tmp_path, capsys):
    world = write_world(tmp_path / "bad-world.json", ROOM, **keys)
    poses = write_poses(tmp_path / "poses.csv", ROOM_POSES)
    result = run_cli(capsys, "simulate", world, "--poses", poses, "--out", tmp_path / "o")
    assert_one_line_error(result, "bad-world.json", fragment)
    assert not (tmp_path / "o" / "log.mcap").exists()


def test_materials_not_one_per_segment_count_in_words(tmp_path, capsys):
    world = write_world(tmp_path / "bad-world.json", ROOM[:1], materials=["wall", "glass"])
    poses = write_poses(tmp_path / "poses.csv", ROOM_POSES)
    result = run_cli(capsys, "simulate", world, "--poses", poses, "--out", tmp_path / "o")
    assert_one_line_error(result, "bad-world.json", "1 segment, materials 2")


@pytest.mark.parametrize(
    ("option", "fragment"),
    [
        (("--fov-deg", "0"), "0<x<=360"),
        (("--fov-deg", "361"), "0<x<=360"),
        (("--fov-deg", "nan"), "--fov-deg"),
        (("--readings", "1"), "2<=x<=100000"),
        (("--noise-cm", "101"), "0<=x<=100"),
        (("--seed", "-1"), "x>=0"),
        (("--material", "brick"), "'brick' is not one of 'wall', 'glass'"),
    ],
)
def test_a_bad_sensor_option_is_one_line(option, fragment, tmp_path, capsys):
    world = write_world(tmp_path / "room.json", ROOM)
    poses = write_poses(tmp_path / "poses.csv", ROOM_POSES)
    result = run_cli(capsys, "simulate", world, "--poses", poses, "--out", tmp_path / "o", *option)
    assert_one_line_error(result, option[0], fragment)


def test_a_world_given_as_a_map_is_checked_as_a_world(tmp_path):
    # A world's keys are checked wherever it is read, not only by the simulator.
    world = write_world(tmp_path / "w.json", ROOM, sensor={"beams": 3})
    with pytest.raises(InputError, match=r"w\.json: unknown key 'beams' in `sensor`"):
        read_map(world)
