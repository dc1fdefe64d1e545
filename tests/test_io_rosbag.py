"""ROS bags: small bags written here with rosbags' own writers, read back field by field."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import HALL
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Ros2Writer
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore
from test_cli import assert_one_line_error, run_cli, run_in_process

from segloc_cli.errors import InputError
from segloc_cli.geometry import Pose2, heading_to_quaternion
from segloc_cli.io.mcap_log import read_log, write_log
from segloc_cli.io.rosbag import read_rosbag, ros1_typestore, shortest_decimals

ROS1_STORE = ros1_typestore()
ROS2_STORE = get_typestore(Stores.LATEST)
SCAN_TYPE = "sensor_msgs/msg/LaserScan"
ODOM_TYPE = "nav_msgs/msg/Odometry"
FORMATS = ["ros1", "ros2-folder", "ros2-mcap"]

# A 181-beam, 180° scanner. LaserScan fields are float32: a reader gets the angles back as
# the float32 values widened to float64, and the ranges, intensities and range limits as the
# shortest decimals that read back as those float32 values (``decimal``).
N_BEAMS = 181
ANGLE_MIN = float(np.float32(-np.pi / 2))
ANGLE_MAX = float(np.float32(np.pi / 2))
ANGLE_INCREMENT = float(np.float32(np.pi / 180))
RANGE_MIN = 0.1  # float32 0.1 read as the shortest decimal
RANGE_MAX = 30.0

EPOCH_S = 1_700_000_000  # stamps near today's Unix time, where float seconds are coarse
# Header stamps of the scans in the order they are written (ns after EPOCH_S): the
# fourth is written after the third but stamped before it.
SCAN_STAMPS_NS = [0, 50_000_000, 200_000_000, 100_000_000, 300_000_000, 450_000_000]
SCAN_TIMES_S = [
    1_700_000_000.0,
    1_700_000_000.05,
    1_700_000_000.1,
    1_700_000_000.2,
    1_700_000_000.3,
    1_700_000_000.45,
]
# Odometry at another rate, from the second scan's stamp to between the last two.
ODOM = [
    (50_000_000, Pose2(1.0, 2.0, 0.5)),
    (130_000_000, Pose2(1.8, 1.2, 0.9)),
    (250_000_000, Pose2(3.0, 0.0, 3.0)),
    (330_000_000, Pose2(3.4, -0.8, -3.0)),
]
# By hand: the scans at 0.1, 0.2 and 0.3 s lie 0.625, 7/12 and 0.625 of the way
# between their odometry neighbours; the last pair's heading goes from 3.0 across
# +π to −3.0, the short way (0.283 rad), not back through zero.
EXPECTED_ODOM_TIMES_S = SCAN_TIMES_S[1:5]
EXPECTED_ODOM_POSES = np.array(
    [
        [1.0, 2.0, 0.5],
        [1.5, 1.5, 0.75],
        [2.5, 0.5, 0.9 + 7 / 12 * 2.1],
        [3.25, -0.5, 3.0 + 0.625 * (2 * math.pi - 6.0) - 2 * math.pi],
    ]
)


def scan_ranges(k: int) -> np.ndarray:
    """Ranges (float32) of the ``k``-th scan written: a ramp with invalid readings of every kind."""
    ranges = (1.0 + 0.01 * np.arange(N_BEAMS) + 0.5 * k).astype(np.float32)
    ranges[0] = RANGE_MAX  # no return
    ranges[1] = np.nan
    ranges[2] = 0.05  # below range_min
    ranges[3] = RANGE_MIN  # exactly range_min: valid
    ranges[4] = np.inf
    ranges[5] = 29.99  # just below range_max: valid
    ranges[6] = 31.0  # above range_max
    ranges[N_BEAMS - 1] = RANGE_MAX
    return ranges


INVALID_BEAMS = [0, 1, 2, 4, 6, N_BEAMS - 1]


def no_mounting(name: str, robot: str | None = "base_link") -> str:
    """The warning on a bag whose transforms do not place its scanner on its robot
    (``robot`` None: a bag read without odometry)."""
    why = (
        "no odometry frame and no transform to laser (the scans' frame)"
        if robot is None
        else f"no transform from {robot} (the robot) to laser (the scans' frame) in /tf_static "
        "or /tf"
    )
    return (
        f"{name}: {why}; the scanner is taken to be at the robot's origin "
        "(--laser-offset X,Y,THETA_DEG sets it)"
    )


def scan_intensities(k: int) -> np.ndarray:
    """Intensities of the ``k``-th scan written; the third has none."""
    if k == 2:
        return np.zeros(0, dtype=np.float32)
    return (np.arange(N_BEAMS) * 2.0 + k).astype(np.float32)


def header(store: Typestore, stamp_ns: int, frame_id: str):
    sec, nanosec = divmod(EPOCH_S * 1_000_000_000 + stamp_ns, 1_000_000_000)
    stamp = store.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
    fields = {"seq": 0} if store is ROS1_STORE else {}
    return store.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id, **fields)


def laser_scan(
    store: Typestore,
    stamp_ns: int,
    ranges: np.ndarray,
    intensities=(),
    angle_max: float = ANGLE_MAX,
    range_max: float = RANGE_MAX,
):
    """A LaserScan of this file's scanner; ``stamp_ns`` counts from ``EPOCH_S``."""
    return store.types[SCAN_TYPE](
        header=header(store, stamp_ns, "laser"),
        angle_min=ANGLE_MIN,
        angle_max=angle_max,
        angle_increment=ANGLE_INCREMENT,
        time_increment=0.0,
        scan_time=0.0,
        range_min=RANGE_MIN,
        range_max=range_max,
        ranges=np.asarray(ranges, dtype=np.float32),
        intensities=np.asarray(intensities, dtype=np.float32),
    )


def odometry(store: Typestore, stamp_ns: int, pose: Pose2, child: str = "base_link"):
    t = store.types
    qx, qy, qz, qw = heading_to_quaternion(pose.theta).tolist()
    vector = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    return t[ODOM_TYPE](
        header=header(store, stamp_ns, "odom"),
        child_frame_id=child,
        pose=t["geometry_msgs/msg/PoseWithCovariance"](
            pose=t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=pose.x, y=pose.y, z=0.0),
                orientation=t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
            ),
            covariance=np.zeros(36),
        ),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](linear=vector, angular=vector),
            covariance=np.zeros(36),
        ),
    )


def serialize(store: Typestore, message, msgtype: str) -> bytes:
    if store is ROS1_STORE:
        return bytes(store.serialize_ros1(message, msgtype))
    return bytes(store.serialize_cdr(message, msgtype))


def scan_record(store: Typestore, record_ns: int, *args, **kwargs) -> tuple[str, int, bytes]:
    """A /scan message for ``write_bag``; the other arguments go to ``laser_scan``."""
    return ("/scan", record_ns, serialize(store, laser_scan(store, *args, **kwargs), SCAN_TYPE))


def odom_record(
    store: Typestore, record_ns: int, stamp_ns: int, pose: Pose2, child: str = "base_link"
) -> tuple:
    """An /odom message for ``write_bag`` (``child``: its child_frame_id)."""
    message = odometry(store, stamp_ns, pose, child)
    return ("/odom", record_ns, serialize(store, message, ODOM_TYPE))


def write_bag(kind: str, where: Path, topics: dict[str, str], messages: list) -> Path:
    """Write a bag of ``kind`` in folder ``where``; returns its path.

    ``topics`` maps topic → type; ``messages`` are (topic, record time ns, bytes).
    rosbags writes ROS 2 bags only as folders: the single ``.mcap`` file is the one
    in an MCAP-storage folder, taken out on its own (as ``ros2 bag record`` makes it).
    """
    if kind == "ros1":
        path = where / "test.bag"
        with Ros1Writer(path) as writer:
            connections = {
                topic: writer.add_connection(topic, msgtype, typestore=ROS1_STORE)
                for topic, msgtype in topics.items()
            }
            for topic, record_ns, data in messages:
                writer.write(connections[topic], record_ns, data)
        return path
    plugin = StoragePlugin.SQLITE3 if kind == "ros2-folder" else StoragePlugin.MCAP
    folder = where / "test_bag"
    with Ros2Writer(folder, version=9, storage_plugin=plugin) as writer:
        connections = {
            topic: writer.add_connection(topic, msgtype, typestore=ROS2_STORE)
            for topic, msgtype in topics.items()
        }
        for topic, record_ns, data in messages:
            writer.write(connections[topic], record_ns, data)
    if kind == "ros2-folder":
        return folder
    path = where / "test.mcap"
    (folder / "test_bag.mcap").rename(path)
    shutil.rmtree(folder)
    return path


