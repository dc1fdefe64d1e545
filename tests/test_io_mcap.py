"""The MCAP log: round trips, unfinished files, bad input."""

from __future__ import annotations

import json
import math
import time
from io import BytesIO

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from segloc_cli.errors import InputError
from segloc_cli.geometry import Pose2, wrap_angle
from segloc_cli.io.files import OutputError
from segloc_cli.io.mcap_log import MAX_CHUNK_BYTES, LogWriter, read_log, write_log
from segloc_cli.scan import MAX_RANGE_M, MAX_READINGS, Scan, fan_defect

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


def test_a_durable_writer_has_every_message_on_disk_before_close(tmp_path):
    """With durable_every_s 0 each message's chunk is ended and flushed at once (the
    recorder waits half a second)."""
    path = tmp_path / "log.mcap"
    writer = LogWriter(path, SENSOR, durable_every_s=0.0)
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
    writer = LogWriter(path, SENSOR, durable_every_s=0.0)
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
GOOD_LATER = GOOD.replace(b'"sec": 0', b'"sec": 1')


def test_scan_message_not_json_is_skipped(tmp_path):
    path = tmp_path / "bad.mcap"
    raw_scan_log(path, [GOOD, b"{not json", GOOD_LATER])
    contents = read_log(path)
    assert [s.time_s for s in contents.scans] == [0.0, 1.0]
    assert contents.message_counts == {"/scan": 3}
    assert contents.warnings == [
        "bad.mcap: skipped 1 /scan message [not a JSON object: malformed, nested too deep or "
        "numbers too long to read]: message 2 (not valid JSON: Expecting property name "
        "enclosed in double quotes: line 1 column 2 (char 1))"
    ]


def test_scan_message_missing_field_is_skipped(tmp_path):
    path = tmp_path / "bad.mcap"
    message = json.loads(GOOD)
    del message["end_angle"]
    raw_scan_log(path, [GOOD, GOOD_LATER, json.dumps(message).encode()])
    contents = read_log(path)
    assert len(contents.scans) == 2
    assert contents.warnings == [
        "bad.mcap: skipped 1 /scan message [start_angle or end_angle missing, not a number or "
        "not finite]: message 3 (lacks field 'end_angle')"
    ]


def test_only_bad_scans_refuse_the_file(tmp_path):
    path = tmp_path / "bad.mcap"
    message = json.loads(GOOD)
    message["ranges"] = [1.0, "far"]
    raw_scan_log(path, [json.dumps(message).encode(), b"[]"])
    with pytest.raises(
        InputError,
        match=r"bad\.mcap: every /scan message is unusable \(2 skipped; first, message 1: "
        r"field 'ranges' is an array holding 'far'\)$",
    ):
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


# --- hostile content: skipped and counted, never passed on ------------------------


def scan_payload(sec=1, start=0.0, end=1.0, ranges=(1.0, 2.0), **extra) -> bytes:
    message = {
        "timestamp": {"sec": sec, "nsec": 0},
        "start_angle": start,
        "end_angle": end,
        "ranges": list(ranges),
        **extra,
    }
    return json.dumps(message).encode()


def odom_payload(sec=1, x=0.0, y=0.0, q=(0.0, 0.0, 0.0, 1.0)) -> bytes:
    message = {
        "timestamp": {"sec": sec, "nsec": 0},
        "pose": {
            "position": {"x": x, "y": y, "z": 0.0},
            "orientation": dict(zip("xyzw", q, strict=True)),
        },
    }
    return json.dumps(message).encode()


def hand_log(path, scans, odom=(), sensor=None, chunked=False, compression="NONE", times=None):
    """A log with the given raw /scan and /odom payloads; log time = publish time = ``times``
    (ns, default the message index)."""
    with open(path, "wb") as stream:
        writer = Writer(stream, use_chunking=chunked, compression=CompressionType[compression])
        writer.start()
        if sensor is not None:
            writer.add_metadata("segloc.sensor", sensor)
        schema = writer.register_schema("foxglove.LaserScan", "jsonschema", b"{}")
        scan_channel = writer.register_channel("/scan", "json", schema)
        odom_channel = writer.register_channel("/odom", "json", schema)
        for i, payload in enumerate(scans):
            t = i if times is None else times[i]
            writer.add_message(scan_channel, t, payload, t)
        for i, payload in enumerate(odom):
            writer.add_message(odom_channel, i, payload, i)
        writer.finish()


