"""Fuzzing beam geometries: a scan whose angles or range limits contradict themselves is
skipped and counted by every reader, and one that adds up is read with its beams turning
counter-clockwise over at most a full turn.

Geometries are drawn around the consistent ones (a SICK-like 181-beam fan), then bent:
inverted, wider than a turn, a step that disagrees with the readings, a range limit below
its minimum. Whether a scan adds up is decided here from its fields alone, independently
of the readers' code.
"""

from __future__ import annotations

import math

import numpy as np
from fuzzing import fuzz_settings
from hypothesis import given
from hypothesis import strategies as st
from test_io_carmen import ROBOTLASER
from test_io_carmen import write as write_carmen
from test_io_rosbag import ODOM_TYPE, ROS1_STORE, SCAN_TYPE, scan_record, write_bag

from segloc_cli.io.carmen import read_carmen
from segloc_cli.io.rosbag import read_rosbag
from segloc_cli.scan import FAN_TOLERANCE_RAD

TURN = 2 * math.pi


def assert_fans(scans) -> None:
    """Every scan's beams turn counter-clockwise, evenly, over at most a full turn."""
    for scan in scans:
        steps = np.diff(scan.angles_rad)
        assert np.all(steps > 0)
        assert scan.angles_rad[-1] - scan.angles_rad[0] <= TURN + FAN_TOLERANCE_RAD


@st.composite
def ros_geometry(draw) -> dict:
    """LaserScan angle and range fields: a consistent 181-beam fan, or one bent."""
    n = draw(st.sampled_from([2, 5, 181, 361]))
    step = draw(st.sampled_from([math.pi / (n - 1), TURN / n, 0.004]))
    start = draw(st.floats(-math.pi, 0.0))
    spanned = n - 1 + draw(st.sampled_from([0, 0, 1, -1, 2, -3, n]))
    sign = draw(st.sampled_from([1.0, 1.0, -1.0]))
    low = draw(st.sampled_from([0.0, 0.1, 2.0]))
    high = draw(st.sampled_from([30.0, 1.0, 0.05, float("nan"), 0.0]))
    return {
        "n": n,
        "angle_min": start,
        "angle_max": start + sign * spanned * step,
        "angle_increment": sign * step,
        "range_min": low,
        "range_max": high,
    }


def ros_adds_up(g: dict) -> bool:
    """Angles rise over at most a turn, the step spans the readings to within a beam, and
    range_max is not below range_min (a missing or non-positive maximum is no maximum)."""
    n, step = g["n"], np.float32(g["angle_increment"])
    low, high = np.float32(g["angle_min"]), np.float32(g["angle_max"])
    last = float(low) + (n - 1) * float(step)
    spanned = round((float(high) - float(low)) / float(step)) + 1
    limits = not (g["range_min"] > g["range_max"] > 0)
    fan = float(step) > 0 and last - float(low) <= TURN + FAN_TOLERANCE_RAD
    return fan and abs(spanned - n) <= 1 and limits


@given(geometries=st.lists(ros_geometry(), min_size=1, max_size=4))
@fuzz_settings
def test_ros_scans_that_do_not_add_up_are_skipped_and_counted(tmp_path_factory, geometries):
    folder = tmp_path_factory.mktemp("geometry")
    good = {"n": 181, "angle_min": -math.pi / 2, "angle_max": math.pi / 2,
            "angle_increment": math.pi / 180, "range_min": 0.1, "range_max": 30.0}  # fmt: skip
    messages = []
    for k, g in enumerate([good, *geometries]):
        fields = {key: g[key] for key in ("angle_max", "range_max")}
        scan = scan_record(ROS1_STORE, 1 + k, k * 100_000_000, np.full(g["n"], 1.5), **fields)
        # scan_record fixes angle_min, the increment and range_min: set them here.
        message = ROS1_STORE.deserialize_ros1(scan[2], SCAN_TYPE)
        message.angle_min = np.float32(g["angle_min"])
        message.angle_increment = np.float32(g["angle_increment"])
        message.range_min = np.float32(g["range_min"])
        messages.append(("/scan", 1 + k, bytes(ROS1_STORE.serialize_ros1(message, SCAN_TYPE))))
    path = write_bag("ros1", folder, {"/scan": SCAN_TYPE, "/odom": ODOM_TYPE}, messages)
    log = read_rosbag(path, odom_topic=None)
    kept = [good, *[g for g in geometries if ros_adds_up(g)]]
    assert [len(s) for s in log.scans] == [g["n"] for g in kept]
    assert log.numbers.tolist() == [1] + [k + 2 for k, g in enumerate(geometries) if ros_adds_up(g)]
    skipped = sum(int(w.split("skipped ")[1].split(" ")[0]) for w in log.warnings if "skipped" in w)
    assert skipped == len(geometries) + 1 - len(kept)
    assert_fans(log.scans)


@st.composite
def robotlaser_geometry(draw) -> tuple[float, float, float]:
    """ROBOTLASER1 start angle, field of view and angular resolution of a 4-beam record."""
    start = draw(st.floats(-4.0, 1.0))
    fov = draw(st.sampled_from([3.0, -3.0, 0.0, 6.3, 7.0, 1.0]))
    resolution = fov / 3 * draw(st.sampled_from([1.0, 1.0, 0.5, 1.3, 2.0, -1.0]))
    return start, fov, resolution


def robotlaser_adds_up(start: float, fov: float, resolution: float) -> bool:
    """The fan rises over at most a turn, within ±4π, and the resolution is the field of view
    over the 3 steps to within one step."""
    rises = (
        0.0 < fov <= TURN + FAN_TOLERANCE_RAD and max(abs(start), abs(start + fov)) <= 4 * math.pi
    )
    return rises and abs(fov - 3 * resolution) <= abs(resolution)


@given(geometries=st.lists(robotlaser_geometry(), min_size=1, max_size=4))
@fuzz_settings
def test_robotlaser1_records_that_do_not_add_up_are_skipped_and_counted(
    tmp_path_factory, geometries
):
    lines = [ROBOTLASER]
    for k, (start, fov, resolution) in enumerate(geometries):
        line = ROBOTLASER.replace("-1.5 3.0 1.0", f"{start!r} {fov!r} {resolution!r}", 1)
        lines.append(line.replace("7.25 host 7.3", f"{8 + k} host {8 + k}"))
    path = write_carmen(tmp_path_factory.mktemp("robotlaser") / "robot.log", lines)
    log = read_carmen(path)
    adds_up = [robotlaser_adds_up(*g) for g in geometries]
    assert log.numbers.tolist() == [1] + [k + 2 for k, ok in enumerate(adds_up) if ok]
    if not all(adds_up):
        count = len(adds_up) - sum(adds_up)
        assert f"skipped {count} ROBOTLASER1 record" in log.warnings[0]
    assert_fans(log.scans)
