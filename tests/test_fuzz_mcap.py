"""Fuzzing the MCAP log reader: hostile messages in well-formed files, and mangled files.

Whatever a log holds, ``read_log`` returns scans a localizer can trust or refuses the
file in one line naming it. ``hostile_scans()`` is public so that other suites can feed
the same hostile laser scans to their own readers and kernels.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from fuzzing import byte_mutations, fuzz_settings, mutate, outcome
from hypothesis import given
from hypothesis import strategies as st
from mcap.writer import CompressionType, Writer

from segloc_cli.errors import InputError
from segloc_cli.geometry import Pose2
from segloc_cli.io.log import Log
from segloc_cli.io.mcap_log import read_log, write_log
from segloc_cli.scan import FAN_TOLERANCE_RAD, MAX_RANGE_M, MAX_READINGS, Scan

# --- hostile content -------------------------------------------------------------------

hostile_numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(-7.0, 7.0),
    st.integers(-(10**400), 10**400),
    st.sampled_from([0, -0.0, 1e-320, 1e30, -1e30, 1e308, 10**400, math.pi, 2 * math.pi, 13.0]),
)
"""Numbers a careless or corrupt writer puts in a file: non-finite, huge, subnormal, beyond
the float range (as JSON integers), and plain ones."""

hostile_values = st.recursive(
    st.none() | st.booleans() | hostile_numbers | st.text(max_size=4),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=3), inner),
    max_leaves=6,
)
"""Any JSON value, numbers hostile."""


@st.composite
def _fan(draw) -> tuple[object, object, list]:
    n = draw(st.sampled_from([0, 1, 2, 3, 17]))
    kind = draw(st.sampled_from(["good", "degenerate", "hostile", "wrong type"]))
    if kind == "good":
        start = draw(st.floats(-2 * math.pi, 2 * math.pi))
        end = start + draw(st.floats(-2 * math.pi, 2 * math.pi))
    elif kind == "degenerate":
        start = end = draw(st.floats(-4.0, 4.0))
    elif kind == "hostile":
        start, end = draw(hostile_numbers), draw(hostile_numbers)
    else:
        start, end = draw(hostile_values), draw(hostile_values)
    ranges = draw(
        st.one_of(
            st.lists(st.floats(0.0, 40.0), min_size=n, max_size=n),
            st.lists(hostile_numbers, min_size=n, max_size=n),
            hostile_values,
        )
    )
    return start, end, ranges


@st.composite
def hostile_scans(draw) -> dict:
    """A ``foxglove.LaserScan`` JSON object (a dict, as ``json.loads`` gives) that may be
    anything from valid to absurd: NaN, infinite, huge or equal fan angles, fans wider
    than a turn, ranges of 1e30, NaN or integers beyond the float range, values of the
    wrong type, bad timestamps, missing fields and mismatched intensities."""
    start, end, ranges = draw(_fan())
    stamp = draw(
        st.one_of(
            st.fixed_dictionaries(
                {"sec": st.integers(0, 2_000_000_000), "nsec": st.integers(0, 999_999_999)}
            ),
            st.fixed_dictionaries({"sec": hostile_values, "nsec": hostile_values}),
            hostile_values,
        )
    )
    message = {"timestamp": stamp, "start_angle": start, "end_angle": end, "ranges": ranges}
    if draw(st.booleans()):
        size = len(ranges) if isinstance(ranges, list) else 0
        message["intensities"] = draw(
            st.one_of(st.lists(hostile_numbers, min_size=size, max_size=size), hostile_values)
        )
    for key in draw(st.lists(st.sampled_from(sorted(message)), max_size=1)):
        del message[key]
    return message


@st.composite
def hostile_odometry(draw) -> dict:
    """A ``foxglove.PoseInFrame`` JSON object with possibly hostile position and orientation
    (NaN, huge, all-zero or subnormal quaternions, wrong types)."""
    number = st.one_of(st.floats(-10.0, 10.0), hostile_numbers)
    q = draw(
        st.one_of(
            st.tuples(number, number, number, number),
            st.just((0.0, 0.0, 0.0, 0.0)),
            st.just((0.0, 0.0, 1e-200, 1e-200)),
        )
    )
    return {
        "timestamp": {"sec": draw(st.integers(0, 10**6)), "nsec": 0},
        "pose": {
            "position": {"x": draw(number), "y": draw(st.one_of(number, hostile_values))},
            "orientation": dict(zip("xyzw", q, strict=True)),
        },
    }


def _encode(value: object) -> bytes:
    # json.dumps writes NaN and Infinity literals, as some writers do.
    return json.dumps(value).encode()


raw_payloads = st.one_of(
    hostile_scans().map(_encode),
    st.binary(max_size=40),
    st.integers(1, 30_000).map(lambda depth: b"[" * depth + b"]" * depth),
    st.integers(1, 30_000).map(lambda depth: b'{"a":' * depth + b"1" + b"}" * depth),
    st.integers(300, 6000).map(lambda digits: b'{"start_angle": ' + b"9" * digits + b"}"),
    st.sampled_from([b"", b"null", b"[]", b'"scan"', b"NaN", b"{}"]),
)
"""Bytes for a ``/scan`` message: hostile scans, binary junk, deep nesting, long numbers."""

sensor_values = st.one_of(
    st.sampled_from(["inf", "30", "nan", "1e400", "-1", "0", "", "8\n", "Infinity", "1e-300"]),
    st.text(max_size=10),
    st.text(min_size=2000, max_size=2000),
)
"""``range_max_m`` settings, sane and absurd."""


def _hand_log(
    path: Path, sensor: str | None, scans: list[bytes], odom: list[bytes], layout: str
) -> None:
    chunked = layout != "unchunked"
    compression = {"unchunked": "NONE", "none": "NONE", "zstd": "ZSTD", "lz4": "LZ4"}[layout]
    with open(path, "wb") as stream:
        writer = Writer(stream, use_chunking=chunked, compression=CompressionType[compression])
        writer.start()
        if sensor is not None:
            writer.add_metadata("segloc.sensor", {"range_max_m": sensor})
        schema = writer.register_schema("foxglove.LaserScan", "jsonschema", b"{}")
        scan_channel = writer.register_channel("/scan", "json", schema)
        odom_channel = writer.register_channel("/odom", "json", schema)
        for k, payload in enumerate(scans):
            writer.add_message(scan_channel, 10**9 * k, payload, 10**9 * k + k % 2)
        for k, payload in enumerate(odom):
            writer.add_message(odom_channel, 10**9 * k, payload, 10**9 * k)
        writer.finish()


# --- what a reader may hand on ---------------------------------------------------------


def assert_trustworthy(contents: Log) -> None:
    """Every scan a finite, evenly spaced, rising, non-degenerate fan of at most a turn, with finite
    readings whose valid ones lie in (0, MAX_RANGE_M); odometry and times finite."""
    assert len(contents.original_times_s) == len(contents.scans)
    assert np.all(np.isfinite(contents.original_times_s))
    for scan in contents.scans:
        angles = np.asarray(scan.angles_rad, dtype=float)
        ranges = np.asarray(scan.ranges_m, dtype=float)
        assert math.isfinite(scan.time_s) and scan.time_s >= 0
        assert angles.shape == ranges.shape and 0 <= len(scan) <= MAX_READINGS
        assert np.all(np.isfinite(angles)) and np.all(np.isfinite(ranges))
        if len(scan) > 1:
            span = angles[-1] - angles[0]
            assert 0.0 < span <= 2 * math.pi + FAN_TOLERANCE_RAD  # counter-clockwise
            steps = np.diff(angles)
            assert np.max(np.abs(steps - span / (len(scan) - 1))) <= 1e-9
        valid = ranges[scan.valid]
        assert np.all(valid > 0) and np.all(valid < MAX_RANGE_M)
        assert np.all(ranges[~scan.valid] == 0.0)
        assert scan.range_max_m > 0
        assert np.all(np.isfinite(scan.intensities))
        assert len(scan.intensities) in (0, len(scan))
    assert contents.odom_poses.shape == (len(contents.odom_times_s), 3)
    assert np.all(np.isfinite(contents.odom_times_s))
    assert np.all(np.isfinite(contents.odom_poses))
    assert np.all(np.abs(contents.odom_poses[:, 2]) <= math.pi)
    for warning in contents.warnings:
        assert "\n" not in warning and len(warning) < 600


def check(path: Path) -> Log | InputError:
    result = outcome(read_log, path)
    if isinstance(result, Log):
        assert_trustworthy(result)
    return result


# --- (a) hostile content in well-formed files ------------------------------------------

_GOOD_SCAN = {
    "timestamp": {"sec": 1, "nsec": 0},
    "start_angle": 0.0,
    "end_angle": 1.0,
    "ranges": [2.0, 3.0],
}


@given(
    scans=st.lists(hostile_scans().map(_encode), max_size=6),
    odom=st.lists(hostile_odometry().map(_encode), max_size=4),
    sensor=st.none() | sensor_values,
    layout=st.sampled_from(["unchunked", "none", "zstd", "lz4"]),
    good_at=st.none() | st.integers(0, 6),
)
@fuzz_settings
def test_hostile_messages(tmp_path, scans, odom, sensor, layout, good_at):
    if good_at is not None:
        scans.insert(good_at, _encode(_GOOD_SCAN))
    path = tmp_path / "hostile.mcap"
    _hand_log(path, sensor, scans, odom, layout)
    result = check(path)
    if good_at is not None and sensor in (None, "inf", "30", "Infinity"):
        assert isinstance(result, Log)
        assert any(scan.ranges_m.tolist() == [2.0, 3.0] for scan in result.scans)


@given(
    payloads=st.lists(raw_payloads, min_size=1, max_size=4),
    good_first=st.booleans(),
)
@fuzz_settings
def test_hostile_payload_bytes_keep_the_good_scans(tmp_path, payloads, good_first):
    scans = [_encode(_GOOD_SCAN), *payloads] if good_first else payloads
    path = tmp_path / "payloads.mcap"
    _hand_log(path, "30", scans, [], "unchunked")
    result = check(path)
    if good_first:
        # One good message keeps the file readable, whatever the others hold.
        assert isinstance(result, Log)
        assert result.scans[0].ranges_m.tolist() == [2.0, 3.0]


# --- (b) mangled bytes of valid logs ---------------------------------------------------


def _valid_logs(folder: Path) -> list[bytes]:
    """A segloc-written log (unchunked) and chunked zstd and lz4 logs of the same scans."""
    scans = [
        Scan(
            time_s=1.0 + k,
            angles_rad=np.linspace(-1.5, 1.5, 9),
            ranges_m=np.linspace(0.5, 4.5, 9) + k,
            range_max_m=8.0,
        )
        for k in range(3)
    ]
    path = folder / "valid.mcap"
    write_log(path, scans, [(1.0, Pose2(1.0, 2.0, 0.5))], {"range_max_m": "8"})
    logs = [path.read_bytes()]
    payloads = [
        _encode(
            {
                "timestamp": {"sec": int(s.time_s), "nsec": 0},
                "start_angle": -1.5,
                "end_angle": 1.5,
                "ranges": s.ranges_m.tolist(),
            }
        )
        for s in scans
    ]
    for layout in ("zstd", "lz4"):
        _hand_log(path, "8", payloads, [], layout)
        logs.append(path.read_bytes())
    return logs


# Where in the file, as a fraction of its length; mostly past the header and schemas, where
# the channels, metadata and messages are.
_where = st.one_of(st.floats(0.0, 1.0), st.floats(0.6, 1.0), st.floats(0.6, 1.0))
_mutation = byte_mutations(_where, length_fields=True)


@given(which=st.integers(0, 2), mutations=st.lists(_mutation, min_size=1, max_size=4))
@fuzz_settings
def test_mangled_logs(tmp_path, which, mutations):
    base = _valid_logs(tmp_path)[which]
    path = tmp_path / "mangled.mcap"
    path.write_bytes(mutate(base, mutations))
    check(path)