def test_non_finite_and_huge_angles_are_skipped(tmp_path):
    path = tmp_path / "angles.mcap"
    hand_log(
        path,
        [
            scan_payload(sec=1),
            b'{"timestamp": {"sec": 2, "nsec": 0}, "start_angle": NaN, "end_angle": 1.0,'
            b' "ranges": [1.0]}',
            scan_payload(sec=3, end=10**400),
            scan_payload(sec=4, start="0"),
            scan_payload(sec=5, start=True),
            scan_payload(sec=6),
        ],
    )
    contents = read_log(path)
    assert contents.scan_times_s.tolist() == [1.0, 6.0]
    assert contents.warnings == [
        "angles.mcap: skipped 4 /scan messages [start_angle or end_angle missing, not a number "
        "or not finite]: messages 2, 3, 4, 5 (first: field 'start_angle' is nan, expected a "
        "finite number)"
    ]


@pytest.mark.parametrize(
    ("start", "end", "n", "why"),
    [
        (0.5, 0.5, 2, "degenerate fan: all 2 beams at 0.5 rad"),
        (-4.0, 4.0, 3, "fan spans 8 rad, more than a full turn"),
        (0.0, 20.0, 3, "fan angles 0 to 20 rad lie beyond ±4π (corrupt, or not radians)"),
        (1.0, -1.0, 3, "fan angles decrease, from 1 to -1 rad"),
        (0.5, 0.25, 1, "fan angles decrease, from 0.5 to 0.25 rad"),
    ],
)
def test_fans_that_are_not_fans_are_skipped(tmp_path, start, end, n, why):
    path = tmp_path / "fan.mcap"
    hand_log(path, [scan_payload(sec=1), scan_payload(sec=2, start=start, end=end, ranges=[1] * n)])
    contents = read_log(path)
    assert len(contents.scans) == 1
    assert contents.warnings == [
        "fan.mcap: skipped 1 /scan message [not a fan: angles that decrease, all beams on one "
        f"ray, over a full turn, or angles beyond ±4π]: message 2 ({why})"
    ]


def test_full_turn_and_single_beam_fans_are_kept(tmp_path):
    path = tmp_path / "fans.mcap"
    hand_log(
        path,
        [
            scan_payload(sec=1, start=-math.pi, end=math.pi, ranges=[1.0] * 5),
            scan_payload(sec=2, start=0.25, end=0.25, ranges=[1.0]),
        ],
    )
    contents = read_log(path)
    assert contents.warnings == []
    np.testing.assert_allclose(contents.scans[0].angles_rad, np.linspace(-np.pi, np.pi, 5))
    assert contents.scans[1].angles_rad.tolist() == [0.25]


def test_absurd_ranges_are_no_returns(tmp_path):
    path = tmp_path / "far.mcap"
    hand_log(
        path,
        [
            b'{"timestamp": {"sec": 1, "nsec": 0}, "start_angle": 0, "end_angle": 1,'
            b' "ranges": [1e30, Infinity, NaN, -2, 999.5, 1000.0, ' + b"9" * 400 + b", 3]}"
        ],
    )
    (scan,) = read_log(path).scans
    assert scan.range_max_m == math.inf
    assert scan.ranges_m.tolist() == [0.0, 0.0, 0.0, 0.0, 999.5, 0.0, 0.0, 3.0]
    assert scan.valid.tolist() == [False] * 4 + [True, False, False, True]


def test_too_many_readings_and_bad_ranges_are_skipped(tmp_path):
    path = tmp_path / "big.mcap"
    hand_log(
        path,
        [
            scan_payload(sec=1),
            scan_payload(sec=2, ranges=[0] * (MAX_READINGS + 1)),
            scan_payload(sec=3, ranges=[1.0, None]),
            scan_payload(sec=4, ranges=[[1.0]]),
            json.dumps(
                {
                    "timestamp": {"sec": 5, "nsec": 0},
                    "start_angle": 0,
                    "end_angle": 1,
                    "ranges": "1,2",
                }
            ).encode(),
        ],
    )
    contents = read_log(path)
    assert len(contents.scans) == 1
    assert contents.warnings == [
        f"big.mcap: skipped 1 /scan message [over 16777216 bytes or over {MAX_READINGS} "
        "readings]: message 2 (100001 readings)",
        "big.mcap: skipped 3 /scan messages [ranges missing or not a list of numbers]: "
        "messages 3, 4, 5 (first: field 'ranges' is an array holding None)",
    ]