def store_of(kind: str) -> Typestore:
    return ROS1_STORE if kind == "ros1" else ROS2_STORE


def standard_messages(kind: str) -> list:
    store = store_of(kind)
    record_ns = EPOCH_S * 1_000_000_000
    messages = [
        scan_record(store, record_ns + 1_000_000 * k, stamp, scan_ranges(k), scan_intensities(k))
        for k, stamp in enumerate(SCAN_STAMPS_NS)
    ]
    messages += [
        odom_record(store, record_ns + 1_000_000 * k + 500_000, stamp, pose)
        for k, (stamp, pose) in enumerate(ODOM)
    ]
    return sorted(messages, key=lambda m: m[1])


TOPICS = {"/scan": SCAN_TYPE, "/odom": ODOM_TYPE}


@pytest.fixture(params=FORMATS)
def kind(request) -> str:
    return request.param


@pytest.fixture
def bag(kind, tmp_path) -> Path:
    return write_bag(kind, tmp_path, TOPICS, standard_messages(kind))


# Scans in stamp order: the k-th scan read is the one written as WRITTEN_ORDER[k].
WRITTEN_ORDER = [0, 1, 3, 2, 4, 5]


def decimal(values_float32) -> np.ndarray:
    """Float32 values as the shortest decimals that read back as each (float64)."""
    return np.array([float(str(v)) for v in np.asarray(values_float32, np.float32).ravel()])


def expected_ranges(k: int) -> np.ndarray:
    ranges = decimal(scan_ranges(k))
    ranges[INVALID_BEAMS] = 0.0
    return ranges


# --- round trip ------------------------------------------------------------------------


def test_scans_in_stamp_order_with_every_field(bag):
    log = read_rosbag(bag)

    assert [scan.time_s for scan in log.scans] == SCAN_TIMES_S
    for scan, k in zip(log.scans, WRITTEN_ORDER, strict=True):
        assert len(scan) == N_BEAMS
        assert scan.angles_rad[0] == ANGLE_MIN
        assert scan.angles_rad[-1] == ANGLE_MIN + 180 * ANGLE_INCREMENT
        assert scan.angles_rad[-1] == pytest.approx(np.pi / 2, abs=1e-6)
        np.testing.assert_allclose(np.diff(scan.angles_rad), ANGLE_INCREMENT, rtol=0, atol=1e-15)
        np.testing.assert_array_equal(scan.ranges_m, expected_ranges(k))
        assert scan.range_max_m == RANGE_MAX
        valid = np.ones(N_BEAMS, dtype=bool)
        valid[INVALID_BEAMS] = False
        np.testing.assert_array_equal(scan.valid, valid)
        np.testing.assert_array_equal(scan.intensities, decimal(scan_intensities(k)))

    first = log.scans[0]
    assert first.ranges_m[3] == RANGE_MIN
    assert first.ranges_m[5] == 29.99
    assert first.ranges_m[7] == 1.07
    assert log.scans[3].intensities.shape == (0,)  # the third written, the fourth by stamp


def test_odometry_interpolated_to_scan_times(bag):
    log = read_rosbag(bag)

    # The first scan precedes the odometry and the last follows it: neither has a pose.
    assert log.odom_times_s.tolist() == EXPECTED_ODOM_TIMES_S
    assert log.odom_poses.shape == (4, 3)
    np.testing.assert_allclose(log.odom_poses, EXPECTED_ODOM_POSES, rtol=0, atol=1e-12)
    assert log.odom_poses[3, 2] == pytest.approx(-3.106194490192345, abs=1e-12)


def test_sensor_settings_and_warnings(bag):
    log = read_rosbag(bag)

    kind = "ROS 1 bag" if bag.suffix == ".bag" else "ROS 2 bag"
    assert log.sensor == {
        "range_max_m": "30.0",
        "range_max_from": "LaserScan range_max",
        "range_min_m": "0.1",
        "readings": "181",
        "fov_deg": "180",
        "frame_id": "laser",
        "source": f"{kind} {bag.name}",
        "scan_topic": "/scan",
        "odom_topic": "/odom",
        "laser_x_m": "0.0",
        "laser_y_m": "0.0",
        "laser_theta_deg": "0.0",
        "laser_offset_source": "none",
    }
    assert log.laser_offset == Pose2(0.0, 0.0, 0.0)
    assert log.warnings == [
        no_mounting(bag.name),
        f"{bag.name}: 2 of 6 scans lie outside the time span of /odom and have no odometry",
    ]


def test_without_odometry_topic(bag):
    log = read_rosbag(bag, odom_topic=None)

    assert len(log.scans) == 6
    assert log.odom_times_s.shape == (0,)
    assert log.odom_poses.shape == (0, 3)
    assert log.sensor["odom_topic"] == "none"
    assert log.warnings == [no_mounting(bag.name, robot=None)]


