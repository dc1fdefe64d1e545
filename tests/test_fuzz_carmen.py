"""CARMEN logs of arbitrary and mangled bytes: a usable log or one line naming the file.

Every outcome of ``read_carmen`` must be either a ``Log`` whose scans have
finite, strictly increasing times and finite beam angles, or an ``InputError``
of one line that names the file; nothing else may escape.
"""

from __future__ import annotations

import gzip

import numpy as np
from fuzzing import ODD_TOKENS, fuzz_settings, outcome
from hypothesis import given
from hypothesis import strategies as st

from segloc_cli.errors import InputError
from segloc_cli.io.carmen import read_carmen
from segloc_cli.io.log import Log

RECORD_KINDS = ["FLASER", "RLASER", "ROBOTLASER1", "ODOM", "PARAM", "SYNC", "# comment"]


def check(result, path) -> None:
    """The outcome of one read is a sound log or a one-line error (checked by ``outcome``)."""
    if isinstance(result, InputError):
        return
    assert isinstance(result, Log)
    times = np.array([scan.time_s for scan in result.scans], dtype=float)
    assert times.size > 0
    assert np.all(np.isfinite(times))
    assert np.all(np.diff(times) > 0)
    np.testing.assert_array_equal(result.odom_times_s, times)
    assert result.original_times_s.shape == times.shape
    assert np.all(np.isfinite(result.original_times_s))
    assert result.odom_poses.shape == result.laser_poses.shape == (times.size, 3)
    for scan in result.scans:
        assert np.all(np.isfinite(scan.angles_rad))
        assert len(scan.angles_rad) == len(scan.ranges_m) > 0
    for warning in result.warnings:
        assert "\n" not in warning and "\r" not in warning
        assert warning.startswith(f"{path}: ")


def read(tmp_path, data: bytes, name: str = "fuzz.log"):
    path = tmp_path / name
    path.write_bytes(data)
    result = outcome(read_carmen, path)
    check(result, path)
    return result


# --- arbitrary bytes ------------------------------------------------------------------


@given(st.binary(max_size=2000))
@fuzz_settings
def test_arbitrary_bytes(tmp_path, data):
    read(tmp_path, data)


@given(st.binary(max_size=2000), st.integers(min_value=0, max_value=4000))
@fuzz_settings
def test_arbitrary_bytes_gzipped_and_cut(tmp_path, data, cut):
    packed = gzip.compress(data)
    read(tmp_path, packed, "whole.log.gz")
    read(tmp_path, packed[: cut % (len(packed) + 1)], "cut.log.gz")


# --- structured, then mangled ------------------------------------------------------------


def number() -> st.SearchStrategy[str]:
    return st.one_of(
        st.floats(min_value=-100.0, max_value=100.0, allow_nan=False).map(repr),
        st.sampled_from(["81.83", "0.5", "2.0", "50"]),
        st.sampled_from(ODD_TOKENS),
    )


@st.composite
def laser_record(draw) -> str:
    kind = draw(st.sampled_from(["FLASER", "RLASER"]))
    n = draw(st.integers(min_value=0, max_value=12))
    ranges = draw(st.lists(number(), min_size=n, max_size=n))
    pose = draw(st.lists(number(), min_size=6, max_size=6))
    time = draw(st.one_of(st.sampled_from(["0", "1.13486e+09", "12.5"]), number()))
    count = draw(st.one_of(st.just(str(n)), st.sampled_from(ODD_TOKENS)))
    return " ".join([kind, count, *ranges, *pose, time, "host", time])


@st.composite
def robotlaser_record(draw) -> str:
    n = draw(st.integers(min_value=0, max_value=8))
    k = draw(st.sampled_from([0, n]))
    config = draw(st.lists(number(), min_size=7, max_size=7))
    ranges = draw(st.lists(number(), min_size=n, max_size=n))
    remissions = draw(st.lists(number(), min_size=k, max_size=k))
    rest = draw(st.lists(number(), min_size=11, max_size=11))
    time = draw(number())
    return " ".join(
        ["ROBOTLASER1", *config, str(n), *ranges, str(k), *remissions, *rest, time, "h", time]
    )


@st.composite
def other_record(draw) -> str:
    kind = draw(st.sampled_from(RECORD_KINDS))
    if kind == "PARAM":
        name = draw(
            st.sampled_from(
                ["robot_front_laser_max", "robot_frontlaser_offset", "robot_rear_laser_max"]
            )
        )
        return f"PARAM {name} {draw(number())} h 0"
    fields = draw(st.lists(number(), min_size=0, max_size=10))
    return " ".join([kind, *fields])


@st.composite
def mangled_log(draw) -> bytes:
    lines = draw(
        st.lists(
            st.one_of(laser_record(), robotlaser_record(), other_record()), min_size=1, max_size=12
        )
    )
    text = "\n".join(lines) + draw(st.sampled_from(["\n", "", "\r\n", "\x00"]))
    data = bytearray(text.encode("utf-8"))
    # A few bytes overwritten anywhere: NULs, line ends, invalid UTF-8.
    for _ in range(draw(st.integers(min_value=0, max_value=3))):
        if data:
            at = draw(st.integers(min_value=0, max_value=len(data) - 1))
            data[at] = draw(st.sampled_from([0x00, 0x0A, 0x0D, 0xFF, 0x20, 0x2D]))
    return bytes(data)


@given(mangled_log())
@fuzz_settings
def test_mangled_records(tmp_path, data):
    read(tmp_path, data)


@given(mangled_log(), st.integers(min_value=0, max_value=1 << 16), st.integers(0, 255))
@fuzz_settings
def test_mangled_records_in_damaged_gzip(tmp_path, data, at, value):
    packed = bytearray(gzip.compress(data))
    read(tmp_path, bytes(packed[: at % (len(packed) + 1)]), "cut.log.gz")
    packed[at % len(packed)] ^= value  # one byte spoiled: header, data or trailer
    read(tmp_path, bytes(packed), "spoiled.log.gz")
    # Two members, the first with a checksum that does not match: both are read.
    good = gzip.compress(data)
    first = bytearray(good)
    first[-8] ^= 0x01
    result = read(tmp_path, bytes(first) + good, "two.log.gz")
    if isinstance(result, Log):
        notes = " ".join(result.warnings)
        assert "the checksum at the end of the compressed data does not match" in notes


@given(st.lists(st.sampled_from(["0", "0.0", "1.13486e+09", "1.13487e+09", "5", "4.999"])))
@fuzz_settings
def test_colliding_times(tmp_path, times):
    lines = [f"FLASER 3 1 2 2 {k} 0 0 {k} 0 0 {t} h {t}" for k, t in enumerate(times)]
    result = read(tmp_path, ("\n".join(lines) + "\n").encode())
    if isinstance(result, Log):
        np.testing.assert_array_equal(result.original_times_s, [float(t) for t in times])
        np.testing.assert_array_equal(result.laser_poses[:, 0], np.arange(len(times)))
    else:
        # No records, or a last group spaced by a gap of 1e9 s that runs past the limit.
        assert not times or "made distinct, run past" in str(result)