def test_deep_and_overlong_json_is_skipped(tmp_path):
    path = tmp_path / "deep.mcap"
    deep = b'{"a": ' + b"[" * 100_000 + b"]" * 100_000 + b"}"
    long_number = scan_payload(sec=3).replace(b'"end_angle": 1.0', b'"end_angle": ' + b"7" * 5000)
    hand_log(path, [scan_payload(sec=1), deep, long_number, b"[1, 2]", b"\xff\xfe{"])
    contents = read_log(path)
    assert len(contents.scans) == 1
    (warning,) = contents.warnings
    assert warning.startswith(
        "deep.mcap: skipped 4 /scan messages [not a JSON object: malformed, nested too deep or "
        "numbers too long to read]: messages 2, 3, 4, 5 (first: not valid JSON: nested too deep)"
    )


@pytest.mark.parametrize(
    ("stamp", "why"),
    [
        ({"sec": 1.5, "nsec": 0}, "timestamp.sec is 1.5, expected an integer"),
        ({"sec": "1", "nsec": 0}, "timestamp.sec is '1', expected an integer"),
        ({"sec": -1, "nsec": 0}, "timestamp -1 s 0 ns out of range"),
        ({"sec": 10**12, "nsec": 0}, "timestamp 1000000000000 s 0 ns out of range"),
        ({"sec": 0}, "lacks field 'timestamp.nsec'"),
    ],
)
def test_bad_timestamps_are_skipped(tmp_path, stamp, why):
    path = tmp_path / "time.mcap"
    bad = json.loads(scan_payload())
    bad["timestamp"] = stamp
    hand_log(path, [scan_payload(sec=7), json.dumps(bad).encode()])
    contents = read_log(path)
    assert contents.scan_times_s.tolist() == [7.0]
    assert contents.warnings == [
        "time.mcap: skipped 1 /scan message [no valid timestamp: whole sec and nsec, from 0 to "
        f"2^63 ns]: message 2 ({why})"
    ]


def test_whole_float_timestamps_are_read(tmp_path):
    path = tmp_path / "time.mcap"
    payload = scan_payload().replace(b'"sec": 1', b'"sec": 2.0')
    hand_log(path, [payload])
    assert read_log(path).scan_times_s.tolist() == [2.0]


def test_bad_odometry_is_skipped(tmp_path):
    path = tmp_path / "odom.mcap"
    hand_log(
        path,
        [scan_payload()],
        odom=[
            odom_payload(sec=1, x=1.0, y=2.0, q=(0.0, 0.0, 1e-200, 1e-200)),
            odom_payload(sec=2, q=(0.0, 0.0, 0.0, 0.0)),
            odom_payload(sec=3, x=float("nan")),
            odom_payload(sec=4, y=10**400),
            odom_payload(sec=5, x=3.0, q=(0.0, 0.0, 1e200, 0.0)),
        ],
    )
    contents = read_log(path)
    assert contents.odom_times_s.tolist() == [1.0, 5.0]
    np.testing.assert_allclose(contents.odom_poses, [[1.0, 2.0, np.pi / 2], [3.0, 0.0, -np.pi]])
    assert contents.warnings == [
        "odom.mcap: skipped 2 /odom messages [position or orientation missing, not numbers or "
        "not finite]: messages 3, 4 (first: field 'pose.position.x' is nan, expected a finite "
        "number)",
        "odom.mcap: skipped 1 /odom message [orientation quaternion all zeros]: message 2 "
        "(orientation is (0, 0, 0, 0))",
    ]


def test_intensities_that_do_not_fit_are_dropped(tmp_path):
    path = tmp_path / "int.mcap"
    hand_log(
        path,
        [
            scan_payload(sec=1, intensities=[1.0]),
            scan_payload(sec=2, intensities=["a", 1]),
            scan_payload(sec=3, intensities=[5.0, float("inf")]),
        ],
    )
    contents = read_log(path)
    assert [s.intensities.tolist() for s in contents.scans] == [[], [], [5.0, 0.0]]
    assert contents.warnings == [
        "int.mcap: dropped the intensities of 2 /scan messages [not one number per reading; "
        "the scans are kept]: messages 1, 2 (first: 1 values for 2 readings)"
    ]