def test_round_trip_through_the_mcap_log(bag, tmp_path):
    log = read_rosbag(bag)
    out = tmp_path / "log.mcap"
    odom = [(t, Pose2(*pose)) for t, pose in zip(log.odom_times_s, log.odom_poses, strict=True)]

    write_log(out, log.scans, odom, log.sensor)
    back = read_log(out)

    assert back.sensor == log.sensor
    assert back.warnings == []
    assert len(back.scans) == len(log.scans)
    for got, want in zip(back.scans, log.scans, strict=True):
        assert got.time_s == want.time_s
        np.testing.assert_allclose(got.angles_rad, want.angles_rad, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(got.ranges_m, want.ranges_m)
        np.testing.assert_array_equal(got.valid, want.valid)
        np.testing.assert_array_equal(got.intensities, want.intensities)
        assert got.range_max_m == want.range_max_m
    np.testing.assert_array_equal(back.odom_times_s, log.odom_times_s)
    np.testing.assert_allclose(back.odom_poses, log.odom_poses, rtol=0, atol=1e-12)


def test_single_odometry_message_covers_only_its_own_instant(tmp_path):
    store = ROS1_STORE
    # One odometry message only: its own instant is the whole span.
    messages = [
        scan_record(store, 1, 10_000_000, scan_ranges(0)),
        scan_record(store, 2, 20_000_000, scan_ranges(1)),
        odom_record(store, 3, 20_000_000, Pose2(-1.0, 4.0, -2.0)),
    ]
    log = read_rosbag(write_bag("ros1", tmp_path, TOPICS, messages))

    assert log.odom_times_s.tolist() == [EPOCH_S + 0.02]
    np.testing.assert_allclose(log.odom_poses, [[-1.0, 4.0, -2.0]], rtol=0, atol=1e-12)


def test_odd_scans_are_read_with_warnings(tmp_path):
    store = ROS1_STORE
    ranges = scan_ranges(0)
    messages = [
        # angle_max one beam short of what 181 ranges at this increment span
        scan_record(store, 1, 0, ranges, angle_max=ANGLE_MAX - ANGLE_INCREMENT),
        # three intensities for 181 ranges
        scan_record(store, 2, 100_000_000, ranges, [1.0, 2.0, 3.0]),
        # 180 ranges where the angles give 181 beams, twice
        scan_record(store, 3, 200_000_000, ranges[:-1]),
        scan_record(store, 4, 300_000_000, ranges[:-1]),
    ]
    path = write_bag("ros1", tmp_path, TOPICS, messages)
    log = read_rosbag(path, odom_topic=None)

    first, second, short, _ = log.scans
    assert first.angles_rad[0] == ANGLE_MIN
    assert first.angles_rad[-1] == ANGLE_MIN + 180 * ANGLE_INCREMENT
    assert second.intensities.shape == (0,)
    np.testing.assert_array_equal(second.ranges_m, expected_ranges(0))
    assert len(short) == 180
    assert short.angles_rad[-1] == ANGLE_MIN + 179 * ANGLE_INCREMENT
    assert log.sensor["readings"] == "180,181"
    assert log.warnings == [
        no_mounting("test.bag", robot=None),
        "test.bag: 1 of 4 scans holds more readings than its angles give (181 readings, where "
        "angle_min -1.5708 to angle_max 1.55334 rad in steps of 0.0174533 rad give 180 beams); "
        "all its readings are kept, beam i at angle_min + i·angle_increment, so its last beam "
        "lies past angle_max (at 1.5708 rad)",
        "test.bag: 2 of 4 scans hold fewer readings than their angles give (first: 180 "
        "readings, where angle_min -1.5708 to angle_max 1.5708 rad in steps of 0.0174533 rad "
        "give 181 beams); all their readings are kept, beam i at angle_min + "
        "i·angle_increment, so their last beam lies short of angle_max (first: at 1.55334 rad)",
        "test.bag: 1 of 4 scans holds a number of intensities other than its number of "
        "readings (3 intensities for 181 readings); its intensities were dropped and its "
        "readings kept",
    ]


def test_range_max_of_each_scan_and_the_largest_for_the_log(tmp_path):
    store = ROS1_STORE
    five_beams = ANGLE_MIN + 4 * ANGLE_INCREMENT
    messages = [
        scan_record(store, 1, 0, [29.0, 30.0, 12.0, 30.0, 31.0], range_max=30.0,
                    angle_max=five_beams),
        scan_record(store, 2, 9, [29.0, 30.0, 49.0, 50.0, 50.0], range_max=50.0,
                    angle_max=five_beams),
    ]  # fmt: skip
    path = write_bag("ros1", tmp_path, TOPICS, messages)
    log = read_rosbag(path, odom_topic=None)

    # One reading (31 m) beyond the first scan's range_max is a stray, not returns.
    assert [scan.range_max_m for scan in log.scans] == [30.0, 50.0]
    np.testing.assert_array_equal(log.scans[0].ranges_m, [29.0, 0.0, 12.0, 0.0, 0.0])
    np.testing.assert_array_equal(log.scans[1].ranges_m, [29.0, 30.0, 49.0, 0.0, 0.0])
    assert log.sensor["range_max_m"] == "50.0"
    assert log.sensor["range_max_from"] == "LaserScan range_max"
    assert log.sensor["readings"] == "5"
    assert "test.bag: range_max varies between scans (30.0 to 50.0 m); each scan keeps its own" in (
        log.warnings
    )


def far_ranges(k: int) -> np.ndarray:
    """The float32 ranges of scan ``k`` of ``far_returns_bag``: 181 beams, 106 from 0.5 to
    9.6 m, 45 from 10 to 49.9 m, continuous, and 30 at 50 m, the scanner's no-return value."""
    ranges = np.concatenate(
        [
            np.linspace(0.5, 9.5, 106) + 0.005 * k,
            np.linspace(10.0, 49.8, 45) + 0.005 * k,
            np.full(30, 50.0),
        ]
    )
    return ranges.astype(np.float32)


def far_returns_bag(where: Path, kind: str, range_max: float = 10.0) -> Path:
    """A bag of 20 scans (``far_ranges``) whose messages say ``range_max``."""
    store = store_of(kind)
    messages = [
        scan_record(store, k + 1, k * 100_000_000, far_ranges(k), range_max=range_max)
        for k in range(20)
    ]
    return write_bag(kind, where, TOPICS, messages)


@pytest.mark.parametrize("kind", FORMATS)
def test_a_range_max_below_real_returns_keeps_them_with_a_warning(tmp_path, kind):
    path = far_returns_bag(tmp_path, kind)
    log = read_rosbag(path, odom_topic=None)

    written = np.concatenate([decimal(far_ranges(k)) for k in range(20)])
    ranges = np.concatenate([s.ranges_m for s in log.scans])
    beyond = (written >= 10.0) & (written < 50.0)
    assert np.count_nonzero(beyond) == 20 * 45
    np.testing.assert_array_equal(ranges[beyond], written[beyond])
    assert not np.any(ranges[written == 50.0])
    assert [s.range_max_m for s in log.scans] == [50.0] * 20
    assert log.sensor["range_max_m"] == "50.0"
    assert log.sensor["range_max_from"] == (
        "for 20 scans whose range_max (10 m) returns lie beyond, inferred: 50 m, the largest "
        "reading that repeats, is 40 % of the readings from 10 m on"
    )
    assert log.warnings[1:] == [
        f"{path.name}: the range_max of 20 scans (10 m) is not the scanner's range limit: it "
        "would have dropped 900 readings (24.9 % of the readings) that are returns, from 10 m "
        "up to 49.895 m; the limit used is 50 m, the no-return value the readings repeat "
        "(--range-max-m sets one)"
    ]
    # A limit given keeps its word, and needs no warning.
    given = read_rosbag(path, odom_topic=None, range_max_m=10.0)
    assert not np.any(np.concatenate([s.ranges_m for s in given.scans])[beyond])
    assert given.sensor["range_max_from"] == "given"
    assert given.warnings == log.warnings[:1]


def test_import_says_so_in_one_line_and_info_where_the_limit_came_from(capsys, tmp_path):
    path = far_returns_bag(tmp_path, "ros1")
    out = tmp_path / "log.mcap"
    done = run_cli(capsys, "import", "rosbag", path, "--out", out, "--odom-topic", "")
    assert done.code == 0, done.err
    said = [line for line in done.err.splitlines() if "range limit" in line]
    assert said == [
        "segloc: warning: test.bag: the range_max of 20 scans (10 m) is not the scanner's range "
        "limit: it would have dropped 900 readings (24.9 % of the readings) that are returns, "
        "from 10 m up to 49.895 m; the limit used is 50 m, the no-return value the readings "
        "repeat (--range-max-m sets one)"
    ]
    assert np.count_nonzero(np.concatenate([s.valid for s in read_log(out).scans])) == 20 * 151
    shown = run_cli(capsys, "info", out).out.splitlines()
    assert "sensor.range_max_m: 50.0" in shown
    assert (
        "sensor.range_max_from: for 20 scans whose range_max (10 m) returns lie beyond, "
        "inferred: 50 m, the largest reading that repeats, is 40 % of the readings from 10 m on"
    ) in shown

    given = tmp_path / "given.mcap"
    args = ["import", "rosbag", path, "--out", given, "--odom-topic", "", "--range-max-m", "10"]
    done = run_cli(capsys, *args)
    assert done.code == 0, done.err
    assert "range limit" not in done.err
    assert np.count_nonzero(np.concatenate([s.valid for s in read_log(given).scans])) == 20 * 106
    assert "sensor.range_max_from: given" in run_cli(capsys, "info", given).out.splitlines()


# --- --survey-out: the odometry as a trajectory ----------------------------------------

# The scans by stamp that lie inside the odometry's span, and their numbers in bag order.
ODOM_SCAN_NUMBERS = [WRITTEN_ORDER[k] + 1 for k in range(1, 5)]


@pytest.mark.parametrize("name", ["odom.csv", "odom.tum"])
def test_survey_out_writes_the_odometry_and_reads_back_as_it(capsys, tmp_path, name):
    from segloc_cli.io.tables import read_pose_table

    path = write_bag("ros1", tmp_path, TOPICS, standard_messages("ros1"))
    out, survey = tmp_path / "log.mcap", tmp_path / name
    done = run_cli(capsys, "import", "rosbag", path, "--out", out, "--survey-out", survey)
    assert done.code == 0, done.err
    assert done.err.splitlines()[-1] == f"segloc: {survey}: 4 odometry poses"

    table, log = read_pose_table(survey), read_log(out)
    np.testing.assert_array_equal(table.time_s, EXPECTED_ODOM_TIMES_S)
    np.testing.assert_array_equal(table.time_s, log.odom_times_s)
    # Positions to 1 µm and headings to 1e-6° (CSV), or through a quaternion (TUM).
    np.testing.assert_allclose(table.poses[:, :2], EXPECTED_ODOM_POSES[:, :2], rtol=0, atol=1e-6)
    np.testing.assert_allclose(table.poses[:, :2], log.odom_poses[:, :2], rtol=0, atol=1e-6)
    heading_error = (table.poses[:, 2] - EXPECTED_ODOM_POSES[:, 2] + np.pi) % (2 * np.pi) - np.pi
    np.testing.assert_allclose(heading_error, 0.0, rtol=0, atol=2e-8)
    if name.endswith(".csv"):
        # Each row is the pose id of the scan its odometry was looked up at.
        assert table.pose_id.tolist() == ODOM_SCAN_NUMBERS
        header = survey.read_text().splitlines()[0]
        assert header == "pose_id,time_s,x_m,y_m,theta_deg,original_time_s"


def test_survey_out_without_odometry_is_one_line(capsys, tmp_path):
    scans_only = [m for m in standard_messages("ros1") if m[0] == "/scan"]
    survey, out = tmp_path / "odom.csv", tmp_path / "log.mcap"
    base = ["import", "rosbag", "--out", out, "--survey-out", survey]

    no_topic = write_bag("ros1", tmp_path, {"/scan": SCAN_TYPE}, scans_only)
    assert_one_line_error(run_cli(capsys, *base, no_topic), "test.bag", "no topic /odom")
    not_read = run_cli(capsys, *base, no_topic, "--odom-topic", "")
    assert_one_line_error(not_read, "--survey-out", "--odom-topic ''")
    (tmp_path / "test.bag").unlink()
    empty_topic = write_bag("ros1", tmp_path, TOPICS, scans_only)
    assert_one_line_error(
        run_cli(capsys, *base, empty_topic), "test.bag", "no scan has an odometry pose from /odom"
    )
    assert not out.exists() and not survey.exists()


def test_survey_out_refuses_an_existing_file_without_force(capsys, tmp_path):
    path = write_bag("ros1", tmp_path, TOPICS, standard_messages("ros1"))
    survey, out = tmp_path / "odom.csv", tmp_path / "log.mcap"
    survey.write_text("precious\n", encoding="utf-8")
    result = run_cli(capsys, "import", "rosbag", path, "--out", out, "--survey-out", survey)
    assert_one_line_error(result, str(survey), "--survey-out", "--force")
    assert survey.read_text(encoding="utf-8") == "precious\n"
    assert not out.exists()
    forced = ["import", "rosbag", path, "--out", out, "--survey-out", survey, "--force"]
    assert run_cli(capsys, *forced).code == 0
    assert survey.read_text(encoding="utf-8").startswith("pose_id,")


# --- bad messages ----------------------------------------------------------------------


def test_undecodable_messages_are_skipped_and_counted(kind, tmp_path):
    messages = standard_messages(kind)
    scan_bytes = messages[0][2]
    record_ns = EPOCH_S * 1_000_000_000
    messages += [
        ("/scan", record_ns + 400_000_000, scan_bytes[:-3]),  # truncated
        ("/scan", record_ns + 400_000_001, scan_bytes + b"\x00" * 16),  # trailing bytes
        ("/odom", record_ns + 400_000_002, b"\x01\x02"),
    ]
    messages.sort(key=lambda m: m[1])
    path = write_bag(kind, tmp_path, TOPICS, messages)

    log = read_rosbag(path)

    assert [scan.time_s for scan in log.scans] == SCAN_TIMES_S
    assert log.odom_times_s.tolist() == EXPECTED_ODOM_TIMES_S
    np.testing.assert_allclose(log.odom_poses, EXPECTED_ODOM_POSES, rtol=0, atol=1e-12)
    assert len(log.warnings) == 4
    assert log.warnings[0].startswith(
        f"{path.name}: skipped 2 messages on /scan that could not be decoded (first: "
    )
    assert log.warnings[1].startswith(
        f"{path.name}: skipped 1 message on /odom that could not be decoded (first: "
    )
    assert log.warnings[2] == no_mounting(path.name)
    assert log.warnings[3] == (
        f"{path.name}: 2 of 6 scans lie outside the time span of /odom and have no odometry"
    )


def test_only_undecodable_scans_is_an_error(tmp_path):
    messages = [("/scan", 1, b"\x00" * 5), ("/odom", 2, standard_messages("ros1")[-1][2])]
    path = write_bag("ros1", tmp_path, TOPICS, messages)

    with pytest.raises(InputError) as info:
        read_rosbag(path)
    assert str(info.value) == f"{path}: topic /scan holds no laser scans; 1 could not be decoded"


def test_damaged_bag_is_an_error(tmp_path):
    path = write_bag("ros2-mcap", tmp_path, TOPICS, standard_messages("ros2-mcap"))
    data = bytearray(path.read_bytes())
    # The message record holding the fourth scan: opcode, length (u64), channel id (u16),
    # sequence (u32), log and publish time (u64 each), then the message. A length far
    # past the end of its chunk cannot be read.
    fourth = standard_messages("ros2-mcap")[3][2]
    at = data.find(fourth) - 22 - 8
    assert at > 0
    data[at : at + 8] = (2**40).to_bytes(8, "little")
    path.write_bytes(bytes(data))

    with pytest.raises(InputError, match=r"the bag is damaged \(") as info:
        read_rosbag(path)
    assert str(info.value).startswith(f"{path}: ")


# --- bad input --------------------------------------------------------------------------


def test_missing_path(tmp_path):
    path = tmp_path / "nothing.bag"
    with pytest.raises(InputError) as info:
        read_rosbag(path)
    assert str(info.value) == f"{path}: file or folder not found; check the path"


EXPECTED_BAG = "a ROS 1 .bag file, a ROS 2 bag folder with metadata.yaml, or a ROS 2 .mcap file"


@pytest.mark.parametrize("name", ["notes.bag", "notes.mcap", "notes.txt"])
def test_not_a_bag(tmp_path, name):
    path = tmp_path / name
    path.write_text("this is not a bag\n")
    with pytest.raises(InputError) as info:
        read_rosbag(path)
    message = str(info.value)
    assert message.startswith(f"{path}: not a readable ROS bag (")
    assert message.endswith(f"); expected {EXPECTED_BAG}")


def test_folder_without_metadata_is_not_a_bag(tmp_path):
    with pytest.raises(InputError) as info:
        read_rosbag(tmp_path)
    assert str(info.value) == f"{tmp_path}: folder has no metadata.yaml; expected {EXPECTED_BAG}"


def test_segloc_mcap_log_is_not_a_ros_bag(bag, tmp_path):
    out = tmp_path / "log.mcap"
    write_log(out, read_rosbag(bag).scans)
    with pytest.raises(InputError) as info:
        read_rosbag(out)
    assert str(info.value).startswith(f"{out}: not a readable ROS bag (")


def test_missing_scan_topic(bag):
    with pytest.raises(InputError) as info:
        read_rosbag(bag, scan_topic="/laser")
    assert str(info.value) == (
        f"{bag}: no topic /laser in the bag; topics found: "
        "/odom (nav_msgs/msg/Odometry), /scan (sensor_msgs/msg/LaserScan)"
    )


def test_missing_odometry_topic(bag):
    with pytest.raises(InputError) as info:
        read_rosbag(bag, odom_topic="/wheel_odom")
    assert str(info.value) == (
        f"{bag}: no topic /wheel_odom in the bag; topics found: "
        "/odom (nav_msgs/msg/Odometry), /scan (sensor_msgs/msg/LaserScan)"
    )


def test_topics_of_the_wrong_type(bag):
    with pytest.raises(InputError) as info:
        read_rosbag(bag, scan_topic="/odom")
    assert str(info.value) == (
        f"{bag}: topic /odom has type nav_msgs/msg/Odometry; expected sensor_msgs/msg/LaserScan"
    )
    with pytest.raises(InputError) as info:
        read_rosbag(bag, odom_topic="/scan")
    assert str(info.value) == (
        f"{bag}: topic /scan has type sensor_msgs/msg/LaserScan; expected nav_msgs/msg/Odometry"
    )


def test_scan_topic_without_messages(kind, tmp_path):
    odom_only = [m for m in standard_messages(kind) if m[0] == "/odom"]
    path = write_bag(kind, tmp_path, TOPICS, odom_only)
    with pytest.raises(InputError) as info:
        read_rosbag(path)
    assert str(info.value) == f"{path}: topic /scan holds no laser scans"


def test_empty_bag_lists_no_topics(tmp_path):
    path = write_bag("ros1", tmp_path, {}, [])
    with pytest.raises(InputError) as info:
        read_rosbag(path)
    assert str(info.value) == f"{path}: no topic /scan in the bag; topics found: none"


def test_odometry_topic_without_messages_is_a_warning(tmp_path):
    scans_only = [m for m in standard_messages("ros1") if m[0] == "/scan"]
    path = write_bag("ros1", tmp_path, TOPICS, scans_only)
    log = read_rosbag(path)
    assert len(log.scans) == 6
    assert log.odom_poses.shape == (0, 3)
    assert log.warnings == [
        no_mounting("test.bag", robot=None),
        "test.bag: topic /odom holds no odometry; none imported",
    ]


# --- colliding stamps --------------------------------------------------------------------


def test_colliding_stamps_get_distinct_times_and_odometry_at_the_real_stamp(kind, tmp_path):
    store = store_of(kind)
    record_ns = EPOCH_S * 1_000_000_000
    # Three scans stamped alike (a driver with a coarse clock), then one 0.3 s later; the
    # odometry runs from x = 0 at the common stamp to x = 3 at 0.3 s.
    messages = [scan_record(store, record_ns + k, 0, scan_ranges(k)) for k in range(3)]
    messages += [
        scan_record(store, record_ns + 3, 300_000_000, scan_ranges(3)),
        odom_record(store, record_ns + 4, 0, Pose2(0.0, 0.0, 0.0)),
        odom_record(store, record_ns + 5, 300_000_000, Pose2(3.0, 0.0, 0.0)),
    ]
    path = write_bag(kind, tmp_path, TOPICS, messages)
    log = read_rosbag(path)

    start = float(EPOCH_S)
    assert [s.time_s for s in log.scans] == [start, start + 0.1, start + 0.2, start + 0.3]
    assert log.original_times_s.tolist() == [start, start, start, start + 0.3]
    # Equal stamps stay in bag order.
    for k, scan in enumerate(log.scans):
        np.testing.assert_array_equal(scan.ranges_m, expected_ranges(k))
    # The odometry is filed under the distinct times but taken at the real stamps: the three
    # scans stamped alike all get the pose at that stamp, not one further along.
    assert log.odom_times_s.tolist() == [s.time_s for s in log.scans]
    np.testing.assert_allclose(
        log.odom_poses, [[0, 0, 0], [0, 0, 0], [0, 0, 0], [3, 0, 0]], rtol=0, atol=1e-12
    )
    assert log.warnings == [
        no_mounting(path.name),
        f"{path.name}: 3 of 4 scans share their time with another or go back in time; "
        "gave them distinct times in stamp and bag order (see README: colliding times)",
    ]


def test_scans_stamped_before_1970_are_skipped(tmp_path):
    store = ROS2_STORE
    early = laser_scan(store, 0, scan_ranges(0))
    early.header.stamp.sec = -5
    messages = [
        ("/scan", 1, serialize(store, early, SCAN_TYPE)),
        scan_record(store, 2, 0, scan_ranges(1)),
    ]
    path = write_bag("ros2-folder", tmp_path, TOPICS, messages)
    log = read_rosbag(path, odom_topic=None)
    assert [s.time_s for s in log.scans] == [float(EPOCH_S)]
    np.testing.assert_array_equal(log.scans[0].ranges_m, expected_ranges(1))
    assert log.warnings == [
        "test_bag: skipped 1 scan on /scan stamped before 1970 (negative header.stamp)",
        no_mounting("test_bag", robot=None),
    ]

    only = write_bag("ros2-folder", tmp_path / "only", TOPICS, messages[:1])
    with pytest.raises(InputError) as info:
        read_rosbag(only, odom_topic=None)
    assert str(info.value) == (
        f"{only}: topic /scan holds no usable laser scans; "
        "skipped 1 scan on /scan stamped before 1970 (negative header.stamp)"
    )


def test_scans_with_unusable_fans_or_too_many_readings_are_skipped(tmp_path):
    store = ROS1_STORE
    bad_fan = laser_scan(store, 0, scan_ranges(0))
    bad_fan.angle_increment = float("nan")
    one_ray = laser_scan(store, 10_000_000, scan_ranges(1))
    one_ray.angle_increment = 0.0
    messages = [
        ("/scan", 1, serialize(store, bad_fan, SCAN_TYPE)),
        ("/scan", 2, serialize(store, one_ray, SCAN_TYPE)),
        scan_record(store, 3, 20_000_000, np.ones(100_001, dtype=np.float32)),
        scan_record(store, 4, 30_000_000, scan_ranges(3)),
    ]
    path = write_bag("ros1", tmp_path, TOPICS, messages)
    log = read_rosbag(path, odom_topic=None)
    assert [s.time_s for s in log.scans] == [EPOCH_S + 0.03]
    np.testing.assert_array_equal(log.scans[0].ranges_m, expected_ranges(3))
    assert log.warnings == [
        "test.bag: skipped 2 scans on /scan with an unusable beam fan "
        "(first: non-finite fan angles (-1.5707963705062866 to nan rad))",
        "test.bag: skipped 1 scan on /scan with more than 100,000 readings",
        no_mounting("test.bag", robot=None),
    ]


# --- a ROS 1 bag cut short ----------------------------------------------------------------


def write_ros1_in_chunks(path: Path, compression: str | None) -> Path:
    """The standard messages as a ROS 1 bag of many small chunks (one or two messages each)."""
    writer = Ros1Writer(path)
    if compression is not None:
        writer.set_compression(Ros1Writer.CompressionFormat[compression])
    writer.chunk_threshold = 64
    with writer:
        connections = {
            topic: writer.add_connection(topic, msgtype, typestore=ROS1_STORE)
            for topic, msgtype in TOPICS.items()
        }
        for topic, record_ns, data in standard_messages("ros1"):
            writer.write(connections[topic], record_ns, data)
    return path


@pytest.mark.parametrize("compression", [None, "BZ2", "LZ4"])
def test_a_bag_cut_short_keeps_the_scans_of_its_whole_chunks(tmp_path, compression):
    path = write_ros1_in_chunks(tmp_path / "whole.bag", compression)
    whole = read_rosbag(path)
    data = path.read_bytes()
    stamps = [s.time_s for s in whole.scans]

    # Without its index (written last) the bag still has every chunk.
    no_index = tmp_path / "no-index.bag"
    no_index.write_bytes(data[: data.rfind(b"op=\x06") - 64])
    salvaged = read_rosbag(no_index)
    assert [s.time_s for s in salvaged.scans] == stamps
    np.testing.assert_array_equal(salvaged.odom_poses, whole.odom_poses)
    assert salvaged.warnings[0].startswith(
        "no-index.bag: the bag's index is missing or damaged (a recording cut short?); read its "
    )

    # Cut through the middle: the scans of the chunks before the cut, in order.
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: len(data) // 2])
    kept = read_rosbag(cut, odom_topic=None)
    assert 0 < len(kept.scans) < len(whole.scans)
    assert [s.time_s for s in kept.scans] == sorted(stamps[: len(kept.scans)])
    assert "cut off" in kept.warnings[0]


def test_a_cut_bag_without_a_whole_scan_is_still_refused(tmp_path):
    path = write_ros1_in_chunks(tmp_path / "whole.bag", None)
    cut = tmp_path / "cut.bag"
    cut.write_bytes(path.read_bytes()[:200])
    with pytest.raises(InputError, match=r"cut\.bag: not a readable ROS bag"):
        read_rosbag(cut)


@pytest.mark.parametrize("range_max", [float("nan"), 0.0, -1.0])
def test_range_limits_that_cannot_apply_keep_the_readings_with_a_warning(tmp_path, range_max):
    ranges = scan_ranges(0)
    messages = [scan_record(ROS1_STORE, 1, 0, ranges, range_max=range_max)]
    log = read_rosbag(write_bag("ros1", tmp_path, TOPICS, messages), odom_topic=None)
    (scan,) = log.scans
    kept = np.isfinite(ranges) & (ranges > 0)
    np.testing.assert_array_equal(scan.ranges_m[kept], decimal(ranges[kept]))
    assert scan.range_max_m == math.inf
    assert log.warnings == [
        no_mounting("test.bag", robot=None),
        f"test.bag: 1 scan gives range limits that cannot be applied (first: range_min "
        f"{RANGE_MIN!r}, range_max {float(decimal(range_max)[0])!r} m); "
        "their readings count up to 1000 m",
    ]


@pytest.mark.parametrize(
    ("fields", "why"),
    [
        (
            {"range_max": RANGE_MIN / 2},
            "whose range_max is below their range_min (first: range_min 0.1 m, range_max 0.05 m)",
        ),
        (
            {"angle_max": ANGLE_MAX + 3 * ANGLE_INCREMENT},
            "whose angle_increment disagrees with their ranges (first: angle_min -1.5708 to "
            "angle_max 1.62316 rad at 0.0174533 rad spans 184 beams, not 181)",
        ),
    ],
)
def test_scans_whose_geometry_contradicts_itself_are_skipped_and_counted(tmp_path, fields, why):
    messages = [
        scan_record(ROS1_STORE, 1, 0, scan_ranges(0)),
        scan_record(ROS1_STORE, 2, 100_000_000, scan_ranges(1), **fields),
    ]
    log = read_rosbag(write_bag("ros1", tmp_path, TOPICS, messages), odom_topic=None)
    assert len(log.scans) == 1
    assert f"test.bag: skipped 1 scan on /scan {why}" in log.warnings


def test_odometry_that_is_not_a_pose_is_skipped_and_counted(tmp_path):
    good = [odom_record(ROS1_STORE, 10 + k, k * 100_000_000, Pose2(k, 0.0, 0.0)) for k in range(3)]
    bad = odom_record(ROS1_STORE, 5, 50_000_000, Pose2(float("nan"), 0.0, 0.0))
    scans = [scan_record(ROS1_STORE, 20 + k, k * 100_000_000, scan_ranges(k)) for k in range(3)]
    log = read_rosbag(
        write_bag("ros1", tmp_path, TOPICS, sorted([*good, bad, *scans], key=lambda m: m[1]))
    )
    np.testing.assert_allclose(log.odom_poses[:, 0], [0.0, 1.0, 2.0])
    assert log.warnings == [
        "test.bag: skipped 1 message on /odom that could not be decoded (first: the pose is "
        "not finite)",
        no_mounting("test.bag"),
    ]


@settings(max_examples=200, deadline=None)
@given(bits=st.lists(st.integers(0, 2**32 - 1), min_size=1, max_size=50))
def test_shortest_decimals_read_back_as_the_same_float32(bits):
    """Every float32 bit pattern, NaN and infinities included, survives: the decimal widened
    back to float32 is the value given (NaN stays NaN)."""
    values = np.array(bits, dtype=np.uint32).view(np.float32)
    back = shortest_decimals(values).astype(np.float32)
    assert np.array_equal(back, values, equal_nan=True)
    finite = np.isfinite(values)
    assert np.array_equal(np.signbit(back[finite]), np.signbit(values[finite]))


INTEL_BAG = Path(__file__).resolve().parents[2] / "shared" / "datasets" / "intel" / "intel.orig.bag"


@pytest.mark.skipif(not INTEL_BAG.is_file(), reason="the shared intel bag is not beside the repo")
def test_the_imported_intel_bag_is_compact_and_indexed(tmp_path):
    """The public Intel Research Lab bag (3.9 MB, bz2) becomes a log of at most 1.5 times its
    size, zstd chunks listed in the summary, with every scan of the bag."""
    out = tmp_path / "intel.mcap"
    done = run_in_process("import", "rosbag", INTEL_BAG, "--out", out)
    assert done.code == 0, done.err
    assert out.stat().st_size <= 1.5 * INTEL_BAG.stat().st_size
    with open(out, "rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary.chunk_indexes and {c.compression for c in summary.chunk_indexes} == {"zstd"}
    assert summary.statistics.channel_message_counts[_channel(summary, "/scan")] == 13631


def _channel(summary, topic: str) -> int:
    return next(k for k, channel in summary.channels.items() if channel.topic == topic)


@pytest.mark.parametrize("kind", FORMATS)
def test_a_bag_where_a_log_is_expected_names_the_import(tmp_path, capsys, kind):
    """A ROS bag of any kind given to info or localize is one line that names the import
    to run (exit 2), not a reading error."""
    store = ROS1_STORE if kind == "ros1" else ROS2_STORE
    path = write_bag(kind, tmp_path, TOPICS, [scan_record(store, 1, 0, scan_ranges(0))])
    (tmp_path / "map.json").write_bytes((HALL / "map.json").read_bytes())
    for args in (["info", path], ["localize", path, "--map", tmp_path / "map.json",
                                  "--out", tmp_path / "est.csv"]):  # fmt: skip
        result = run_cli(capsys, *args)
        assert result.code == 2
        (line,) = result.err.splitlines()
        # The command named runs as it stands: --out is required, and names a log beside the
        # bag that is not the bag itself.
        out = tmp_path / {"ros1": "test.mcap", "ros2-folder": "test_bag.mcap",
                          "ros2-mcap": "test-segloc.mcap"}[kind]  # fmt: skip
        assert line.endswith(f"convert it first with `segloc import rosbag {path} --out {out}`")


@pytest.mark.parametrize("inside", ["database", "metadata"])
def test_a_file_inside_a_ros2_bag_names_the_bag_folder(tmp_path, capsys, inside):
    """A ROS 2 bag's .db3 or metadata.yaml, given where a bag is read (evaluate's EST, import
    rosbag's LOG), says to give the bag folder; given where a log is read (info, localize,
    map build), to convert the bag folder."""
    messages = [scan_record(ROS2_STORE, 1, 0, scan_ranges(0))]
    folder = write_bag("ros2-folder", tmp_path, TOPICS, messages)
    (database,) = folder.glob("*.db3")
    path = database if inside == "database" else folder / "metadata.yaml"
    survey, out = HALL / "survey.csv", tmp_path / "out"
    out.mkdir()
    give = (
        f"segloc: error: {path}: a file inside a ROS 2 bag; give the bag folder {folder} "
        "(the folder holding metadata.yaml)"
    )
    for args in (
        ["evaluate", path, "--survey", survey],
        ["evaluate", path, "--est-format", "ros2", "--topic", "/amcl_pose", "--survey", survey],
        ["import", "rosbag", path, "--out", out / "log.mcap"],
    ):
        assert assert_one_line_error(run_cli(capsys, *args)) == give
    convert = (
        f"segloc: error: {path}: a file inside a ROS 2 bag, not a segloc log; convert the bag "
        f"folder first with `segloc import rosbag {folder} --out {tmp_path / 'test_bag.mcap'}`"
    )
    for args in (
        ["info", path],
        ["localize", path, "--map", HALL / "map.json", "--out", out / "est.csv"],
        ["map", "build", path, "--survey", survey, "--out", out / "map.json"],
    ):
        assert assert_one_line_error(run_cli(capsys, *args)) == convert
    assert not list(out.iterdir()), "nothing is written"


# --- the scanner's mounting: /tf_static, /tf and --laser-offset ---------------------------

TF_TYPE = "tf2_msgs/msg/TFMessage"
TF_TOPICS = {**TOPICS, "/tf_static": TF_TYPE, "/tf": TF_TYPE}


def quaternion(roll: float = 0.0, pitch: float = 0.0, yaw: float = 0.0) -> tuple:
    """The rotation ``yaw`` about z after ``pitch`` about y after ``roll`` about x (rad), as a
    quaternion x y z w (ROS's fixed-axis roll, pitch, yaw)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )


def tf_record(store: Typestore, topic: str, record_ns: int, links: list) -> tuple:
    """A TFMessage for ``write_bag`` holding ``links``: (parent, child, (x, y, z) m,
    quaternion x y z w), each the child's pose in its parent."""
    t = store.types
    stamped = [
        t["geometry_msgs/msg/TransformStamped"](
            header=header(store, 0, parent),
            child_frame_id=child,
            transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=xyz[0], y=xyz[1], z=xyz[2]),
                rotation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
            ),
        )
        for parent, child, xyz, q in links
    ]
    return (topic, record_ns, serialize(store, t[TF_TYPE](transforms=stamped), TF_TYPE))


