"""CARMEN text logs: every field of the result, range maxima, offsets, bad input, gzip damage."""

from __future__ import annotations

import gzip
import math
import zlib

import numpy as np
import pytest

from segloc_cli.errors import InputError
from segloc_cli.geometry import Pose2
from segloc_cli.io.carmen import read_carmen
from segloc_cli.io.mcap_log import read_log, write_log

HALF_PI = np.pi / 2


def laser_line(ranges, pose, odom, time_s, kind="FLASER", logger_s=None) -> str:
    """One FLASER/RLASER record with readings ``ranges`` and the given pose fields."""
    numbers = [*ranges, *pose, *odom]
    logger = time_s if logger_s is None else logger_s
    return (
        f"{kind} {len(ranges)} {' '.join(repr(float(v)) for v in numbers)} {time_s} host {logger}"
    )


def write(path, lines: list[str], newline: str = "\n"):
    data = (newline.join(lines) + newline).encode()
    path.write_bytes(gzip.compress(data) if path.name.endswith(".gz") else data)
    return path


BASIC = [
    "# CARMEN Logfile",
    "# file format is one message per line",
    "PARAM robot_frontlaser_offset 0.0 nohost 0",
    "ODOM 0 0 0 0 0 0 0.000246 pippo 0.000246",
    "FLASER 5 1.0 2.5 81.83 4.0 0.5 0.6 -0.03 -0.35 0.6 -0.03 -0.35 32.9068 pippo 32.9068",
    "",
    "SYNC whatever 1 2",
    "FLASER 5 81.83 81.83 3.25 3.5 3.75 1.0 2.0 3.0 1.5 2.5 3.5 33.5 pippo 33.51",
    "TRUEPOS 1 2 3 4 5 6 7 h 8",
    "NEFF 8.39921",
    "FLASER 5 0.25 0.5 0.75 1.0 1.25 -4.0 2.0 -1.0 -4.0 2.0 -1.0 34.0 pippo 34.0",
]


def check_basic(log, name: str) -> None:
    assert len(log.scans) == 3
    assert [s.time_s for s in log.scans] == [32.9068, 33.5, 34.0]
    np.testing.assert_array_equal(log.odom_times_s, [32.9068, 33.5, 34.0])
    for scan in log.scans:
        np.testing.assert_allclose(
            scan.angles_rad, [-HALF_PI, -np.pi / 4, 0.0, np.pi / 4, HALF_PI], rtol=0, atol=1e-15
        )
        assert scan.range_max_m == 81.83
        assert scan.intensities.size == 0
    np.testing.assert_array_equal(log.scans[0].ranges_m, [1.0, 2.5, 81.83, 4.0, 0.5])
    np.testing.assert_array_equal(log.scans[1].ranges_m, [81.83, 81.83, 3.25, 3.5, 3.75])
    np.testing.assert_array_equal(log.scans[2].ranges_m, [0.25, 0.5, 0.75, 1.0, 1.25])
    np.testing.assert_array_equal(log.scans[0].valid, [True, True, False, True, True])
    np.testing.assert_array_equal(log.scans[1].valid, [False, False, True, True, True])
    np.testing.assert_array_equal(log.scans[2].valid, [True] * 5)
    # Headings are wrapped into [-pi, pi): 3.0 stays, 3.5 becomes 3.5 - 2pi.
    np.testing.assert_allclose(
        log.laser_poses,
        [[0.6, -0.03, -0.35], [1.0, 2.0, 3.0], [-4.0, 2.0, -1.0]],
        rtol=0,
        atol=1e-15,
    )
    np.testing.assert_allclose(
        log.odom_poses,
        [[0.6, -0.03, -0.35], [1.5, 2.5, 3.5 - 2 * np.pi], [-4.0, 2.0, -1.0]],
        rtol=0,
        atol=1e-15,
    )
    assert log.sensor == {
        "range_max_m": "81.83",
        "range_max_from": (
            "inferred: 81.83 m, the largest reading that repeats, is 20 % of the readings"
        ),
        "readings": "5",
        "fov_deg": "180",
        "laser": "front",
        "laser_offset_m": "0",
        "records": "FLASER",
        "source": name,
        "format": "CARMEN log",
    }
    assert log.warnings == []


def test_flaser_every_field(tmp_path):
    log = read_carmen(write(tmp_path / "basic.log", BASIC))
    check_basic(log, "basic.log")


def test_gzip_and_crlf_read_the_same(tmp_path):
    check_basic(read_carmen(write(tmp_path / "basic.log.gz", BASIC)), "basic.log.gz")
    check_basic(read_carmen(write(tmp_path / "crlf.clf", BASIC, "\r\n")), "crlf.clf")
    # gzip is found by its magic bytes, not by the file name.
    renamed = tmp_path / "compressed.clf"
    renamed.write_bytes((tmp_path / "basic.log.gz").read_bytes())
    check_basic(read_carmen(renamed), "compressed.clf")


def test_multi_member_gzip_and_zero_padding(tmp_path):
    first, second = "\n".join(BASIC[:6]) + "\n", "\n".join(BASIC[6:]) + "\n"
    path = tmp_path / "members.log.gz"
    path.write_bytes(gzip.compress(first.encode()) + gzip.compress(second.encode()) + bytes(16))
    check_basic(read_carmen(path), "members.log.gz")


def test_beam_angles_follow_carmens_rule_for_sick_readings(tmp_path):
    # CARMEN's reader: 181/180 readings 1° apart, 361/360 0.5° apart, from −90°; a count
    # no SICK mode gives spans 180° inclusive.
    counts = (180, 181, 360, 361, 100)
    path = write(
        tmp_path / "beams.log",
        [laser_line([2.0] * n, (0, 0, 0), (0, 0, 0), 1.0 + k) for k, n in enumerate(counts)],
    )
    log = read_carmen(path, range_max_m=80.0)
    assert [len(s) for s in log.scans] == list(counts)
    steps = (np.deg2rad(1.0), np.deg2rad(1.0), np.deg2rad(0.5), np.deg2rad(0.5), np.pi / 99)
    last_deg = (89.0, 90.0, 89.5, 90.0, 90.0)
    for scan, step, last in zip(log.scans, steps, last_deg, strict=True):
        assert scan.angles_rad[0] == pytest.approx(-HALF_PI, abs=1e-12)
        assert np.rad2deg(scan.angles_rad[-1]) == pytest.approx(last, abs=1e-10)
        np.testing.assert_allclose(np.diff(scan.angles_rad), step, rtol=0, atol=1e-12)
    assert log.sensor["readings"] == "100,180,181,360,361"
    assert log.sensor["fov_deg"] == "179,179.5,180"
    assert log.sensor["range_max_m"] == "80"
    assert log.sensor["range_max_from"] == "given"