@pytest.mark.parametrize("value", ["nan", "1e400", "-3", "0", "eight", "x" * 1000, "1\n2"])
def test_unusable_range_max_refuses_the_file(tmp_path, value):
    path = tmp_path / "sensor.mcap"
    hand_log(path, [scan_payload()], sensor={"range_max_m": value})
    with pytest.raises(InputError) as error:
        read_log(path)
    message = str(error.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: metadata segloc.sensor: range_max_m is ")
    assert message.endswith("expected a positive finite number in metres or 'inf'")
    assert len(message) < len(str(path)) + 140


@pytest.mark.parametrize("value", ["inf", "Infinity", "+inf", " 30 "])
def test_range_max_spellings(tmp_path, value):
    path = tmp_path / "sensor.mcap"
    hand_log(path, [scan_payload()], sensor={"range_max_m": value})
    (scan,) = read_log(path).scans
    assert scan.range_max_m == (30.0 if value == " 30 " else math.inf)


def test_repeated_and_backward_times_are_reported_not_changed(tmp_path):
    path = tmp_path / "times.mcap"
    hand_log(path, [scan_payload(sec=s) for s in (1, 2, 2, 1, 3, 3)])
    contents = read_log(path)
    assert contents.scan_times_s.tolist() == [1.0, 2.0, 2.0, 1.0, 3.0, 3.0]
    assert contents.warnings == [
        "times.mcap: 3 scans repeat an earlier scan's time or go back in time (first: /scan "
        "message 3 at 2.000000000 s); pairing scans by time may refuse them"
    ]


def test_chunked_compressed_logs_are_read(tmp_path):
    for compression in ("ZSTD", "LZ4", "NONE"):
        path = tmp_path / f"{compression}.mcap"
        hand_log(
            path,
            [scan_payload(sec=s) for s in range(1, 4)],
            odom=[odom_payload()],
            chunked=True,
            compression=compression,
        )
        contents = read_log(path)
        assert contents.scan_times_s.tolist() == [1.0, 2.0, 3.0]
        assert len(contents.odom_times_s) == 1
        assert contents.warnings == []


def test_chunk_claiming_too_much_memory_is_corrupt(tmp_path):
    path = tmp_path / "bomb.mcap"
    hand_log(path, [scan_payload(sec=1)], chunked=True, compression="ZSTD")
    data = bytearray(path.read_bytes())
    offset = 8
    while data[offset] != 0x06:  # the first chunk record
        offset += 9 + int.from_bytes(data[offset + 1 : offset + 9], "little")
    size_field = offset + 9 + 16
    data[size_field : size_field + 8] = (MAX_CHUNK_BYTES + 1).to_bytes(8, "little")
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"bomb\.mcap: no /scan channel; .*has a corrupt chunk"):
        read_log(path)


# --- original times and the writer ----------------------------------------------------


def test_original_times_round_trip(tmp_path):
    path = tmp_path / "log.mcap"
    scans = make_scans()
    originals = [12.345678901, 12.345678901, 11.0, 1_000.0]
    write_log(path, scans, sensor=SENSOR, original_times_s=originals)
    contents = read_log(path)
    assert contents.scan_times_s.tolist() == [s.time_s for s in scans]
    assert contents.original_times_s.tolist() == originals
    with open(path, "rb") as stream:
        publish = [m.publish_time for _, _, m in make_reader(stream).iter_messages()]
    assert publish == [12_345_678_901, 12_345_678_901, 11_000_000_000, 1_000_000_000_000]


def test_original_times_default_to_scan_times(log_path):
    contents = read_log(log_path)
    np.testing.assert_array_equal(contents.original_times_s, contents.scan_times_s)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"original_times_s": [1.0]}, "1 original times for 4 scans"),
        ({"original_times_s": [1.0, 2.0, math.nan, 3.0]}, "log times must be finite"),
        ({"odom": [(-1.0, Pose2(0.0, 0.0, 0.0))]}, "log times must be finite and from 0"),
        ({"odom": [(1.0, Pose2(math.inf, 0.0, 0.0))]}, "odometry at t=1.0 s is not finite"),
        ({"sensor": {"range_max_m": "nan"}}, "range_max_m must be a positive number"),
    ],
)
def test_write_log_checks_before_creating_the_file(tmp_path, kwargs, match):
    path = tmp_path / "log.mcap"
    with pytest.raises(ValueError, match=match):
        write_log(path, make_scans(), **kwargs)
    assert not path.exists()