def mounted_bag(kind: str, where: Path, static: list, moving: list = (), child="base_link"):
    """The standard scans and odometry (child frame ``child``) with ``static`` links on
    /tf_static (one message) and each entry of ``moving`` (a list of links) as a /tf message."""
    store = store_of(kind)
    record_ns = EPOCH_S * 1_000_000_000
    messages = [m for m in standard_messages(kind) if m[0] == "/scan"]
    messages += [
        odom_record(store, record_ns + 1_000_000 * k + 500_000, stamp, pose, child)
        for k, (stamp, pose) in enumerate(ODOM)
    ]
    messages.append(tf_record(store, "/tf_static", record_ns - 1, static))
    messages += [
        tf_record(store, "/tf", record_ns + 1_000_000 * k + 700_000, links)
        for k, links in enumerate(moving)
    ]
    return write_bag(kind, where, TF_TOPICS, sorted(messages, key=lambda m: m[1]))


# base_link → laser_mount → laser: two links with a yaw each, heights that the floor plane
# drops, and a camera beside them in the tree.
MOUNT_LINK = ("base_link", "laser_mount", (0.2, 0.05, 0.3), quaternion(yaw=math.radians(30)))
LASER_LINK = ("laser_mount", "laser", (0.02, -0.01, 0.05), quaternion(yaw=math.radians(15)))
CAMERA_LINK = ("base_link", "camera", (0.1, 0.0, 1.2), quaternion(pitch=0.3))
EXPECTED_MOUNT = Pose2(0.2, 0.05, math.radians(30)).compose(Pose2(0.02, -0.01, math.radians(15)))
SOURCE = "tf_static:base_link->laser"


