"""A row names the scan it came from: a scan that cannot be read (or whose beams contradict
themselves) is skipped, and shifts no other row's id.

For every reader (MCAP, CARMEN, ROS 1, ROS 2), a log of five scans with the first, the
third or the last one unreadable is imported where it must be and localized; each row's
``pose_id`` is the scan's own number in the source and its ``time_s`` that scan's time.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from mcap.writer import Writer
from test_cli import run_cli
from test_io_carmen import laser_line
from test_io_carmen import write as write_carmen
from test_io_mcap import odom_payload
from test_io_rosbag import (
    ANGLE_INCREMENT,
    ANGLE_MIN,
    EPOCH_S,
    N_BEAMS,
    ODOM_TYPE,
    ROS1_STORE,
    ROS2_STORE,
    SCAN_TYPE,
    odom_record,
    scan_record,
    write_bag,
)

from segloc_cli.estimates import PoseTable
from segloc_cli.geometry import Pose2
from segloc_cli.io.maps import read_map, write_map
from segloc_cli.io.mcap_log import read_log, write_log
from segloc_cli.io.tables import write_pose_table
from segloc_cli.scan import Scan

# A 6 m × 4 m room; five scans 0.1 m apart along it, 1 s apart from t = 1 s.
ROOM = np.array([[0, 0, 6, 0], [6, 0, 6, 4], [6, 4, 0, 4], [0, 4, 0, 0.0]])
POSES = [Pose2(2.0 + 0.1 * k, 2.0, 0.05 * k) for k in range(5)]
TIMES_S = [1.0 + k for k in range(5)]
ANGLES = ANGLE_MIN + ANGLE_INCREMENT * np.arange(N_BEAMS)  # 181 beams over 180°, as SICK's


def room_ranges(pose: Pose2) -> np.ndarray:
    """Ranges (m) of the 181 beams from ``pose`` to the room's walls."""
    heading = pose.theta + ANGLES
    c, s = np.cos(heading), np.sin(heading)
    with np.errstate(divide="ignore"):
        along_x = np.where(c > 0, (6.0 - pose.x) / c, np.where(c < 0, -pose.x / c, np.inf))
        along_y = np.where(s > 0, (4.0 - pose.y) / s, np.where(s < 0, -pose.y / s, np.inf))
    return np.round(np.minimum(along_x, along_y), 3)


def mcap_of_another_tool(where: Path, bad: int) -> Path:
    """Scans and odometry as another tool writes them (every sequence number 0), the scan
    ``bad`` not JSON."""
    path = where / "other.mcap"
    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start()
        writer.add_metadata("segloc.sensor", {"range_max_m": "30"})
        schema = writer.register_schema("foxglove.LaserScan", "jsonschema", b"{}")
        scans = writer.register_channel("/scan", "json", schema)
        odom = writer.register_channel("/odom", "json", schema)
        for k, (pose, t) in enumerate(zip(POSES, TIMES_S, strict=True)):
            message = {
                "timestamp": {"sec": int(t), "nsec": 0},
                "start_angle": float(ANGLES[0]),
                "end_angle": float(ANGLES[-1]),
                "ranges": room_ranges(pose).tolist(),
            }
            data = b"{not json" if k == bad else json.dumps(message).encode()
            ns = int(t * 1e9)
            writer.add_message(scans, ns, data, ns)
            odom_data = json.loads(odom_payload(int(t), pose.x, pose.y))
            odom_data["pose"]["orientation"] = {"x": 0, "y": 0, "z": np.sin(pose.theta / 2),
                                                "w": np.cos(pose.theta / 2)}  # fmt: skip
            writer.add_message(odom, ns, json.dumps(odom_data).encode(), ns)
        writer.finish()
    return path


def carmen_log(where: Path, bad: int) -> Path:
    """FLASER records, the one of scan ``bad`` cut short."""
    lines = []
    for k, (pose, t) in enumerate(zip(POSES, TIMES_S, strict=True)):
        fields = (pose.x, pose.y, pose.theta)
        line = laser_line(room_ranges(pose), fields, fields, t)
        lines.append(f"FLASER {N_BEAMS} 1.0 2.0" if k == bad else line)
    return write_carmen(where / "room.clf", lines)


