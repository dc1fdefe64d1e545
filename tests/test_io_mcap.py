"""The MCAP log: round trips, unfinished files, bad input."""

from __future__ import annotations

import json
import math
from io import BytesIO

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
from mcap.writer import Writer

from segloc_cli.errors import InputError
from segloc_cli.geometry import Pose2, wrap_angle
from segloc_cli.io.mcap_log import LogWriter, read_log, write_log
from segloc_cli.scan import Scan

RANGE_MAX_M = 8.0


def make_scans() -> list[Scan]:
    """Scans of several sizes, with invalid readings and intensities, at exact ns times."""
    return [
        Scan(
            time_s=12.345678901,
            angles_rad=np.linspace(-np.pi, np.pi, 8, endpoint=False),
            ranges_m=np.array([1.0, 2.5, 0.0, -1.0, np.inf, np.nan, 8.0, 7.999]),
            range_max_m=RANGE_MAX_M,
            intensities=np.array([10.0, 20.0, 0.0, 0.0, 0.0, 0.0, 0.0, 5.5]),
        ),
        Scan(
            time_s=12.5,
            angles_rad=np.linspace(-2.0, 2.0, 3),
            ranges_m=np.array([0.25, 3.0, 9.5]),
            range_max_m=RANGE_MAX_M,
        ),
        Scan(
            time_s=13.000000001,
            angles_rad=np.array([0.3]),
            ranges_m=np.array([4.125]),
            range_max_m=RANGE_MAX_M,
            intensities=np.array([1.0]),
        ),
        Scan(
            time_s=1_000.0,
            angles_rad=np.linspace(0.0, 2.0, 101),
            ranges_m=np.linspace(0.5, 6.5, 101),
            range_max_m=RANGE_MAX_M,
        ),
    ]


ODOM = [
    (12.3, Pose2(1.0, -2.0, 0.5)),
    (12.4, Pose2(-3.25, 4.5, np.pi - 1e-9)),
    (12.6, Pose2(0.0, 0.0, -np.pi + 1e-9)),
    (12.7, Pose2(10.0, 20.0, -np.pi / 2)),
]

SENSOR = {"range_max_m": "8.0", "device": "emulator", "readings": "8", "seed": "7"}


def expected_ranges(scan: Scan) -> np.ndarray:
    r = np.asarray(scan.ranges_m, dtype=float)
    ok = np.isfinite(r) & (r > 0) & (r < RANGE_MAX_M)
    return np.where(ok, r, 0.0)


@pytest.fixture
def log_path(tmp_path):
    path = tmp_path / "log.mcap"
    write_log(path, make_scans(), ODOM, SENSOR)
    return path