def beam_points_3d(scan, links: list) -> np.ndarray:
    """Where a scan's valid beams end in the robot frame, through the 3D chain of ``links``
    (parent first; each as ``tf_record`` takes it), projected onto the floor (K, 2)."""
    from segloc_cli.io.tf import transform_matrix

    chain = np.eye(4)
    for _, _, xyz, q in links:
        chain = chain @ transform_matrix(xyz, q)
    a, r = scan.angles_rad[scan.valid], scan.ranges_m[scan.valid]
    beams = np.column_stack([r * np.cos(a), r * np.sin(a), np.zeros_like(r), np.ones_like(r)])
    return (beams @ chain.T)[:, :2]


def test_a_two_link_chain_on_tf_static_composes_to_the_mounting(kind, tmp_path):
    path = mounted_bag(kind, tmp_path, [MOUNT_LINK, LASER_LINK, CAMERA_LINK])
    log = read_rosbag(path)

    offset = log.laser_offset
    assert offset.x == pytest.approx(EXPECTED_MOUNT.x, abs=1e-12)
    assert offset.y == pytest.approx(EXPECTED_MOUNT.y, abs=1e-12)
    assert offset.theta_deg == pytest.approx(45.0, abs=1e-9)
    assert (offset.x, offset.y) == pytest.approx((0.222320508, 0.051339746), abs=1e-9)
    assert log.sensor["laser_offset_source"] == SOURCE
    assert log.sensor["laser_x_m"] == repr(offset.x)
    assert all(scan.mount == offset for scan in log.scans)
    assert not any("laser" in w for w in log.warnings)
    # The scan's points are where its beams end on the robot, through the 3D chain.
    first = log.scans[0]
    np.testing.assert_allclose(
        first.points(), beam_points_3d(first, [MOUNT_LINK, LASER_LINK]), rtol=0, atol=1e-12
    )