def ros_bag(kind: str, where: Path, bad: int) -> Path:
    """A ROS 1 bag or ROS 2 bag folder of scans and odometry, the scan ``bad`` bytes that do
    not decode."""
    store = ROS1_STORE if kind == "ros1" else ROS2_STORE
    messages = []
    for k, (pose, t) in enumerate(zip(POSES, TIMES_S, strict=True)):
        stamp = int((t - 1.0) * 1e9)
        record = EPOCH_S * 1_000_000_000 + stamp
        scan = scan_record(store, record, stamp, room_ranges(pose))
        messages.append(("/scan", record, b"\x01\x02") if k == bad else scan)
        messages.append(odom_record(store, record + 1, stamp, pose))
    topics = {"/scan": SCAN_TYPE, "/odom": ODOM_TYPE}
    return write_bag("ros1" if kind == "ros1" else "ros2-folder", where, topics, messages)


def times_in(kind: str) -> list[float]:
    """The scans' times as the log segloc localizes holds them."""
    return [EPOCH_S + t - 1.0 for t in TIMES_S] if kind.startswith("ros") else TIMES_S


@pytest.mark.parametrize("kind", ["mcap", "carmen", "ros1", "ros2"])
@pytest.mark.parametrize("bad", [0, 2, 4])
def test_rows_keep_their_scans_numbers_when_one_cannot_be_read(kind, bad, tmp_path, capsys):
    map_path = tmp_path / "map.json"
    write_map(map_path, ROOM)
    log = tmp_path / "log.mcap"
    if kind == "mcap":
        log = mcap_of_another_tool(tmp_path, bad)
    else:
        source = carmen_log(tmp_path, bad) if kind == "carmen" else ros_bag(kind, tmp_path, bad)
        imported = run_cli(capsys, "import", "rosbag" if kind.startswith("ros") else kind,
                           source, "--out", log)  # fmt: skip
        assert imported.code == 0 and "skipped 1" in imported.err, imported.err
    out = tmp_path / "estimates.csv"
    result = run_cli(capsys, "localize", log, "--map", map_path, "--out", out)
    assert result.code == 0, result.err
    assert kind != "mcap" or "skipped 1 /scan message" in result.err
    rows = pd.read_csv(out)
    kept = [k for k in range(5) if k != bad]
    assert rows["pose_id"].tolist() == [k + 1 for k in kept]
    assert rows["time_s"].to_numpy() == pytest.approx([times_in(kind)[k] for k in kept])
    # Each row's answer is its own scan's pose: the rows are not shifted onto other scans.
    for (_, row), k in zip(rows.iterrows(), kept, strict=True):
        assert np.hypot(row.x_m - POSES[k].x, row.y_m - POSES[k].y) < 0.02


def test_numbers_round_trip_through_segloc_logs(tmp_path):
    scans = [Scan(t, ANGLES, room_ranges(p), 30.0) for p, t in zip(POSES, TIMES_S, strict=True)]
    path = tmp_path / "gaps.mcap"
    write_log(path, scans, numbers=[3, 4, 7, 8, 12])
    assert read_log(path).scan_numbers.tolist() == [3, 4, 7, 8, 12]
    write_log(path, scans)
    assert read_log(path).scan_numbers.tolist() == [1, 2, 3, 4, 5]
    with pytest.raises(ValueError, match="some alike"):
        write_log(path, scans, numbers=[1, 2, 2, 3, 4])


def test_map_build_and_localize_skip_a_scan_turning_the_wrong_way(tmp_path, capsys):
    """A scan whose angles decrease would draw the room's walls mirrored; the map and the
    rows come from the other scans, and both commands say one was skipped."""
    scans = [Scan(t, ANGLES, room_ranges(p), 30.0) for p, t in zip(POSES, TIMES_S, strict=True)]
    scans[2] = Scan(TIMES_S[2], ANGLES[::-1].copy(), room_ranges(POSES[2]), 30.0)
    log = tmp_path / "log.mcap"
    write_log(log, scans, [(t, p) for t, p in zip(TIMES_S, POSES, strict=True)])
    survey = tmp_path / "survey.csv"
    write_pose_table(survey, PoseTable(np.arange(1, 6), np.array(TIMES_S),
                                       np.array([[p.x, p.y, p.theta] for p in POSES])))  # fmt: skip
    built = tmp_path / "map.json"
    result = run_cli(capsys, "map", "build", log, "--survey", survey, "--out", built)
    assert result.code == 0 and "skipped 1 /scan message" in result.err, result.err
    segments = read_map(built)
    assert np.all((segments[:, 0::2] > -0.05) & (segments[:, 0::2] < 6.05))
    assert np.all((segments[:, 1::2] > -0.05) & (segments[:, 1::2] < 4.05))
    out = tmp_path / "estimates.csv"
    result = run_cli(capsys, "localize", log, "--map", built, "--out", out)
    assert result.code == 0 and "skipped 1 /scan message" in result.err, result.err
    assert pd.read_csv(out)["pose_id"].tolist() == [1, 2, 4, 5]