def test_round_trip_every_field(log_path):
    contents = read_log(log_path)
    originals = make_scans()

    assert contents.finished is True
    assert contents.warnings == []
    assert contents.sensor == SENSOR
    assert len(contents.scans) == len(originals)
    for got, want in zip(contents.scans, originals, strict=True):
        assert round(got.time_s * 1e9) == round(want.time_s * 1e9)
        assert got.time_s == want.time_s
        np.testing.assert_allclose(got.angles_rad, want.angles_rad, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(got.ranges_m, expected_ranges(want))
        np.testing.assert_array_equal(got.valid, want.valid)
        np.testing.assert_array_equal(got.intensities, want.intensities)
        assert got.range_max_m == RANGE_MAX_M

    # Invalid readings are stored as 0 and stay invalid.
    first = contents.scans[0]
    np.testing.assert_array_equal(
        first.valid, [True, True, False, False, False, False, False, True]
    )
    np.testing.assert_array_equal(contents.scans[1].ranges_m, [0.25, 3.0, 0.0])

    np.testing.assert_array_equal(contents.odom_times_s, [t for t, _ in ODOM])
    assert contents.odom_poses.shape == (4, 3)
    for (_, pose), row in zip(ODOM, contents.odom_poses, strict=True):
        assert row[0] == pose.x
        assert row[1] == pose.y
        assert abs(wrap_angle(row[2] - pose.theta)) < 1e-12
        assert -np.pi <= row[2] < np.pi


def test_headings_near_pi_keep_their_side(log_path):
    poses = read_log(log_path).odom_poses
    assert poses[1, 2] == pytest.approx(np.pi - 1e-9, abs=1e-12)
    assert poses[2, 2] == pytest.approx(-np.pi + 1e-9, abs=1e-12)


def test_summary_reader_sees_foxglove_schemas(log_path):
    with open(log_path, "rb") as stream:
        reader = make_reader(stream)
        seen = [
            (schema.name, channel.topic, message)
            for schema, channel, message in reader.iter_messages()
        ]
    names = {topic: name for name, topic, _ in seen}
    assert names == {"/scan": "foxglove.LaserScan", "/odom": "foxglove.PoseInFrame"}
    scan_messages = [m for _, topic, m in seen if topic == "/scan"]
    assert len(scan_messages) == 4
    first = json.loads(scan_messages[0].data)
    assert scan_messages[0].log_time == 12_345_678_901
    assert scan_messages[0].publish_time == 12_345_678_901
    assert first["timestamp"] == {"sec": 12, "nsec": 345_678_901}
    assert first["frame_id"] == "laser"
    assert first["pose"]["orientation"] == {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
    assert first["start_angle"] == -np.pi
    assert first["end_angle"] == pytest.approx(np.pi - 2 * np.pi / 8, abs=1e-15)
    odom = json.loads(next(m for _, t, m in seen if t == "/odom").data)
    assert odom["frame_id"] == "world"
    assert odom["pose"]["orientation"]["z"] == pytest.approx(math.sin(0.25))
    assert odom["pose"]["orientation"]["w"] == pytest.approx(math.cos(0.25))


def test_schema_fields_match_foxglove(log_path):
    with open(log_path, "rb") as stream:
        summary = make_reader(stream).get_summary()
    schemas = {s.name: json.loads(s.data) for s in summary.schemas.values()}
    assert {s.encoding for s in summary.schemas.values()} == {"jsonschema"}
    scan = schemas["foxglove.LaserScan"]["properties"]
    assert list(scan) == [
        "timestamp",
        "frame_id",
        "pose",
        "start_angle",
        "end_angle",
        "ranges",
        "intensities",
    ]
    assert list(scan["timestamp"]["properties"]) == ["sec", "nsec"]
    assert list(scan["pose"]["properties"]["orientation"]["properties"]) == ["x", "y", "z", "w"]
    for key in ("ranges", "intensities"):
        assert scan[key]["type"] == "array"
        assert scan[key]["items"] == {"type": "number"}
    assert scan["timestamp"]["properties"]["nsec"]["maximum"] == 999_999_999
    assert list(schemas["foxglove.PoseInFrame"]["properties"]) == ["timestamp", "frame_id", "pose"]


def test_sensor_range_max_applies_to_every_scan(tmp_path):
    path = tmp_path / "log.mcap"
    scan = Scan(1.0, np.array([0.0, 0.5]), np.array([2.0, 3.5]))  # range_max_m = inf
    write_log(path, [scan], sensor={"range_max_m": "3.0"})
    (got,) = read_log(path).scans
    assert got.range_max_m == 3.0
    np.testing.assert_array_equal(got.ranges_m, [2.0, 0.0])


def test_missing_range_max_reads_as_inf(tmp_path):
    path = tmp_path / "log.mcap"
    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start()
        schema = writer.register_schema("foxglove.LaserScan", "jsonschema", b"{}")
        channel = writer.register_channel("/scan", "json", schema)
        message = {
            "timestamp": {"sec": 1, "nsec": 0},
            "start_angle": 0.0,
            "end_angle": 1.0,
            "ranges": [100.0, 2.0],
        }
        writer.add_message(channel, 10**9, json.dumps(message).encode(), 10**9)
        writer.finish()
    (scan,) = read_log(path).scans
    assert scan.range_max_m == math.inf
    assert scan.intensities.shape == (0,)
    np.testing.assert_array_equal(scan.angles_rad, [0.0, 1.0])
    np.testing.assert_array_equal(scan.valid, [True, True])


def test_uneven_angles_are_refused(tmp_path):
    scan = Scan(1.0, np.array([0.0, 0.1, 0.3]), np.array([1.0, 1.0, 1.0]))
    with LogWriter(tmp_path / "log.mcap", {"range_max_m": "inf"}) as writer:
        with pytest.raises(ValueError, match="not evenly spaced"):
            writer.add_scan(scan)


def test_writer_requires_range_max(tmp_path):
    with pytest.raises(ValueError, match="range_max_m"):
        LogWriter(tmp_path / "log.mcap", {"device": "x"})


def test_every_message_is_on_disk_before_close(tmp_path):
    path = tmp_path / "log.mcap"
    writer = LogWriter(path, SENSOR)
    for scan in make_scans()[:3]:
        writer.add_scan(scan)
    # Read while the writer is still open, as after a killed recorder.
    contents = read_log(path)
    writer.close()
    assert len(contents.scans) == 3
    assert contents.finished is False
    assert contents.warnings == [
        "log.mcap: file has no footer (recording was not finished); kept 3 scans"
    ]


def complete_scan_count(data: bytes, cut: int) -> int:
    """How many /scan messages end at or before byte ``cut``, read with mcap's own stream
    reader from the whole file."""
    stream = BytesIO(data)
    topics = {}
    count = 0
    for record in StreamReader(stream).records:
        if stream.tell() > cut:
            break
        if isinstance(record, Channel):
            topics[record.id] = record.topic
        elif isinstance(record, Message) and topics.get(record.channel_id) == "/scan":
            count += 1
    return count


@pytest.mark.parametrize("fraction", [0.97, 0.9, 0.7, 0.5])
def test_truncated_file_keeps_complete_scans(tmp_path, log_path, fraction):
    data = log_path.read_bytes()
    cut = int(len(data) * fraction)
    truncated = tmp_path / "cut.mcap"
    truncated.write_bytes(data[:cut])
    contents = read_log(truncated)
    want = complete_scan_count(data, cut)
    assert want > 0
    assert contents.finished is False
    assert len(contents.scans) == want
    originals = make_scans()
    for got, orig in zip(contents.scans, originals, strict=False):
        assert got.time_s == orig.time_s
        np.testing.assert_array_equal(got.ranges_m, expected_ranges(orig))
    assert len(contents.warnings) == 1
    assert contents.warnings[0].startswith("cut.mcap: file ")
    assert contents.warnings[0].endswith(f"kept {want} scans")


def test_cut_mid_message_names_the_count(tmp_path):
    path = tmp_path / "log.mcap"
    scans = make_scans()
    writer = LogWriter(path, SENSOR)
    for scan in scans[:2]:
        writer.add_scan(scan)
    size_after_two = path.stat().st_size
    writer.add_scan(scans[3])  # the big one
    size_after_three = path.stat().st_size
    writer.close()
    data = path.read_bytes()
    cut_path = tmp_path / "cut.mcap"
    cut_path.write_bytes(data[: (size_after_two + size_after_three) // 2])
    contents = read_log(cut_path)
    assert [s.time_s for s in contents.scans] == [scans[0].time_s, scans[1].time_s]
    assert contents.warnings == ["cut.mcap: file ends mid-record after 2 messages; kept 2 scans"]


def test_no_scan_channel(tmp_path):
    path = tmp_path / "odom_only.mcap"
    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start()
        schema = writer.register_schema("foxglove.PoseInFrame", "jsonschema", b"{}")
        writer.register_channel("/odom", "json", schema)
        writer.register_channel("/imu", "json", schema)
        writer.finish()
    with pytest.raises(
        InputError,
        match=r"odom_only\.mcap: no /scan channel; .*"
        r"channels found: /imu, /odom",
    ):
        read_log(path)


def test_not_an_mcap_file(tmp_path):
    path = tmp_path / "notes.mcap"
    path.write_text("pose_id,time_s\n1,2\n")
    with pytest.raises(InputError, match=r"notes\.mcap: not an MCAP file"):
        read_log(path)


def test_empty_file_is_not_mcap(tmp_path):
    path = tmp_path / "empty.mcap"
    path.write_bytes(b"")
    with pytest.raises(InputError, match="not an MCAP file"):
        read_log(path)


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match=r"nothere\.mcap: file not found"):
        read_log(tmp_path / "nothere.mcap")


def raw_scan_log(path, payloads: list[bytes]) -> None:
    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start()
        schema = writer.register_schema("foxglove.LaserScan", "jsonschema", b"{}")
        channel = writer.register_channel("/scan", "json", schema)
        for i, payload in enumerate(payloads):
            writer.add_message(channel, i, payload, i)
        writer.finish()


GOOD = json.dumps(
    {"timestamp": {"sec": 0, "nsec": 0}, "start_angle": 0.0, "end_angle": 0.0, "ranges": [1.0]}
).encode()


def test_scan_message_not_json(tmp_path):
    path = tmp_path / "bad.mcap"
    raw_scan_log(path, [GOOD, b"{not json"])
    with pytest.raises(InputError, match=r"bad\.mcap: /scan message 2 is not valid JSON"):
        read_log(path)


def test_scan_message_missing_field(tmp_path):
    path = tmp_path / "bad.mcap"
    message = json.loads(GOOD)
    del message["end_angle"]
    raw_scan_log(path, [GOOD, GOOD, json.dumps(message).encode()])
    with pytest.raises(InputError, match=r"/scan message 3 lacks field 'end_angle'"):
        read_log(path)


def test_scan_message_bad_ranges(tmp_path):
    path = tmp_path / "bad.mcap"
    message = json.loads(GOOD)
    message["ranges"] = [1.0, "far"]
    raw_scan_log(path, [json.dumps(message).encode()])
    with pytest.raises(InputError, match=r"/scan message 1: field 'ranges' must be a list"):
        read_log(path)


def test_message_counts_cover_every_channel(tmp_path):
    path = tmp_path / "mixed.mcap"
    scans = make_scans()
    with LogWriter(path, {"range_max_m": "30"}) as log:
        for scan in scans:
            log.add_scan(scan)
        log.add_odom(1.0, Pose2(0.0, 0.0, 0.0))
        schema = log._writer.register_schema("note", "jsonschema", b"{}")
        notes = log._writer.register_channel("/notes", "json", schema)
        for k in range(3):
            log._writer.add_message(notes, log_time=k, data=b"{}", publish_time=k)
    contents = read_log(path)
    assert contents.message_counts == {"/scan": len(scans), "/odom": 1, "/notes": 3}