def test_the_robot_frame_is_the_odometry_s_child_even_beside_the_scanner(tmp_path):
    """base_footprint holds base_link and the laser side by side: the chain runs up from
    base_link and down to the laser."""
    links = [
        ("base_footprint", "base_link", (0.1, 0.0, 0.2), quaternion(yaw=math.radians(90))),
        ("base_footprint", "laser", (0.3, 0.1, 0.4), quaternion(yaw=math.radians(-30))),
    ]
    log = read_rosbag(mounted_bag("ros1", tmp_path, links))
    expected = (
        Pose2(0.1, 0.0, math.radians(90)).inverse().compose(Pose2(0.3, 0.1, math.radians(-30)))
    )
    assert log.laser_offset.x == pytest.approx(expected.x, abs=1e-12)
    assert log.laser_offset.y == pytest.approx(expected.y, abs=1e-12)
    assert log.laser_offset.theta == pytest.approx(expected.theta, abs=1e-12)
    assert log.laser_offset_source == SOURCE


def test_without_odometry_the_top_of_the_scanner_s_tree_is_the_robot(tmp_path):
    links = [("base_footprint", "base_link", (0.0, 0.0, 0.1), (0, 0, 0, 1)), MOUNT_LINK, LASER_LINK]
    log = read_rosbag(mounted_bag("ros2-folder", tmp_path, links), odom_topic=None)
    assert log.laser_offset_source == "tf_static:base_footprint->laser"
    assert log.laser_offset.x == pytest.approx(EXPECTED_MOUNT.x, abs=1e-12)
    assert log.laser_offset.theta_deg == pytest.approx(45.0, abs=1e-9)