def test_rear_laser_angles_offset_and_record_choice(tmp_path):
    path = write(
        tmp_path / "two.log",
        [
            "PARAM robot_rearlaser_offset 0.2 h 0",
            "PARAM robot_frontlaser_offset 0.5 h 0",
            "PARAM robot_rear_laser_max 5.5 h 0",
            laser_line([1.0, 3.0, 3.0], (0.0, 0.0, 0.0), (1.0, 1.0, HALF_PI), 1.0),
            laser_line([4.0, 5.0, 6.0], (1.0, 1.0, 0.5), (1.0, 1.0, 0.5), 1.5, kind="RLASER"),
            laser_line([4.0, 5.0, 5.5], (9.0, 9.0, 0.0), (1.0, 2.0, 0.0), 2.0, kind="RLASER"),
        ],
    )
    rear = read_carmen(path, laser="rear")
    assert [s.time_s for s in rear.scans] == [1.5, 2.0]
    np.testing.assert_array_equal(rear.scans[0].ranges_m, [4.0, 5.0, 6.0])
    np.testing.assert_array_equal(rear.scans[1].ranges_m, [4.0, 5.0, 5.5])
    for scan in rear.scans:
        # Facing backward: from +90° to +270°, continuous and evenly spaced.
        np.testing.assert_allclose(
            scan.angles_rad, [HALF_PI, np.pi, 3 * HALF_PI], rtol=0, atol=1e-15
        )
        # No value repeats at the top of the readings: the rear PARAM is the limit.
        np.testing.assert_array_equal(scan.valid, [True, True, False])
        assert scan.range_max_m == 5.5
    # The rear scanner sits 0.2 m behind the centre: odometry (≠ pose fields) moves back.
    np.testing.assert_allclose(rear.odom_poses, [[1.0, 1.0, 0.5], [0.8, 2.0, 0.0]], atol=1e-15)
    np.testing.assert_allclose(rear.laser_poses, [[1.0, 1.0, 0.5], [9.0, 9.0, 0.0]], atol=1e-15)
    assert rear.sensor["laser"] == "rear"
    assert rear.sensor["laser_offset_m"] == "0.2"
    assert rear.sensor["records"] == "RLASER"
    assert rear.sensor["range_max_m"] == "5.5"
    assert rear.sensor["range_max_from"] == (
        "PARAM robot_rear_laser_max (the readings repeat no no-return value, and no return lies "
        "beyond it)"
    )

    front = read_carmen(path)
    assert [s.time_s for s in front.scans] == [1.0]
    np.testing.assert_allclose(front.scans[0].angles_rad, [-HALF_PI, 0.0, HALF_PI], atol=1e-15)
    # 0.5 m ahead along the odometry heading (+y); the pose fields stay as written.
    np.testing.assert_allclose(front.odom_poses, [[1.0, 1.5, HALF_PI]], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(front.laser_poses, [[0.0, 0.0, 0.0]])
    assert front.sensor["laser_offset_m"] == "0.5"
    # The rear maximum is not the front laser's: inferred from the FLASER readings.
    assert front.sensor["range_max_m"] == "3"
    assert front.sensor["range_max_from"] == (
        "inferred: 3 m, the largest reading that repeats, is 66.7 % of the readings"
    )


def test_offset_leaves_a_corrected_log_alone(tmp_path):
    """Pose fields equal to the odometry fields (a SLAM-corrected log) are one pose: kept."""
    path = write(
        tmp_path / "corrected.log",
        [
            "PARAM robot_frontlaser_offset -0.04 h 0",
            laser_line([1.0, 2.0], (0.5, 0.25, 0.0), (0.5, 0.25, 0.0), 0.5),
            laser_line([1.0, 2.0], (0.5, 0.25, 0.0), (0.0, 0.0, np.pi), 0.75),
        ],
    )
    log = read_carmen(path, range_max_m=10.0)
    np.testing.assert_array_equal(log.laser_poses, [[0.5, 0.25, 0.0], [0.5, 0.25, 0.0]])
    # The second record's odometry is the robot centre facing -x: 4 cm behind is +x.
    np.testing.assert_allclose(
        log.odom_poses, [[0.5, 0.25, 0.0], [0.04, 0.0, -np.pi]], rtol=0, atol=1e-15
    )
    assert log.sensor["laser_offset_m"] == "-0.04"


ROBOTLASER = (
    "ROBOTLASER1 0 -1.5 3.0 1.0 5.0 0.01 0 4 1.0 2.0 5.0 6.5 4 10 20 30 40 "
    "1.0 2.0 0.1 0.9 2.0 0.1 0.3 0.0 1.0 0.5 1000000 7.25 host 7.3"
)
ROBOTLASER_NO_REMISSIONS = (
    "ROBOTLASER1 0 0.0 0.5 0.25 0 0.01 0 3 8.0 1.0 1.5 0 "
    "3.0 4.0 -0.5 3.0 4.0 -0.5 0 0 1.0 0.5 1000000 8.0 host 8.0"
)


@pytest.mark.parametrize(
    "config",
    ["-1.5 -3.0 -1.0", "1.5 -3.0 1.0", "-1.5 3.0 0.5", "-1.5 3.0 2.5"],
    ids=["field of view turning clockwise", "field of view negative", "step too fine",
         "step too coarse"],
)  # fmt: skip
def test_robotlaser1_whose_geometry_contradicts_itself_is_skipped(tmp_path, config):
    """Start angle, field of view and angular resolution of a 4-beam record: the step must
    be the field of view over 3 beams, to within one beam, and the fan must turn
    counter-clockwise."""
    bad = ROBOTLASER.replace("-1.5 3.0 1.0", config, 1).replace("7.25", "7.5")
    path = write(tmp_path / "robot.log", [ROBOTLASER, bad])
    log = read_carmen(path)
    assert [s.time_s for s in log.scans] == [7.25]
    assert log.numbers.tolist() == [1]
    assert (
        f"{path}: skipped 1 ROBOTLASER1 record with a beam fan that decreases" in (log.warnings[0])
    )
    assert log.warnings[0].endswith("(line 2)")


def test_robotlaser1_records(tmp_path):
    path = write(
        tmp_path / "robot.log",
        [
            "PARAM robot_frontlaser_offset 0.1 h 0",
            laser_line([2.0, 8.0, 8.0], (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 6.0),
            ROBOTLASER,
            ROBOTLASER_NO_REMISSIONS,
        ],
    )
    log = read_carmen(path)
    flaser, first, second = log.scans
    assert [s.time_s for s in log.scans] == [6.0, 7.25, 8.0]

    # start_angle + i·fov/(n−1): -1.5 + i·1.0
    np.testing.assert_allclose(first.angles_rad, [-1.5, -0.5, 0.5, 1.5], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(first.ranges_m, [1.0, 2.0, 5.0, 6.5])
    assert first.range_max_m == 5.0  # the record's own maximum_range
    np.testing.assert_array_equal(first.valid, [True, True, False, False])
    np.testing.assert_array_equal(first.intensities, [10.0, 20.0, 30.0, 40.0])

    np.testing.assert_allclose(second.angles_rad, [0.0, 0.25, 0.5], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(second.ranges_m, [8.0, 1.0, 1.5])
    assert second.intensities.size == 0
    # maximum_range 0 is no maximum: like FLASER, inferred (8.0 is 3 of the 6 readings).
    assert second.range_max_m == 8.0
    assert flaser.range_max_m == 8.0
    np.testing.assert_array_equal(second.valid, [False, True, True])

    # Laser pose as written; robot pose moved 0.1 m ahead along its heading 0.1.
    np.testing.assert_array_equal(log.laser_poses[1], [1.0, 2.0, 0.1])
    np.testing.assert_allclose(
        log.odom_poses[1], [0.9 + 0.1 * math.cos(0.1), 2.0 + 0.1 * math.sin(0.1), 0.1], atol=1e-15
    )
    np.testing.assert_array_equal(log.laser_poses[2], [3.0, 4.0, -0.5])
    np.testing.assert_array_equal(log.odom_poses[2], [3.0, 4.0, -0.5])
    assert log.sensor == {
        "range_max_m": "8",
        "range_max_from": (
            "ROBOTLASER1 maximum_range; "
            "inferred: 8 m, the largest reading that repeats, is 50 % of the readings"
        ),
        "readings": "3,4",
        "fov_deg": "28.64788976,171.8873385,180",
        "laser": "front",
        "laser_offset_m": "0.1",
        "records": "FLASER,ROBOTLASER1",
        "source": "robot.log",
        "format": "CARMEN log",
    }
    assert log.warnings == []


def robot_line(ranges, time_s: float) -> str:
    """A ROBOTLASER1 record: ``ranges`` over 180° from -90°, maximum range 50 m, no
    remissions, laser and robot pose (1, 2, 0.5)."""
    n = len(ranges)
    fov = math.pi
    return (
        f"ROBOTLASER1 0 {-fov / 2!r} {fov!r} {fov / (n - 1)!r} 50.0 0.01 0 {n} "
        f"{' '.join(f'{r:.3f}' for r in ranges)} 0 1.0 2.0 0.5 1.0 2.0 0.5 0 0 1.0 0.5 1000000 "
        f"{time_s} host {time_s}"
    )


def test_a_scan_written_as_both_flaser_and_robotlaser1_is_imported_once(tmp_path):
    """A logger writing each scan in both front-laser layouts: the ROBOTLASER1 records are
    read, the FLASER twins (same time, as many readings, values written to fewer digits)
    left out with one warning; a FLASER record without a twin stays."""
    rng = np.random.default_rng(4)
    ranges = np.round(rng.uniform(0.5, 9.0, size=(3, 181)), 3)
    lines = []
    for i, scan in enumerate(ranges):
        lines.append(laser_line(np.round(scan, 2), (1.0, 2.0, 0.5), (1.0, 2.0, 0.5), 10.0 + i))
        lines.append(robot_line(scan, 10.0 + i))
    lines.append(laser_line(ranges[0, :180], (1.0, 2.0, 0.5), (1.0, 2.0, 0.5), 12.0))
    lines.append(laser_line(ranges[1], (1.0, 2.0, 0.5), (1.0, 2.0, 0.5), 13.0))
    path = write(tmp_path / "both.log", lines)
    log = read_carmen(path)
    assert log.original_times_s.tolist() == [10.0, 11.0, 12.0, 12.0, 13.0]
    for scan, written in zip(log.scans[:3], ranges, strict=True):
        np.testing.assert_array_equal(scan.ranges_m, written)
        assert scan.range_max_m == 50.0
    assert len(log.scans[3]) == 180 and len(log.scans[4]) == 181
    assert log.numbers.tolist() == [2, 4, 6, 7, 8]
    assert log.sensor["records"] == "FLASER,ROBOTLASER1"
    repeats = [w for w in log.warnings if "left out" in w]
    assert repeats == [
        f"{path}: imported the ROBOTLASER1 records; left out 3 FLASER records repeating one of "
        "them (same time, as many readings)"
    ]
    # The rear laser's records are a different scanner: no twins there.
    rear = write(tmp_path / "rear.log", [line.replace("FLASER", "RLASER") for line in lines])
    assert not any("left out" in w for w in read_carmen(rear, laser="rear").warnings)


def test_range_max_argument_overrides_everything(tmp_path):
    path = write(
        tmp_path / "robot.log",
        [
            "PARAM robot_front_laser_max 4.0 h 0",
            ROBOTLASER,
            laser_line([3.0, 9.0], (0,) * 3, (0,) * 3, 9),
        ],
    )
    log = read_carmen(path, range_max_m=6.0)
    assert [s.range_max_m for s in log.scans] == [6.0, 6.0]
    np.testing.assert_array_equal(log.scans[0].valid, [True, True, True, False])
    np.testing.assert_array_equal(log.scans[1].valid, [True, False])
    assert log.sensor["range_max_m"] == "6"
    assert log.sensor["range_max_from"] == "given"


@pytest.mark.parametrize(
    "param",
    ["robot_front_laser_max 8.0 h 0", "laser_front_laser_max_range 8 h 0", "FRONT_LASER_MAX 8.0"],
)
def test_range_max_from_param_when_the_readings_repeat_no_no_return_value(tmp_path, param):
    path = write(
        tmp_path / "param.log",
        [
            "PARAM robot_rear_laser_max 3.0 h 0",
            laser_line([7.99, 8.0, 2.5, 4.0], (0,) * 3, (0,) * 3, 1.0),
            f"PARAM {param}",
        ],
    )
    log = read_carmen(path)
    assert log.scans[0].range_max_m == 8.0
    np.testing.assert_array_equal(log.scans[0].valid, [True, False, True, True])
    assert log.sensor["range_max_m"] == "8"
    assert log.sensor["range_max_from"] == (
        f"PARAM {param.split()[0]} (the readings repeat no no-return value, and no return lies "
        "beyond it)"
    )
    assert log.warnings == []


def test_the_no_return_value_the_readings_repeat_comes_before_a_param(tmp_path):
    """A PARAM that drops no return is not used either: the readings say where the
    scanner's no-return value lies (8.5 m here), and a reading at the PARAM is a return."""
    path = write(
        tmp_path / "param.log",
        [
            "PARAM robot_front_laser_max 8.0 h 0",
            laser_line([7.99, 8.0, 8.5, 8.5], (0,) * 3, (0,) * 3, 1.0),
        ],
    )
    log = read_carmen(path)
    assert log.scans[0].range_max_m == 8.5
    np.testing.assert_array_equal(log.scans[0].valid, [True, True, False, False])
    assert log.sensor["range_max_from"] == (
        "inferred: 8.5 m, the largest reading that repeats, is 50 % of the readings; "
        "PARAM robot_front_laser_max (8 m) not used"
    )
    assert log.warnings == []


def returns_beyond_a_param_log(path, param_m: float = 10.0, scans: int = 40):
    """A CARMEN log whose ``PARAM robot_front_laser_max`` says ``param_m`` while its scanner
    (181 beams) returns readings from 0.5 m to 49.88 m and writes 50 m for no return: in each
    scan, 30 beams at 50 m, and 45 beams from 10 to 49.88 m, continuous, as corridors give."""
    lines = [f"PARAM robot_front_laser_max {param_m:g} h 0"]
    for k in range(scans):
        ranges = np.concatenate(
            [
                np.linspace(0.5, 9.5, 106) + 0.01 * k,
                np.linspace(10.0, 49.8, 45) + 0.002 * k,
                np.full(30, 50.0),
            ]
        )
        lines.append(laser_line(np.round(ranges, 2), (k * 0.1, 0, 0), (k * 0.1, 0, 0), float(k)))
    return write(path, lines)


def test_a_param_below_real_returns_keeps_them_with_a_warning(tmp_path):
    path = returns_beyond_a_param_log(tmp_path / "far.log")
    log = read_carmen(path)
    ranges = np.concatenate([s.ranges_m for s in log.scans])
    valid = np.concatenate([s.valid for s in log.scans])
    beyond = (ranges >= 10.0) & (ranges < 50.0)
    assert np.count_nonzero(beyond) == 40 * 45
    # Every return between the PARAM and the no-return value is kept; 50 m is no return.
    assert valid[beyond].all()
    assert not valid[ranges == 50.0].any()
    assert valid[ranges < 10.0].all()
    assert [s.range_max_m for s in log.scans] == [50.0] * 40
    assert log.sensor["range_max_m"] == "50"
    assert log.sensor["range_max_from"] == (
        "inferred: 50 m, the largest reading that repeats, is 16.6 % of the readings; "
        "PARAM robot_front_laser_max (10 m) not used: returns lie beyond it"
    )
    assert log.warnings == [
        f"{path}: PARAM robot_front_laser_max (10 m) is not the scanner's range limit: it "
        "would have dropped 1800 readings (24.9 % of the readings) that are returns, from 10 m "
        "up to 49.88 m; the limit used is 50 m, the no-return value the readings repeat "
        "(--range-max-m sets one)"
    ]
    # A limit given keeps its word, and needs no warning.
    given = read_carmen(path, range_max_m=10.0)
    assert not np.concatenate([s.valid for s in given.scans])[beyond].any()
    assert given.warnings == []


def test_import_says_so_in_one_line_and_info_where_the_limit_came_from(capsys, tmp_path):
    from test_cli import run_cli

    path = returns_beyond_a_param_log(tmp_path / "far.log")
    out = tmp_path / "far.mcap"
    done = run_cli(capsys, "import", "carmen", path, "--out", out)
    assert done.code == 0, done.err
    assert [line for line in done.err.splitlines() if "warning" in line] == [
        f"segloc: warning: {path}: PARAM robot_front_laser_max (10 m) is not the scanner's "
        "range limit: it would have dropped 1800 readings (24.9 % of the readings) that are "
        "returns, from 10 m up to 49.88 m; the limit used is 50 m, the no-return value the "
        "readings repeat (--range-max-m sets one)"
    ]
    assert np.count_nonzero(np.concatenate([s.valid for s in read_log(out).scans])) == 40 * 151
    shown = run_cli(capsys, "info", out).out.splitlines()
    assert "sensor.range_max_m: 50" in shown
    assert (
        "sensor.range_max_from: inferred: 50 m, the largest reading that repeats, is 16.6 % of "
        "the readings; PARAM robot_front_laser_max (10 m) not used: returns lie beyond it"
    ) in shown


def test_robotlaser1_maximum_range_below_real_returns_is_not_used(tmp_path):
    """A ROBOTLASER1 record's own maximum_range is checked as a PARAM is."""
    lines = []
    for k in range(10):
        ranges = np.round(
            np.concatenate([np.linspace(1.0, 7.9, 12), np.linspace(8.0, 29.0, 4), [30.0] * 4]), 2
        )
        ranges[:12] += 0.01 * k
        fields = " ".join(f"{v:g}" for v in ranges)
        lines.append(
            f"ROBOTLASER1 0 -1.5 3.0 {3.0 / 19:.17g} 8.0 0.01 0 20 {fields} 0 "
            f"0 0 0 0 0 0 0 0 1.0 0.5 1000000 {k}.5 host {k}.5"
        )
    path = write(tmp_path / "robot.log", lines)
    log = read_carmen(path)
    assert [s.range_max_m for s in log.scans] == [30.0] * 10
    np.testing.assert_array_equal(log.scans[0].valid, [True] * 16 + [False] * 4)
    assert log.sensor["range_max_from"] == (
        "for 10 ROBOTLASER1 records whose maximum_range (8 m) returns lie beyond, inferred: 30 m, "
        "the largest reading that repeats, is 50 % of the readings from 8 m on"
    )
    assert log.warnings == [
        f"{path}: the maximum_range of 10 ROBOTLASER1 records (8 m) is not the scanner's range "
        "limit: it would have dropped 40 readings (20 % of the readings) that are returns, from "
        "8 m up to 29 m; the limit used is 30 m, the no-return value the readings repeat "
        "(--range-max-m sets one)"
    ]


def test_a_param_is_not_overruled_by_stray_readings(tmp_path):
    """Two readings beyond the PARAM among 7,240 (under 0.1 %) are strays, as above a
    no-return value: the PARAM stands where the readings repeat no no-return value."""
    lines = ["PARAM robot_front_laser_max 20 h 0"]
    for k in range(40):
        ranges = np.round(np.linspace(0.5, 19.0, 181) + 0.003 * k, 3)
        if k in (3, 30):
            ranges[90] = 25.0 + k
        lines.append(laser_line(ranges, (0,) * 3, (0,) * 3, float(k)))
    path = write(tmp_path / "stray.log", lines)
    log = read_carmen(path)
    assert [s.range_max_m for s in log.scans] == [20.0] * 40
    assert not log.scans[3].valid[90] and not log.scans[30].valid[90]
    assert log.warnings == []


def test_unusable_param_falls_back_to_inference_with_a_warning(tmp_path):
    path = write(
        tmp_path / "param.log",
        [
            "PARAM robot_front_laser_max far h 0",
            "PARAM robot_frontlaser_offset n/a h 0",
            laser_line([1.0, 2.0, 2.0], (0,) * 3, (1.0, 0.0, 0.0), 1.0),
        ],
    )
    log = read_carmen(path)
    assert log.scans[0].range_max_m == 2.0
    np.testing.assert_array_equal(log.odom_poses, [[1.0, 0.0, 0.0]])
    assert log.sensor["laser_offset_m"] == "0"
    assert log.warnings == [
        f"{path}: PARAM robot_front_laser_max is 'far', not a number (line 1); ignored",
        f"{path}: PARAM robot_frontlaser_offset is 'n/a', not a number (line 2); ignored",
    ]


NO_MAXIMUM = (
    "no maximum range found, no reading value repeats often enough at the top of the "
    "readings to be a no-return value (the largest reading is {} m); every positive reading "
    "counts as a return (pass --range-max-m if the scanner has a maximum range)"
)


@pytest.mark.parametrize(("n", "expected"), [(400, 9.0), (401, math.inf)])
def test_inferred_range_max_needs_half_a_percent(tmp_path, n, expected):
    # 1.0 repeats far more often, but 9.0 lies above it: only 9.0 can be the no-return value.
    ranges = [1.0] * (n - 2) + [9.0, 9.0]
    path = write(tmp_path / "rare.log", [laser_line(ranges, (0,) * 3, (0,) * 3, 1.0)])
    log = read_carmen(path)
    assert log.scans[0].range_max_m == expected
    assert bool(log.scans[0].valid[-1]) is math.isinf(expected)
    if math.isinf(expected):
        assert log.sensor["range_max_m"] == "inf"
        assert log.sensor["range_max_from"] == (
            "none: no reading value repeats often enough at the top of the readings to be a "
            "no-return value (the largest reading is 9 m)"
        )
        assert log.warnings == [f"{path}: " + NO_MAXIMUM.format(9)]
    else:
        assert log.sensor["range_max_m"] == "9"
        assert log.sensor["range_max_from"] == (
            "inferred: 9 m, the largest reading that repeats, is 0.5 % of the readings"
        )
        assert log.warnings == []


def test_a_lone_outlier_does_not_set_the_range_max(tmp_path):
    # 20 scans of 181 readings; every fifth reading is the 81.83 m no-return value, and
    # one reading is a corrupt 99999 m: the maximum stays 81.83 and 99999 is no return.
    lines = []
    for k in range(20):
        ranges = 0.5 + 0.001 * np.arange(181) + 0.2 * k
        ranges[::5] = 81.83
        if k == 7:
            ranges[3] = 99999.0
        lines.append(laser_line(ranges, (0,) * 3, (0,) * 3, float(k)))
    path = write(tmp_path / "outlier.log", lines)
    log = read_carmen(path)
    assert [s.range_max_m for s in log.scans] == [81.83] * 20
    assert log.sensor["range_max_from"] == (
        "inferred: 81.83 m, the largest reading that repeats, is 20.4 % of the readings; "
        "the 1 larger reading counts as no return"
    )
    assert not log.scans[7].valid[3]
    assert sum(int(np.count_nonzero(~s.valid)) for s in log.scans) == 20 * 37 + 1
    assert log.warnings == []


@pytest.mark.parametrize(
    ("ranges", "largest"),
    [
        (np.linspace(0.5, 30.0, 500), "30"),  # every value once
        # 2 m repeats in half the readings, but half lie above it: a wall, not a sentinel.
        (np.concatenate([np.full(100, 2.0), np.linspace(3.0, 20.0, 100)]), "20"),
    ],
)
def test_no_repeating_top_value_means_no_maximum_and_a_warning(tmp_path, ranges, largest):
    path = write(tmp_path / "plain.log", [laser_line(ranges, (0,) * 3, (0,) * 3, 1.0)])
    log = read_carmen(path)
    assert log.scans[0].range_max_m == math.inf
    assert log.scans[0].valid.all()
    assert log.sensor["range_max_m"] == "inf"
    assert log.warnings == [f"{path}: " + NO_MAXIMUM.format(largest)]
    # A given maximum, or a ROBOTLASER1 record's own, needs no warning.
    assert read_carmen(path, range_max_m=25.0).warnings == []


BAD_RECORDS = [
    laser_line([1.0, 2.0, 3.0], (0,) * 3, (0,) * 3, 1.0),  # 1 good
    "FLASER 3 1.0 2.0 0 0 0 0 0 0 2.0 h 2.0",  # 2 two readings for n = 3
    "FLASER 3 1.0 2.0",  # 3 truncated
    "FLASER",  # 4 no reading count
    "FLASER three 1 2 3 0 0 0 0 0 0 5.0 h 5.0",  # 5 reading count not a number
    "FLASER 3 1.0 abc 3.0 0 0 0 0 0 0 6.0 h 6.0",  # 6 non-numeric reading
    "FLASER 3 1.0 nan 3.0 0 0 0 0 0 0 7.0 h 7.0",  # 7 NaN reading
    "FLASER 3 1.0 2.0 3.0 0 NaN 0 0 0 0 8.0 h 8.0",  # 8 NaN pose
    "FLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 -9.0 h 9.0",  # 9 negative time
    "FLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 nan h 10.0",  # 10 NaN time
    "FLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 inf h 11.0",  # 11 infinite time
    "ODOM 1 2 3 0 0 0 12.0 h",  # 12 ODOM short
    "ODOM 1 x 3 0 0 0 13.0 h 13.0",  # 13 ODOM non-numeric
    "ODOM 1 2 3 0 0 0 -1 h 14.0",  # 14 ODOM negative time
    "FLASER 0 0 0 0 0 0 0 15.0 h 15.0",  # 15 zero readings
    laser_line([1.5, 2.5, 3.5], (1, 2, 0.5), (3, 4, -0.5), 16.0),  # 16 good
    "FLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 abc h 17.0",  # 17 non-numeric time
    "FLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 18.0 h zz",  # 18 non-numeric logger time
    "RLASER 3 x",  # 19 the rear laser: not read
    "ROBOTLASER1 0 -1.5 3.0 1.0 5.0 0.01 0 4 1.0 2.0",  # 20 truncated
    "FLASER 3 1 2 3 4 0 0 0 0 0 0 21.0 h 21.0",  # 21 four readings for n = 3
    "ODOM 0.5 0.5 0 0 0 0 22.0 h 22.0",  # 22 good ODOM
    laser_line([0.5, 0.75, 1.0], (0,) * 3, (0,) * 3, 23.0),  # 23 good
]


def test_bad_records_are_skipped_and_counted(tmp_path):
    path = write(tmp_path / "bad.log", BAD_RECORDS)
    log = read_carmen(path, range_max_m=50.0)
    assert [s.time_s for s in log.scans] == [1.0, 16.0, 23.0]
    np.testing.assert_array_equal(log.scans[0].ranges_m, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(log.scans[1].ranges_m, [1.5, 2.5, 3.5])
    np.testing.assert_array_equal(log.scans[2].ranges_m, [0.5, 0.75, 1.0])
    np.testing.assert_array_equal(log.laser_poses, [[0, 0, 0], [1, 2, 0.5], [0, 0, 0]])
    np.testing.assert_array_equal(log.odom_poses, [[0, 0, 0], [3, 4, -0.5], [0, 0, 0]])
    assert log.warnings == [
        f"{path}: skipped 3 FLASER records with a wrong field count (lines 2, 3, 21)",
        f"{path}: skipped 3 FLASER records with a missing, invalid or too large reading count "
        "(at most 100,000) (lines 4, 5, 15)",
        f"{path}: skipped 5 FLASER records with non-numeric or non-finite values "
        "(lines 6, 7, 8, 17, 18)",
        f"{path}: skipped 3 FLASER records with a negative, non-finite or too large timestamp "
        "(at most 4294967296 s) (lines 9, 10, 11)",
        f"{path}: skipped 1 ODOM record with a wrong field count (line 12)",
        f"{path}: skipped 1 ODOM record with non-numeric or non-finite values (line 13)",
        f"{path}: skipped 1 ODOM record with a negative, non-finite or too large timestamp "
        "(at most 4294967296 s) (line 14)",
        f"{path}: skipped 1 ROBOTLASER1 record with a wrong field count (line 20)",
    ]


def test_long_runs_of_bad_lines_show_the_first_five(tmp_path):
    first, last = (laser_line([1.0, 2.0], (0,) * 3, (0,) * 3, t) for t in (1.0, 2.0))
    path = write(tmp_path / "many.log.gz", [first] + ["FLASER 2 1.0"] * 7 + [last])
    log = read_carmen(path, range_max_m=10.0)
    assert len(log.scans) == 2
    assert log.warnings == [
        f"{path}: skipped 7 FLASER records with a wrong field count "
        "(lines 2, 3, 4, 5, 6 and 2 more)"
    ]


# --- damaged gzip -----------------------------------------------------------------

GOOD = [laser_line([1.0 + i, 2.0], (i, 0, 0), (i, 0, 0), float(i)) for i in range(4)]
LATER = [laser_line([5.5 + i, 7.25, 0.5 * i], (-i, 3, 1), (-i, 3, 1), 10.0 + i) for i in range(3)]


def gzip_parts(head: str, tail: str) -> tuple[bytes, bytes]:
    """A gzip stream of head + tail, split at a full flush point after ``head``."""
    deflate = zlib.compressobj(9, zlib.DEFLATED, 31)
    first = deflate.compress(head.encode()) + deflate.flush(zlib.Z_FULL_FLUSH)
    return first, deflate.compress(tail.encode()) + deflate.flush()


def assert_first_four(log) -> None:
    assert [s.time_s for s in log.scans] == [0.0, 1.0, 2.0, 3.0]
    np.testing.assert_array_equal(log.scans[3].ranges_m, [4.0, 2.0])
    np.testing.assert_array_equal(log.laser_poses[:, 0], [0.0, 1.0, 2.0, 3.0])


@pytest.mark.parametrize("partial", ["", "FLASER 2 1.0 "])
def test_garbage_in_a_gzip_keeps_the_lines_before_it(tmp_path, partial):
    head = "\n".join(GOOD) + "\n" + partial
    first, rest = gzip_parts(head, partial and "2.0 0 0 0 0 0 0 4.0 h 4.0\n" + "\n".join(LATER))
    path = tmp_path / "garbage.log.gz"
    path.write_bytes(first + b"\xff" * 32 + rest)
    log = read_carmen(path, range_max_m=20.0)
    assert_first_four(log)
    assert log.warnings == [
        f"{path}: the compressed data is corrupt (Error -3 while decompressing data: "
        "invalid block type); records from line 5 on are lost; "
        "the 4 complete lines before it are kept"
    ]


def test_gzip_cut_short_keeps_the_complete_lines(tmp_path):
    first, rest = gzip_parts("\n".join(GOOD) + "\n", "\n".join(LATER) + "\n")
    path = tmp_path / "cut.log.gz"
    path.write_bytes(first + rest[:2])
    log = read_carmen(path, range_max_m=20.0)
    assert_first_four(log)
    assert log.warnings == [
        f"{path}: the file ends in the middle of the compressed data (truncated); "
        "records from line 5 on are lost; the 4 complete lines before it are kept"
    ]


def test_gzip_cut_in_half_gives_a_prefix(tmp_path):
    lines = [laser_line([0.01 * i, 1.0, 2.0], (i, 0, 0), (i, 0, 0), float(i)) for i in range(300)]
    data = gzip.compress(("\n".join(lines) + "\n").encode())
    path = tmp_path / "half.log.gz"
    path.write_bytes(data[: len(data) // 2])
    # What zlib yields from the first half, up to its last line end.
    complete = zlib.decompressobj(31).decompress(data[: len(data) // 2]).count(b"\n")
    assert 0 < complete < 300
    log = read_carmen(path, range_max_m=20.0)
    assert [s.time_s for s in log.scans] == [float(i) for i in range(complete)]
    assert log.warnings == [
        f"{path}: the file ends in the middle of the compressed data (truncated); "
        f"records from line {complete + 1} on are lost; the {complete} complete lines before it "
        "are kept"
    ]


def test_gzip_with_a_bad_checksum_keeps_the_lines_and_names_them(tmp_path):
    data = bytearray(gzip.compress(("\n".join(GOOD) + "\n").encode()))
    data[-8] ^= 0xFF  # first byte of the CRC-32 in the trailer
    path = tmp_path / "crc.log.gz"
    path.write_bytes(bytes(data))
    log = read_carmen(path, range_max_m=20.0)
    assert_first_four(log)
    assert log.warnings == [
        f"{path}: lines 1–4 may hold damaged values; "
        "the checksum at the end of the compressed data does not match"
    ]


@pytest.mark.parametrize(
    ("flip", "what"), [(-8, "the checksum"), (-1, "the length")], ids=["crc", "length"]
)
def test_bad_trailer_in_one_member_names_only_its_lines(tmp_path, flip, what):
    members = [GOOD[:2], GOOD[2:], LATER[:1], LATER[1:]]
    parts = [bytearray(gzip.compress(("\n".join(m) + "\n").encode())) for m in members]
    parts[1][flip] ^= 0x01
    path = tmp_path / "members.log.gz"
    path.write_bytes(b"".join(parts))
    log = read_carmen(path, range_max_m=20.0)
    # Every record is kept, also those after the member whose trailer does not match.
    assert [s.time_s for s in log.scans] == [0.0, 1.0, 2.0, 3.0, 10.0, 11.0, 12.0]
    np.testing.assert_array_equal(log.scans[4].ranges_m, [5.5, 7.25, 0.0])
    assert log.warnings == [
        f"{path}: lines 3–4 may hold damaged values; "
        f"{what} at the end of the compressed data does not match"
    ]

    parts[1][flip] ^= 0x01
    parts[2][-8] ^= 0x80
    path.write_bytes(b"".join(parts))
    assert read_carmen(path, range_max_m=20.0).warnings == [
        f"{path}: line 5 may hold damaged values; "
        "the checksum at the end of the compressed data does not match"
    ]


def test_gzip_followed_by_junk(tmp_path):
    junk = tmp_path / "junk.log.gz"
    junk.write_bytes(gzip.compress(("\n".join(GOOD) + "\n").encode()) + b"not gzip")
    log = read_carmen(junk, range_max_m=20.0)
    assert_first_four(log)
    assert log.warnings == [
        f"{junk}: the compressed data is followed by bytes that are not gzip; "
        "records from line 5 on are lost; the 4 complete lines before it are kept"
    ]


# --- files that cannot be read ------------------------------------------------------


def test_missing_file_and_directory(tmp_path):
    missing = tmp_path / "nope.log.gz"
    with pytest.raises(InputError) as raised:
        read_carmen(missing)
    assert str(raised.value) == f"{missing}: file not found; check the path"
    with pytest.raises(InputError) as raised:
        read_carmen(tmp_path)
    assert str(raised.value) == (
        f"{tmp_path}: is a directory, expected a CARMEN log (text, or gzip-compressed text)"
    )


def test_binary_files_are_refused(tmp_path):
    expected = "not a text file; expected a CARMEN log (text, or gzip-compressed text)"
    binary = tmp_path / "image.png"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(range(256)))
    with pytest.raises(InputError) as raised:
        read_carmen(binary)
    assert str(raised.value) == f"{binary}: {expected}"

    packed = tmp_path / "packed.gz"
    packed.write_bytes(gzip.compress(bytes(range(256)) * 4))
    with pytest.raises(InputError) as raised:
        read_carmen(packed)
    assert str(raised.value) == f"{packed}: {expected}"


def test_no_records_of_the_chosen_laser(tmp_path):
    path = write(
        tmp_path / "odom.log",
        ["# only odometry", "PARAM robot_use_laser on h 0", "ODOM 0 0 0 0 0 0 1 h 1"] * 2,
    )
    with pytest.raises(InputError) as raised:
        read_carmen(path)
    assert str(raised.value) == (
        f"{path}: no FLASER records (nor ROBOTLASER1); record types found: ODOM ×2, PARAM ×2"
    )

    front_only = write(tmp_path / "front.log", [GOOD[0], "ODOM 0 0 0 0 0 0 1 h 1"])
    with pytest.raises(InputError) as raised:
        read_carmen(front_only, laser="rear")
    assert str(raised.value) == (
        f"{front_only}: no RLASER records; record types found: FLASER ×1, ODOM ×1; "
        "the file has FLASER records (the front laser)"
    )

    empty = write(tmp_path / "empty.log", ["# nothing here"])
    with pytest.raises(InputError) as raised:
        read_carmen(empty)
    assert (
        str(raised.value)
        == f"{empty}: no FLASER records (nor ROBOTLASER1); the file has no records"
    )


def test_no_readable_records_says_why(tmp_path):
    path = write(tmp_path / "broken.log", ["FLASER 2 1.0", "FLASER 2 1.0 2.0 0 0 0 0 0 0 -1 h 0"])
    with pytest.raises(InputError) as raised:
        read_carmen(path)
    assert str(raised.value) == (
        f"{path}: no FLASER records (nor ROBOTLASER1) that can be read (all 2 were skipped); "
        "record types found: FLASER ×2; "
        "skipped 1 FLASER record with a wrong field count (line 1); "
        "skipped 1 FLASER record with a negative, non-finite or too large timestamp "
        "(at most 4294967296 s) (line 2)"
    )

    damaged = tmp_path / "damaged.log.gz"
    damaged.write_bytes(gzip.compress(b"FLASER 2 1.0 2.0")[:10] + b"\xff" * 16)  # header only
    with pytest.raises(InputError) as raised:
        read_carmen(damaged)
    assert str(raised.value) == (
        f"{damaged}: no FLASER records (nor ROBOTLASER1); the file has no records; "
        "the compressed data is corrupt (Error -3 while decompressing data: invalid block type); "
        "records from line 1 on are lost"
    )


def test_bad_arguments(tmp_path):
    path = write(tmp_path / "basic.log", BASIC)
    with pytest.raises(ValueError, match="laser must be one of \\['front', 'rear'\\], got 'top'"):
        read_carmen(path, laser="top")
    with pytest.raises(ValueError, match=r"range_max_m must be positive, got 0\.0"):
        read_carmen(path, range_max_m=0.0)


# --- into a segloc log and back -------------------------------------------------------


def test_round_trip_through_the_mcap_log(tmp_path):
    path = write(tmp_path / "trip.log.gz", [*BASIC, ROBOTLASER])
    log = read_carmen(path)
    out = tmp_path / "trip.mcap"
    odom = [(t, Pose2(*pose)) for t, pose in zip(log.odom_times_s, log.odom_poses, strict=True)]
    write_log(out, log.scans, odom, log.sensor)
    back = read_log(out)

    assert back.warnings == []
    assert back.sensor == log.sensor
    assert back.sensor["range_max_m"] == "81.83"
    assert len(back.scans) == 4
    for got, want in zip(back.scans, log.scans, strict=True):
        assert got.time_s == want.time_s
        np.testing.assert_allclose(got.angles_rad, want.angles_rad, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(got.valid, want.valid)
        np.testing.assert_array_equal(got.ranges_m, np.where(want.valid, want.ranges_m, 0.0))
        np.testing.assert_array_equal(got.intensities, want.intensities)
    # The ROBOTLASER1 scan kept its own 5 m maximum: 5.0 and 6.5 stay invalid.
    np.testing.assert_array_equal(back.scans[3].ranges_m, [1.0, 2.0, 0.0, 0.0])
    np.testing.assert_array_equal(back.odom_times_s, log.odom_times_s)
    np.testing.assert_array_equal(back.odom_poses[:, :2], log.odom_poses[:, :2])
    np.testing.assert_allclose(back.odom_poses[:, 2], log.odom_poses[:, 2], rtol=0, atol=1e-12)


# --- colliding times ----------------------------------------------------------------


def timed(times: list) -> list[str]:
    """One small FLASER record per time, written as given (a string stays as printed)."""
    return [laser_line([1.0, 2.0, 2.0], (k, 0, 0), (k, 0, 0), t) for k, t in enumerate(times)]


COLLIDING = (
    "laser records share their time with another or go back in time; "
    "gave them distinct times in file order (see README: colliding times)"
)


def test_all_times_zero_become_one_second_apart(tmp_path):
    path = write(tmp_path / "zeros.log", timed(["0", "0", "0", "0"]))
    log = read_carmen(path)
    assert [s.time_s for s in log.scans] == [0.0, 1.0, 2.0, 3.0]
    np.testing.assert_array_equal(log.odom_times_s, [0.0, 1.0, 2.0, 3.0])
    np.testing.assert_array_equal(log.original_times_s, [0.0, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(log.laser_poses[:, 0], [0, 1, 2, 3])  # order kept
    assert log.warnings == [f"{path}: 4 of 4 {COLLIDING}"]


def test_six_significant_digits_are_spread_over_their_gap(tmp_path):
    path = write(tmp_path / "coarse.log.gz", timed(["1.13486e+09"] * 3 + ["1.13487e+09"] * 2))
    log = read_carmen(path)
    t0, t1 = 1.13486e9, 1.13487e9
    step = (t1 - t0) / 3
    # The last group is spaced as the groups before it, but at most 1 s apart.
    assert [s.time_s for s in log.scans] == [t0, t0 + step, t0 + 2 * step, t1, t1 + 1.0]
    np.testing.assert_array_equal(log.odom_times_s, [s.time_s for s in log.scans])
    np.testing.assert_array_equal(log.original_times_s, [t0] * 3 + [t1] * 2)
    assert log.warnings == [f"{path}: 5 of 5 {COLLIDING}"]


def test_one_step_back_and_increasing_times(tmp_path):
    path = write(tmp_path / "back.log", timed(["10.0", "11.0", "12.0", "11.5", "14.0"]))
    log = read_carmen(path)
    assert [s.time_s for s in log.scans] == [10.0, 11.0, 12.0, 13.0, 14.0]
    np.testing.assert_array_equal(log.original_times_s, [10.0, 11.0, 12.0, 11.5, 14.0])
    assert log.warnings == [f"{path}: 2 of 5 {COLLIDING}"]

    increasing = read_carmen(write(tmp_path / "fine.log", timed(["0.5", "0.75", "2"])))
    assert [s.time_s for s in increasing.scans] == [0.5, 0.75, 2.0]
    np.testing.assert_array_equal(increasing.original_times_s, [0.5, 0.75, 2.0])
    assert increasing.warnings == []


def test_distinct_times_survive_the_mcap_log(tmp_path):
    log = read_carmen(write(tmp_path / "zeros.log", timed(["0"] * 3)))
    out = tmp_path / "zeros.mcap"
    odom = [(t, Pose2(*pose)) for t, pose in zip(log.odom_times_s, log.odom_poses, strict=True)]
    write_log(out, log.scans, odom, log.sensor)
    back = read_log(out)
    assert [s.time_s for s in back.scans] == [0.0, 1.0, 2.0]
    np.testing.assert_array_equal(back.odom_times_s, [0.0, 1.0, 2.0])


# --- NUL bytes and odd bytes ----------------------------------------------------------


def test_lines_with_nul_bytes_are_skipped_and_counted(tmp_path):
    lines = list(BASIC)
    lines[0] = "# CARMEN Logfile \x00\x00 written by a crashed logger"
    lines.insert(9, "FLASER 5 1 2 3 4 5 0 0 0 0 0 0 33.7 pip\x00po 33.7")
    path = write(tmp_path / "nul.log", lines)
    log = read_carmen(path)
    assert [s.time_s for s in log.scans] == [32.9068, 33.5, 34.0]
    assert log.warnings == [f"{path}: skipped 2 lines holding NUL bytes (lines 1, 10)"]


def test_mostly_nul_lines_or_no_record_besides_them_is_not_text(tmp_path):
    expected = "not a text file; expected a CARMEN log (text, or gzip-compressed text)"
    wide = tmp_path / "utf16.log"
    wide.write_bytes(("\n".join(BASIC) + "\n").encode("utf-16-le"))
    many = write(tmp_path / "many.log", [GOOD[0], "a\x00", "b\x00", "c\x00", GOOD[1]])
    only = write(tmp_path / "only.log", ["# fine", "\x00\x00\x00", "ODOM 0 0 0 0 0 0 1 h 1"])
    for path in (wide, many, only):
        with pytest.raises(InputError) as raised:
            read_carmen(path)
        assert str(raised.value) == f"{path}: {expected}"
    # Two of five lines is not most of them.
    log = read_carmen(write(tmp_path / "some.log", [GOOD[0], "a\x00", "b\x00", *GOOD[1:3]]))
    assert len(log.scans) == 3


ODD_RECORDS = [
    laser_line([1.0, 2.0, 2.0], (0,) * 3, (0,) * 3, 1.0),  # 1 good
    "FLASER 999999999999 1 2 3 0 0 0 0 0 0 2.0 h 2.0",  # 2 huge count
    "FLASER " + "9" * 5000 + " 1 0 0 0 0 0 0 3.0 h 3.0",  # 3 count beyond int()'s digits
    "FLASER 3 1e400 2 3 0 0 0 0 0 0 4.0 h 4.0",  # 4 overflows to inf
    "FLASER 3 1 2 3 0 0 0 0 0 0 5e9 h 5e9",  # 5 time beyond 2^32 s
    "FLASER 3 1 2 2 0 0 0 0 0 0 -0.0 h 6.0",  # 6 negative zero: time 0
    "FLASER 3 1 inf 3 0 0 0 0 0 0 7.0 h 7.0",  # 7 inf reading
    "FLASER 3 1 2 3 0 nan 0 0 0 0 8.0 h 8.0",  # 8 nan pose
    "FL\xc3\xa9SER 3 1 2 3 0 0 0 0 0 0 9.0 h 9.0",  # 9 not a record type
    "FLASER 3 1 2 \xff 0 0 0 0 0 0 10.0 h 10.0",  # 10 invalid UTF-8 reading
    "FLASER 100001 " + "1 " * 100001 + "0 0 0 0 0 0 11.0 h 11.0",  # 11 above MAX_READINGS
    "ROBOTLASER1 0 -90 180 1 80 0.01 0 2 1.0 2.0 0 0 0 0 0 0 0 0 0 1 0.5 1 12.0 h 12.0",  # 12 deg
    laser_line([1.5, 2.5, 2.5], (1,) * 3, (1,) * 3, 13.0),  # 13 good
]


def test_odd_bytes_and_numbers_are_skipped_and_counted(tmp_path):
    path = tmp_path / "odd.log"
    path.write_bytes(("\n".join(ODD_RECORDS) + "\n").encode("latin-1"))
    log = read_carmen(path)
    assert [s.time_s for s in log.scans] == [1.0, 7.0, 13.0]  # 0.0 went back: after 1.0
    assert log.original_times_s.tolist() == [1.0, 0.0, 13.0]
    assert math.copysign(1.0, log.original_times_s[1]) == 1.0  # not -0.0
    assert log.warnings == [
        f"{path}: skipped 3 FLASER records with a missing, invalid or too large reading count "
        "(at most 100,000) (lines 2, 3, 11)",
        f"{path}: skipped 4 FLASER records with non-numeric or non-finite values "
        "(lines 4, 7, 8, 10)",
        f"{path}: skipped 1 FLASER record with a negative, non-finite or too large timestamp "
        "(at most 4294967296 s) (line 5)",
        f"{path}: skipped 1 ROBOTLASER1 record with a beam fan that decreases, is degenerate, "
        "is wider than a full turn, lies beyond ±4π rad, or whose angular resolution disagrees "
        "with its field of view (line 12)",
        f"{path}: 2 of 3 {COLLIDING}",
    ]


def test_unprintable_names_are_escaped_in_messages(tmp_path):
    path = tmp_path / "names.log"
    path.write_bytes(b"\xffFLASER\x1b[2J 1 2\nPARAM robot_front_laser_max \x85far\x07 h 0\n")
    with pytest.raises(InputError) as raised:
        read_carmen(path)
    message = str(raised.value)
    assert message == f"{path}: no FLASER records (nor ROBOTLASER1); record types found: " + (
        "PARAM ×1, \\xffFLASER\\x1b[2J ×1"
    )
    path.write_bytes(b"PARAM robot_front_laser_max \x85far\x07 h 0\n" + GOOD[0].encode() + b"\n")
    assert read_carmen(path).warnings[0] == (
        f"{path}: PARAM robot_front_laser_max is '\\x85far\\x07', not a number (line 1); ignored"
    )


def test_an_absurd_laser_offset_is_ignored(tmp_path):
    path = write(
        tmp_path / "offset.log",
        ["PARAM robot_frontlaser_offset 1e300 h 0", laser_line([1, 2], (0,) * 3, (1, 0, 0), 1.0)],
    )
    log = read_carmen(path, range_max_m=5.0)
    np.testing.assert_array_equal(log.odom_poses, [[1.0, 0.0, 0.0]])
    assert log.sensor["laser_offset_m"] == "0"
    assert log.warnings == [
        f"{path}: PARAM robot_frontlaser_offset is 1e+300 m, more than 10 m; ignored"
    ]


def test_times_spread_past_the_limit_are_refused(tmp_path):
    # The last group's records, 1 s apart, run past 2**32 s.
    path = write(tmp_path / "far.log", timed(["0", "4294967295", "4294967295", "4294967295"]))
    with pytest.raises(InputError) as raised:
        read_carmen(path)
    assert str(raised.value) == (
        f"{path}: the times of the laser records, made distinct, run past 4294967296 s "
        "(the year 2106); the log's times are not plausible (see README: colliding times)"
    )