def test_uneven_scan_is_refused_before_the_file_is_created(tmp_path):
    path = tmp_path / "log.mcap"
    uneven = Scan(1.0, np.array([0.0, 0.1, 0.3]), np.array([1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match="not evenly spaced"):
        write_log(path, [make_scans()[0], uneven])
    assert not path.exists()


def test_write_errors_name_the_file(tmp_path):
    with pytest.raises(OutputError, match=r"^/dev/full: cannot write file \(No space left"):
        write_log("/dev/full", make_scans(), sensor=SENSOR)
    with pytest.raises(OutputError, match=r"log\.mcap: cannot write file"):
        LogWriter(tmp_path / "missing" / "log.mcap", SENSOR)
    with pytest.raises(OutputError, match="cannot write file"):
        LogWriter(tmp_path, SENSOR)


# --- the Scan type ------------------------------------------------------------------------


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_scan_refuses_non_finite_angles(bad):
    with pytest.raises(ValueError, match="beam angles must be finite"):
        Scan(1.0, np.array([0.0, bad]), np.array([1.0, 1.0]))


def test_scan_valid_ignores_readings_beyond_the_physical_bound():
    scan = Scan(0.0, np.zeros(4), np.array([999.0, MAX_RANGE_M, 1e30, 5.0]))
    assert scan.valid.tolist() == [True, False, False, True]
    limited = Scan(0.0, np.zeros(4), np.array([999.0, MAX_RANGE_M, 1e30, 5.0]), range_max_m=5.0)
    assert limited.valid.tolist() == [False, False, False, False]


@pytest.mark.parametrize(
    ("n", "start", "end", "defect"),
    [
        (0, 0.0, 0.0, None),
        (1, 3.0, 3.0, None),
        (3, 0.0, 2 * math.pi, None),
        (3, 2 * math.pi, 4 * math.pi - 1.0, None),
        (3, 4 * math.pi - 1.0, 2 * math.pi, "fan angles decrease, from 11.5664 to 6.28319 rad"),
        (2, 1.0, 1.0, "degenerate fan: all 2 beams at 1 rad"),
        (3, 0.0, 2 * math.pi + 0.01, "fan spans 6.29319 rad, more than a full turn"),
        (3, math.nan, 1.0, "non-finite fan angles (nan to 1.0 rad)"),
        (1, 13.0, 13.0, "fan angles 13 to 13 rad lie beyond ±4π (corrupt, or not radians)"),
    ],
)
def test_fan_defect(n, start, end, defect):
    assert fan_defect(n, start, end) == defect


def test_a_ros2_bag_in_mcap_points_at_the_importer(tmp_path):
    path = tmp_path / "ros2.mcap"
    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start(profile="ros2", library="rosbag2")
        schema = writer.register_schema("sensor_msgs/msg/LaserScan", "ros2msg", b"")
        channel = writer.register_channel("/scan", "cdr", schema)
        writer.add_message(channel, log_time=0, data=b"\x00\x01", publish_time=0)
        writer.finish()
    with pytest.raises(InputError) as caught:
        read_log(path)
    assert str(caught.value) == (
        f"{path}: channel /scan uses message encoding 'cdr'; segloc reads JSON-encoded foxglove "
        f"messages; it is a ROS bag: convert it first with `segloc import rosbag {path} --out "
        f"{tmp_path / 'ros2-segloc.mcap'}`"
    )


def test_a_log_is_chunked_compressed_and_indexed(tmp_path):
    """Every chunk is zstd-compressed and listed in the summary with its messages' indexes,
    so a reader can seek to a time without reading the rest; the messages read back."""
    path = tmp_path / "log.mcap"
    scans = make_scans()
    write_log(path, scans, odom=[(s.time_s, Pose2(1.0, 2.0, 0.5)) for s in scans])
    with open(path, "rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary.chunk_indexes
    assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
    indexed = {channel for c in summary.chunk_indexes for channel in c.message_index_offsets}
    assert {summary.channels[k].topic for k in indexed} == {"/scan", "/odom"}
    assert summary.statistics.message_count == 2 * len(scans)
    assert len(read_log(path).scans) == len(scans)


def test_a_durable_writer_flushes_a_waiting_message_once_it_is_due(tmp_path):
    path = tmp_path / "log.mcap"
    writer = LogWriter(path, SENSOR, durable_every_s=0.2)
    first, second = make_scans()[:2]
    writer.add_scan(first)  # the first goes to disk at once, with the channels
    assert len(read_log(path).scans) == 1
    writer.add_scan(second)
    assert len(read_log(path).scans) == 1  # in the chunk in progress
    writer.make_durable_if_due()
    assert len(read_log(path).scans) == 1  # not due yet
    time.sleep(0.25)
    writer.make_durable_if_due()
    assert len(read_log(path).scans) == 2
    writer.close()


# --- the laser offset (the scanner's pose on the robot) -----------------------------------


MOUNT = Pose2(0.22, -0.05, math.radians(30.0))
OFFSET_SETTINGS = {
    "range_max_m": "inf",
    "laser_x_m": "0.22",
    "laser_y_m": "-0.05",
    "laser_theta_deg": "30.0",
    "laser_offset_source": "--laser-offset",
}


def test_the_laser_offset_is_every_scan_s_mounting(tmp_path):
    path = tmp_path / "mounted.mcap"
    scan = Scan(1.0, np.array([0.0, np.pi / 2]), np.array([2.0, 1.0]), mount=MOUNT)
    write_log(path, [scan], sensor=OFFSET_SETTINGS)
    log = read_log(path)
    assert log.laser_offset == MOUNT
    assert log.laser_offset_source == "--laser-offset"
    (got,) = log.scans
    assert got.mount == MOUNT
    # The readings stay in the scanner's frame; their points are the robot's.
    np.testing.assert_array_equal(got.ranges_m, [2.0, 1.0])
    c, s = math.cos(MOUNT.theta), math.sin(MOUNT.theta)
    robot = [[0.22 + 2.0 * c, -0.05 + 2.0 * s], [0.22 - s, -0.05 + c]]
    np.testing.assert_allclose(got.points(), robot, rtol=0, atol=1e-15)


def test_a_log_without_the_offset_has_its_scanner_at_the_robot_origin(log_path):
    log = read_log(log_path)
    assert "laser_x_m" not in log.sensor
    assert log.laser_offset == Pose2(0.0, 0.0, 0.0)
    assert log.laser_offset_source == "none"
    assert all(scan.mount == Pose2(0.0, 0.0, 0.0) for scan in log.scans)
    first = log.scans[0]
    a, r = first.angles_rad[first.valid], first.ranges_m[first.valid]
    np.testing.assert_array_equal(first.points(), np.column_stack([r * np.cos(a), r * np.sin(a)]))


@pytest.mark.parametrize(
    ("key", "value", "expected"),
    [
        ("laser_x_m", "ahead", "laser_x_m is 'ahead', expected a number of metres within ±10"),
        ("laser_y_m", "nan", "laser_y_m is 'nan', expected a number of metres within ±10"),
        ("laser_x_m", "12", "laser_x_m is '12', expected a number of metres within ±10"),
        ("laser_theta_deg", "inf", "laser_theta_deg is 'inf', expected degrees"),
        ("laser_theta_deg", None, "laser_theta_deg is missing beside laser_x_m"),
    ],
)
def test_a_malformed_offset_refuses_the_file_in_one_line(tmp_path, key, value, expected):
    path = tmp_path / "offset.mcap"
    sensor = dict(OFFSET_SETTINGS)
    if value is None:
        del sensor[key]
    else:
        sensor[key] = value
    hand_log(path, [scan_payload()], sensor=sensor)
    with pytest.raises(InputError) as error:
        read_log(path)
    assert str(error.value) == f"{path}: metadata segloc.sensor: {expected}"


def test_the_writer_refuses_a_scan_mounted_otherwise_than_the_settings_say(tmp_path):
    mounted = Scan(1.0, np.array([0.0, 0.5]), np.array([2.0, 3.0]), mount=MOUNT)
    with LogWriter(tmp_path / "a.mcap", {"range_max_m": "inf"}) as writer:
        with pytest.raises(ValueError, match="mounted at"):
            writer.add_scan(mounted)
    with LogWriter(tmp_path / "b.mcap", OFFSET_SETTINGS) as writer:
        with pytest.raises(ValueError, match="mounted at"):
            writer.add_scan(Scan(1.0, np.array([0.0, 0.5]), np.array([2.0, 3.0])))
    with pytest.raises(ValueError, match="laser_x_m"):
        LogWriter(tmp_path / "c.mcap", {**OFFSET_SETTINGS, "laser_x_m": "x"})


def test_info_on_a_log_with_a_malformed_offset_is_one_line(tmp_path, capsys):
    from test_cli import assert_one_line_error, run_cli

    path = tmp_path / "offset.mcap"
    hand_log(path, [scan_payload()], sensor={**OFFSET_SETTINGS, "laser_x_m": "forward"})
    result = run_cli(capsys, "info", path)
    assert_one_line_error(result, str(path), "laser_x_m is 'forward'")