def test_a_mounting_published_unchanged_on_tf_counts_and_motion_does_not(tmp_path):
    moving = [
        [("odom", "base_link", (0.1 * k, 0.0, 0.0), (0, 0, 0, 1)), MOUNT_LINK, LASER_LINK]
        for k in range(3)
    ]
    log = read_rosbag(mounted_bag("ros1", tmp_path, [CAMERA_LINK], moving))
    assert log.laser_offset_source == "tf:base_link->laser"
    assert log.laser_offset.theta_deg == pytest.approx(45.0, abs=1e-9)

    # A laser link that moves (a panning scanner) is no mounting.
    panning = [[MOUNT_LINK, (*LASER_LINK[:3], quaternion(yaw=0.1 * k))] for k in range(3)]
    (tmp_path / "pan").mkdir()
    log = read_rosbag(mounted_bag("ros1", tmp_path / "pan", [CAMERA_LINK], panning))
    assert log.laser_offset == Pose2(0.0, 0.0, 0.0)
    assert log.laser_offset_source == "none"
    assert no_mounting("test.bag") in log.warnings


def test_laser_offset_overrides_the_bag(tmp_path):
    path = mounted_bag("ros1", tmp_path, [MOUNT_LINK, LASER_LINK])
    log = read_rosbag(path, laser_offset=(0.1, -0.2, 90.0))
    assert log.laser_offset == Pose2(0.1, -0.2, math.pi / 2)
    assert log.sensor["laser_theta_deg"] == "90.0"
    assert log.laser_offset_source == "--laser-offset"
    assert all(scan.mount == log.laser_offset for scan in log.scans)


def test_an_upside_down_scanner_is_mirrored_into_an_upright_scan(tmp_path):
    flipped = ("base_link", "laser", (0.15, 0.0, 0.2), quaternion(roll=math.pi, yaw=0.4))
    path = mounted_bag("ros2-mcap", tmp_path, [flipped])
    log = read_rosbag(path)
    as_recorded = read_rosbag(path, laser_offset=(0.0, 0.0, 0.0)).scans[0]

    assert log.sensor["laser_upside_down"] == "yes"
    assert log.laser_offset.theta == pytest.approx(0.4, abs=1e-12)
    assert (
        f"test.mcap: the scanner (laser) is mounted upside down ({SOURCE}); its beams are "
        "mirrored into an upright scan"
    ) in log.warnings
    first = log.scans[0]
    assert np.all(np.diff(first.angles_rad) > 0)  # counter-clockwise still
    np.testing.assert_array_equal(first.ranges_m, as_recorded.ranges_m[::-1])
    # The beams end where the 3D mounting puts them, in reversed order.
    np.testing.assert_allclose(
        first.points(), beam_points_3d(as_recorded, [flipped])[::-1], rtol=0, atol=1e-12
    )


def test_a_tilted_scanner_is_read_as_level_with_a_warning_and_a_vertical_one_refused(tmp_path):
    tilted = ("base_link", "laser", (0.2, 0.0, 0.3), quaternion(pitch=math.radians(10)))
    log = read_rosbag(mounted_bag("ros1", tmp_path, [tilted]))
    assert log.laser_offset.x == pytest.approx(0.2, abs=1e-12)
    assert log.laser_offset.theta == pytest.approx(0.0, abs=1e-12)
    assert (
        f"test.bag: the scanner (laser) is tilted 10.0° from the floor plane of base_link "
        f"({SOURCE}); its scans are taken as level"
    ) in log.warnings

    vertical = ("base_link", "laser", (0.2, 0.0, 0.3), quaternion(pitch=math.radians(90)))
    (tmp_path / "vertical").mkdir()
    path = mounted_bag("ros1", tmp_path / "vertical", [vertical])
    with pytest.raises(InputError) as info:
        read_rosbag(path)
    assert str(info.value) == (
        f"{path}: the scanner (laser) is tilted 90.0° from the floor plane ({SOURCE}): it does "
        "not scan a floor plan; --laser-offset X,Y,THETA_DEG imports its scans as level"
    )
    assert read_rosbag(path, laser_offset=(0.2, 0.0, 0.0)).laser_offset.x == 0.2


def test_import_and_info_say_the_offset_and_keep_it_through_the_log(capsys, tmp_path):
    from segloc_cli.io.mcap_log import read_log

    path = mounted_bag("ros1", tmp_path, [MOUNT_LINK, LASER_LINK])
    out = tmp_path / "log.mcap"
    done = run_cli(capsys, "import", "rosbag", path, "--out", out)
    assert done.code == 0, done.err
    line = "laser offset: x 0.222321 m, y 0.0513397 m, theta 45° (robot frame; from "
    assert f"segloc: {line}{SOURCE})" in done.err.splitlines()
    in_memory, back = read_rosbag(path), read_log(out)
    assert back.laser_offset == in_memory.laser_offset  # the round trip keeps every bit
    assert back.scans[0].mount == in_memory.laser_offset
    assert {k: v for k, v in back.sensor.items() if k.startswith("laser")} == {
        k: v for k, v in in_memory.sensor.items() if k.startswith("laser")
    }
    shown = run_cli(capsys, "info", out)
    assert f"{line}{SOURCE})" in shown.out.splitlines()

    given = tmp_path / "given.mcap"
    done = run_cli(capsys, "import", "rosbag", path, "--out", given, "--laser-offset", "0.3,0,-90")
    assert done.code == 0, done.err
    assert read_log(given).laser_offset == Pose2(0.3, 0.0, -math.pi / 2)
    shown = run_cli(capsys, "info", given)
    assert "laser offset: x 0.3 m, y 0 m, theta -90° (robot frame; from --laser-offset)" in (
        shown.out.splitlines()
    )


def test_a_bag_without_a_mounting_says_so_in_one_line(capsys, tmp_path):
    path = write_bag("ros1", tmp_path, TOPICS, standard_messages("ros1"))
    out = tmp_path / "log.mcap"
    done = run_cli(capsys, "import", "rosbag", path, "--out", out)
    assert done.code == 0, done.err
    offset_lines = [line for line in done.err.splitlines() if "origin" in line]
    assert offset_lines == [f"segloc: warning: {no_mounting('test.bag')}"]
    shown = run_cli(capsys, "info", out)
    assert "laser offset: none (the scanner is taken to be at the robot's origin)" in (
        shown.out.splitlines()
    )


@pytest.mark.parametrize("value", ["0.2,0", "a,b,c", "0,0,nan", "11,0,0", "0.1,0.2,0.3,4"])
def test_a_bad_laser_offset_is_one_line(capsys, tmp_path, value):
    path = write_bag("ros1", tmp_path, TOPICS, standard_messages("ros1"))
    result = run_cli(
        capsys, "import", "rosbag", path, "--out", tmp_path / "o.mcap", "--laser-offset", value
    )
    assert_one_line_error(result, "--laser-offset", repr(value), "X_M,Y_M,THETA_DEG")
    assert not (tmp_path / "o.mcap").exists()


# --- localizing an off-centre scanner's bag: the robot's pose --------------------------------

HALL_MOUNT = Pose2(0.22, 0.06, math.radians(12.0))
"""A scanner 0.22 m ahead of base_link and 6 cm to its left, turned 12° (as two links)."""
HALL_LINKS = [
    ("base_link", "laser_mount", (0.22, 0.06, 0.35), quaternion(yaw=math.radians(20.0))),
    ("laser_mount", "laser", (0.0, 0.0, 0.05), quaternion(yaw=math.radians(-8.0))),
]
N_HALL_SCANS = 8


def hall_bag(where: Path, kind: str) -> tuple[Path, np.ndarray]:
    """A bag of simulated scans of the hall taken by the mounted scanner at random robot
    poses, odometry at the robot poses off by up to 0.5 m and 10°; and the true robot poses
    (S, 3)."""
    from segloc_cli.io.maps import read_world
    from segloc_cli.sim import (
        SensorModel,
        initial_guesses,
        random_free_poses,
        simulate_scan,
        uniform_initial_errors,
    )

    store = store_of(kind)
    rng = np.random.default_rng(2000)
    world = read_world(HALL / "world.json")
    truth = random_free_poses(world, N_HALL_SCANS, rng)
    guesses = initial_guesses(truth, uniform_initial_errors(N_HALL_SCANS, 0.5, 10.0, rng))
    sensor = SensorModel(readings=1024)
    step = 2 * math.pi / sensor.readings
    messages = [tf_record(store, "/tf_static", 1, HALL_LINKS)]
    for k, (pose, guess) in enumerate(zip(truth, guesses, strict=True)):
        scanner = Pose2(*pose).compose(HALL_MOUNT)
        scan = simulate_scan(world, scanner, sensor, rng, 0.0)
        ranges = np.where(scan.valid, scan.ranges_m, np.inf).astype(np.float32)
        message = laser_scan(store, k * 200_000_000, ranges, range_max=sensor.range_max_m)
        message.angle_min, message.angle_increment = 0.0, step
        message.angle_max = step * (sensor.readings - 1)
        messages.append(("/scan", 10 + 2 * k, serialize(store, message, SCAN_TYPE)))
        messages.append(odom_record(store, 11 + 2 * k, k * 200_000_000, Pose2(*guess)))
    return write_bag(kind, where, TF_TOPICS, messages), truth


def localized(capsys, tmp_path: Path, bag: Path, *options: str) -> np.ndarray:
    """Import ``bag`` (with ``options``) and localize it on the hall's map: the estimates
    (S, 3) x m, y m, theta rad in scan order."""
    import pandas as pd

    log, out = tmp_path / "log.mcap", tmp_path / "est.csv"
    imported = run_cli(capsys, "import", "rosbag", bag, "--out", log, *options)
    assert imported.code == 0, imported.err
    done = run_cli(capsys, "localize", log, "--map", HALL / "map.json", "--out", out)
    assert done.code == 0, done.err
    rows = pd.read_csv(out)
    return np.column_stack([rows.x_m, rows.y_m, np.deg2rad(rows.theta_deg)])


def pose_errors(estimates: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position errors (S,) m and |heading errors| (S,) degrees."""
    from segloc_cli.geometry import wrap_angle

    position = np.hypot(*(estimates[:, :2] - truth[:, :2]).T)
    heading = np.abs(np.rad2deg(wrap_angle(estimates[:, 2] - truth[:, 2])))
    return position, heading


@pytest.mark.parametrize("kind", ["ros1", "ros2-mcap"])
def test_an_off_centre_scanner_localizes_the_robot(capsys, tmp_path, kind):
    """The bag's two-link mounting is found, kept through the log, and every estimate is
    the robot's pose within the simulated tests' 2 cm and 0.3°. Imported as if the scanner
    sat at the robot's origin, the same scans give the scanner's poses instead: off by the
    mounting, so the test tells the two apart."""
    from segloc_cli.io.mcap_log import read_log

    bag, truth = hall_bag(tmp_path, kind)
    (tmp_path / "with").mkdir()
    (tmp_path / "without").mkdir()

    estimates = localized(capsys, tmp_path / "with", bag)
    log = read_log(tmp_path / "with" / "log.mcap")
    assert log.laser_offset_source == SOURCE
    assert log.laser_offset.x == pytest.approx(HALL_MOUNT.x, abs=1e-12)
    assert log.laser_offset.y == pytest.approx(HALL_MOUNT.y, abs=1e-12)
    assert log.laser_offset.theta == pytest.approx(HALL_MOUNT.theta, abs=1e-12)
    position, heading = pose_errors(estimates, truth)
    assert position.max() < 0.02 and heading.max() < 0.3, (position, heading)

    unmounted = localized(capsys, tmp_path / "without", bag, "--laser-offset", "0,0,0")
    position, heading = pose_errors(unmounted, truth)
    assert position.min() > 0.2 and heading.min() > 11.0, (position, heading)
    scanner_poses = np.array([Pose2(*p).compose(HALL_MOUNT).as_array() for p in truth])
    position, heading = pose_errors(unmounted, scanner_poses)
    assert position.max() < 0.02 and heading.max() < 0.3, (position, heading)


def test_a_ros2_bag_folder_imports_and_its_run_file_hashes_the_folder(capsys, tmp_path):
    import tomllib

    path = write_bag("ros2-folder", tmp_path / "bag", TOPICS, standard_messages("ros2-folder"))
    assert path.is_dir()
    out = tmp_path / "log.mcap"
    done = run_cli(capsys, "import", "rosbag", path, "--out", out)
    assert done.code == 0, done.err
    run_file = tmp_path / "log.run.toml"

    def recorded() -> str:
        inputs = tomllib.loads(run_file.read_text(encoding="utf-8"))["run"]["inputs"]
        [bag] = [i for i in inputs if i["path"] == "bag" or i["path"].endswith("bag")]
        return bag["sha256"]

    before = recorded()
    with (path / "metadata.yaml").open("a", encoding="utf-8") as stream:
        stream.write("\n")  # a changed file in the folder must change the folder's hash
    done = run_cli(capsys, "import", "rosbag", path, "--out", out, "--force")
    assert done.code == 0, done.err
    assert recorded() != before


def test_a_transform_message_that_is_no_transform_is_skipped_and_counted(tmp_path):
    broken = ("base_link", "laser", (math.nan, 0.0, 0.0), quaternion())
    # The good chain comes on /tf (unchanging); a broken /tf_static message is skipped whole.
    path = mounted_bag("ros1", tmp_path, [broken], moving=[[MOUNT_LINK, LASER_LINK]] * 2)
    log = read_rosbag(path)
    assert log.warnings[0] == (
        "test.bag: skipped 1 message on /tf_static that could not be decoded (first: the "
        "transform is not finite (to laser))"
    )
    assert log.laser_offset_source == "tf:base_link->laser"
    assert abs(log.laser_offset.x - EXPECTED_MOUNT.x) < 1e-12
    zero = ("base_link", "laser", (0.1, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0))
    (tmp_path / "zero").mkdir()
    path = mounted_bag("ros1", tmp_path / "zero", [zero])
    assert (
        read_rosbag(path)
        .warnings[0]
        .endswith("(first: the transform's rotation quaternion is all zeros (to laser))")
    )
