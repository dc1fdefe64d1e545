"""Tests of the SCIP 2.0 codec, stream parser, emulated URG-04LX and host driver."""

from __future__ import annotations

import itertools
import math
import re
import time
from collections.abc import Callable

import numpy as np
import pytest
from conftest import HALL_POSE, HALL_WORLD, ParrotDevice, SilentDevice
from fuzzing import byte_mutations, fuzz_settings, mutate
from hypothesis import given
from hypothesis import strategies as st

from segloc_cli.devices.base import ClockUnwrapper, DeviceError, FrameError, printable
from segloc_cli.devices.scip2 import (
    MAX_REPLY_LINES,
    TIMESTAMP_MODULUS,
    URG_04LX_PARAMETERS,
    URG_04LX_VERSION,
    Reply,
    ScanDecoder,
    ScanRequest,
    Scip2Device,
    Scip2Driver,
    Scip2Stream,
    checksum,
    data_lines,
    decode_scan,
    decode_value,
    decode_values,
    describe_status,
    encode_value,
    encode_values,
    format_reply,
    parse_fields,
    parse_parameters,
    parse_reply,
    parse_scan_request,
    step_angles,
    values_to_ranges_m,
)
from segloc_cli.geometry import Pose2
from segloc_cli.io.maps import read_world
from segloc_cli.sim import NOISE_FREE, render_ranges

STEP_RAD = 2.0 * math.pi / 1024
URG_ANGLES = (np.arange(44, 726) - 384) * STEP_RAD
"""The URG-04LX's 682 beam angles from its PP values (AMIN 44, AMAX 725, AFRT 384, ARES 1024)."""

# A hand-made MD reply for steps 44..46: values 1234 ("0CB"), 5432 ("1Dh") and 7 ("007",
# an error code below DMIN); timestamp 1000 ms ("00?X"). Checksums worked out by hand:
# "0CB1Dh007" sums to 553, 553 & 63 = 41, + 48 = 89 = "Y"; "00?X" sums to 247 → "g".
HAND_MD = b"MD0044004601000\n99b\n00?Xg\n0CB1Dh007Y\n\n"


def _lines(block: bytes) -> list[bytes]:
    return block.split(b"\n")[:-2]


def _scan_block(values: list[int], timestamp_ms: int = 0, chars: int = 3) -> bytes:
    """An MD (or MS) scan reply for steps 44.. with these raw values."""
    command = "MD" if chars == 3 else "MS"
    echo = ScanRequest(command, 44, 44 + len(values) - 1).text().encode()
    stamp = encode_value(timestamp_ms, 4)
    body = stamp + bytes([checksum(stamp)]) + b"\n" + data_lines(encode_values(values, chars))
    return format_reply(echo, b"99", body)


# --- the character codec ------------------------------------------------------------------------


def test_encoding_examples_of_the_specification():
    assert decode_value(b"CB") == 1234
    assert decode_value(b"1Dh") == 5432
    assert encode_value(1234, 2) == b"CB"
    assert encode_value(5432, 3) == b"1Dh"
    assert encode_value(0, 4) == b"0000"
    assert decode_value(b"oooo") == (1 << 24) - 1


def test_values_round_trip_and_reject_what_does_not_fit():
    values = np.array([0, 1, 63, 64, 4095, 262143])
    assert np.array_equal(decode_values(encode_values(values, 3), 3), values)
    with pytest.raises(ValueError):
        encode_values(np.array([4096]), 2)
    with pytest.raises(FrameError, match="do not split"):
        decode_values(b"0000", 3)
    with pytest.raises(FrameError, match="outside"):
        decode_values(b"0p0", 3)  # 'p' = 0x70 is past the last SCIP character 0x6F


def test_checksum_of_known_lines():
    assert chr(checksum(b"00")) == "P"
    assert chr(checksum(b"99")) == "b"
    assert chr(checksum(b"02")) == "R"
    assert chr(checksum(b"0CB1Dh007")) == "Y"
    # The specification's PP example lines: the checksum covers the text before ';'.
    assert chr(checksum(b"DMIN:20")) == "4"
    assert chr(checksum(b"SCAN:600")) == "e"


# --- replies and scans --------------------------------------------------------------------------


def test_hand_made_md_reply_decodes_to_exact_millimetres_and_angles():
    reply = parse_reply(_lines(HAND_MD))
    assert (reply.echo, reply.status, reply.lines) == (
        "MD0044004601000",
        "99",
        (b"00?X", b"0CB1Dh007"),
    )
    scan = decode_scan(reply)
    assert scan.request == ScanRequest("MD", 44, 46, 1, 0, 0)
    assert scan.timestamp_ms == 1000
    assert scan.values.tolist() == [1234, 5432, 7]
    assert values_to_ranges_m(scan.values, 20, 5600).tolist() == [1.234, 5.432, 0.0]
    angles = step_angles(44, 46, 1, ares=1024, afrt=384)
    assert np.allclose(angles, [-340 * STEP_RAD, -339 * STEP_RAD, -338 * STEP_RAD], atol=1e-15)


def test_cluster_angle_is_the_mean_of_its_steps_and_the_last_cluster_may_be_short():
    angles = step_angles(44, 48, 2, ares=1024, afrt=384)
    assert np.allclose(angles / STEP_RAD, [-339.5, -337.5, -336.0])
    assert ScanRequest("MD", 44, 48, 2).readings == 3
    assert ScanRequest("MD", 44, 725, 3).readings == 228


def test_a_value_spanning_two_data_lines_is_decoded_whole():
    values = [1234] * 21 + [5432]  # the 22nd value's 3 characters straddle the 64-char line
    block = _scan_block(values)
    lines = _lines(block)
    assert lines[3] == b"0CB" * 21 + b"1" + bytes([checksum(b"0CB" * 21 + b"1")])
    assert lines[4] == b"Dh" + bytes([checksum(b"Dh")])
    assert decode_scan(parse_reply(lines)).values.tolist() == values


def test_parameter_lines_accept_both_checksum_conventions():
    spec = b"PP\n00P\nDMIN:20;4\nDMAX:5600;_\n\n"
    with_semicolon = b"PP\n00P\nDMIN:20;" + bytes([checksum(b"DMIN:20;")]) + b"\n\n"
    assert parse_fields(parse_reply(_lines(spec))) == {"DMIN": "20", "DMAX": "5600"}
    assert parse_fields(parse_reply(_lines(with_semicolon))) == {"DMIN": "20"}
    with pytest.raises(FrameError, match="bad checksum"):
        parse_reply(_lines(b"PP\n00P\nDMIN:20;5\n\n"))


def test_broken_replies_raise_frame_error():
    with pytest.raises(FrameError, match="status"):
        parse_reply([b"MD0044004601000", b"99c"])
    with pytest.raises(FrameError, match="bad checksum"):
        parse_reply(_lines(HAND_MD.replace(b"007Y", b"007Z")))
    short = b"0CB1Dh" + bytes([checksum(b"0CB1Dh")])  # two values where three are due
    with pytest.raises(FrameError, match="expected 3 values"):
        decode_scan(parse_reply(_lines(HAND_MD.replace(b"0CB1Dh007Y", short))))
    with pytest.raises(FrameError, match="not scan data"):
        decode_scan(Reply("MD0044004601000", "00", (b"00?X",)))
    with pytest.raises(FrameError, match="smaller than the starting step"):
        parse_scan_request("MD0046004401000")


def test_timestamps_unwrap_across_the_24_bit_wrap():
    unwrap = ClockUnwrapper(TIMESTAMP_MODULUS)
    raw = [TIMESTAMP_MODULUS - 150, TIMESTAMP_MODULUS - 50, 50, 150, 140]
    assert [unwrap(r) for r in raw] == [
        TIMESTAMP_MODULUS - 150,
        TIMESTAMP_MODULUS - 50,
        TIMESTAMP_MODULUS + 50,
        TIMESTAMP_MODULUS + 150,
        TIMESTAMP_MODULUS + 140,  # a small step back is jitter, not a wrap
    ]


# --- the stream parser --------------------------------------------------------------------------


def _feed_all(data: bytes, chunks: list[int] | None = None) -> list[Reply | FrameError]:
    stream, out, at = Scip2Stream(), [], 0
    for size in chunks or [len(data)]:
        out += stream.feed(data[at : at + size])
        at += size
    return out + stream.feed(data[at:])


def test_stream_gives_the_same_replies_fed_byte_by_byte():
    data = HAND_MD + b"BM\n00P\n\n" + _scan_block([100, 200])
    whole = _feed_all(data)
    assert [r.echo for r in whole] == ["MD0044004601000", "BM", "MD0044004501000"]
    assert _feed_all(data, [1] * len(data)) == whole


def test_corrupted_scan_is_reported_and_the_next_one_decoded():
    bad = _scan_block([111, 222], timestamp_ms=100)
    bad = bad[:-3] + bytes([bad[-3] ^ 1]) + bad[-2:]  # flip the data line's checksum
    items = _feed_all(bad + _scan_block([333, 444], timestamp_ms=200))
    assert isinstance(items[0], FrameError)
    assert decode_scan(items[1]).values.tolist() == [333, 444]


def test_garbage_between_and_glued_to_frames_is_dropped():
    data = (
        b"\xff\x00garbage\n"
        + _scan_block([1000], 100)
        + b"junk\x13 without newline"
        + _scan_block([2000], 200)
        + b"\n\n\x80"
        + _scan_block([3000], 300)
    )
    items = _feed_all(data)
    assert all(isinstance(i, Reply) for i in items)
    assert [decode_scan(i).values.tolist() for i in items] == [[1000], [2000], [3000]]


def test_reply_whose_end_was_lost_is_reported_and_the_next_one_kept():
    cut = _scan_block([1000, 2000], 100)[:-1]  # no empty line at the end
    items = _feed_all(cut + _scan_block([3000], 200))
    assert isinstance(items[0], FrameError) and "cut short" in str(items[0])
    assert decode_scan(items[1]).values.tolist() == [3000]


def test_reply_lines_without_their_echo_count_as_one_lost_reply():
    headless = _scan_block([1000] * 30, 100).split(b"\n", 1)[1]
    items = _feed_all(headless + _scan_block([3000], 200))
    assert isinstance(items[0], FrameError) and "without an echo" in str(items[0])
    assert decode_scan(items[1]).values.tolist() == [3000]


def _check_items(items: list[Reply | FrameError]) -> None:
    """Every item is a reply or a FrameError, and decoding a reply raises FrameError at most."""
    for item in items:
        assert isinstance(item, Reply | FrameError)
        if isinstance(item, Reply):
            for decode in (decode_scan, parse_fields):
                try:
                    decode(item)
                except FrameError:
                    pass


@given(st.binary(max_size=3000), st.lists(st.integers(1, 200), max_size=20))
@fuzz_settings
def test_fuzz_random_bytes(data, chunks):
    _check_items(_feed_all(data, chunks))


def _valid_stream(values: list[list[int]]) -> bytes:
    out = b"VV\n00P\nPROT:SCIP 2.0;N\n\n" + b"PP\n00P\nDMIN:20;4\n\n"
    for i, scan in enumerate(values):
        out += _scan_block(scan, timestamp_ms=100 * i, chars=3 if i % 2 == 0 else 2)
    return out


_SCANS = st.lists(st.lists(st.integers(0, 4095), min_size=1, max_size=60), min_size=1, max_size=4)


@given(_SCANS, st.lists(st.integers(1, 300), max_size=10))
@fuzz_settings
def test_fuzz_valid_stream_round_trips_in_any_chunks(values, chunks):
    items = _feed_all(_valid_stream(values), chunks)
    assert [i.echo[:2] for i in items[:2]] == ["VV", "PP"]
    assert [decode_scan(i).values.tolist() for i in items[2:]] == values


@given(_SCANS, st.lists(byte_mutations(), min_size=1, max_size=6), st.lists(st.integers(1, 300)))
@fuzz_settings
def test_fuzz_mutated_valid_stream(values, mutations, chunks):
    data = mutate(_valid_stream(values), mutations)
    items = _feed_all(data, chunks)
    _check_items(items)
    assert len(items) <= data.count(b"\n")  # bounded: at most one item per line


# --- bounds on what a device reports -------------------------------------------------------------

PORT = "/dev/ttyACM7"
URG_PP = parse_parameters(URG_04LX_PARAMETERS, PORT)


def test_the_urg_04lx_parameters_pass_as_numbers():
    assert URG_PP == {
        "DMIN": 20,
        "DMAX": 5600,
        "ARES": 1024,
        "AMIN": 44,
        "AMAX": 725,
        "AFRT": 384,
        "SCAN": 600,
    }


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        (
            "AMAX",
            "99999999999",
            "PP parameter AMAX=99999999999 is out of bounds (the last step must be "
            "0..1023: below ARES=1024, at most 9999)",
        ),
        ("ARES", "0", "ARES=0 is out of bounds (steps per revolution must be 1..65536)"),
        ("ARES", "65537", "ARES=65537 is out of bounds (steps per revolution must be 1..65536)"),
        ("AMAX", "1024", "AMAX=1024 is out of bounds (the last step must be 0..1023"),
        ("AFRT", "726", "AFRT=726 is out of bounds (the front step must be 0..AMAX=725)"),
        ("AMIN", "385", "AMIN=385 is out of bounds (the first step must be 0..AFRT=384)"),
        ("DMAX", "262144", "DMAX=262144 is out of bounds (the largest range must be 2..262143 mm)"),
        ("DMIN", "0", "DMIN=0 is out of bounds (the smallest range must be 1..5599 mm)"),
        ("DMIN", "5600", "DMIN=5600 is out of bounds (the smallest range must be 1..5599 mm)"),
        ("SCAN", "0", "SCAN=0 is out of bounds (the motor speed must be 60..6000 rpm)"),
        ("SCAN", "1" * 40, "SCAN=" + "1" * 32 + "... is out of bounds"),
        ("DMIN", "-20", "the PP reply lacks a number for DMIN (got '-20')"),
        ("AFRT", "3\x1b[2J", "lacks a number for AFRT (got '3\\x1b[2J')"),
        ("SCAN", "", "the PP reply lacks a number for SCAN (got nothing)"),
    ],
)
def test_pp_numbers_out_of_bounds_are_refused_naming_the_field_and_value(field, value, message):
    fields = {**URG_04LX_PARAMETERS, field: value}
    with pytest.raises(DeviceError) as error:
        parse_parameters(fields, PORT)
    text = str(error.value)
    assert text.startswith(f"{PORT}: ") and message in text and "\n" not in text


def test_real_scanner_geometries_pass():
    utm_30lx = {"DMIN": "23", "DMAX": "60000", "ARES": "1440", "AMIN": "0", "AMAX": "1080"}
    fields = {**URG_04LX_PARAMETERS, **utm_30lx, "AFRT": "540", "SCAN": "2400"}
    assert parse_parameters(fields, PORT)["AMAX"] == 1080


def test_device_text_is_made_printable_on_one_line():
    assert printable("URG\x1b[31m\nX\xe9") == "URG\\x1b[31m\\nX\\xe9"
    assert printable(b"\xff ok") == "\\xff ok"
    assert printable("a" * 40, 4) == "aaaa..."


def test_a_scan_of_2161_steps_fits_in_one_reply():
    # A 0.125° scanner (ARES 2880) over 270°: 2161 values in 3 characters is 102 data lines.
    values = np.arange(2161) % 5000 + 20
    echo = ScanRequest("MD", 0, 2160).text().encode()
    body = b"0000" + bytes([checksum(b"0000")]) + b"\n" + data_lines(encode_values(values, 3))
    block = format_reply(echo, b"99", body)
    assert block.count(b"\n") - 1 == 3 + 102 <= MAX_REPLY_LINES
    (reply,) = Scip2Stream().feed(block)
    assert decode_scan(reply).values.tolist() == values.tolist()


def test_decoder_skips_a_scan_whose_size_disagrees_and_ignores_other_requests():
    decoder = ScanDecoder(URG_PP, ScanRequest("MD", 44, 46), PORT)
    short = b"0CB1Dh" + bytes([checksum(b"0CB1Dh")])  # two values where three are due
    with pytest.raises(FrameError, match="expected 3 values"):
        decoder.take(parse_reply(_lines(HAND_MD.replace(b"0CB1Dh007Y", short))))
    frame = decoder.take(parse_reply(_lines(HAND_MD)))
    assert (frame.sequence, frame.device_time_s) == (0, 1.0)
    assert frame.ranges_m.tolist() == [1.234, 5.432, 0.0] and frame.range_max_m == 5.6
    other = HAND_MD.replace(b"MD0044004601000", b"MD0044004602000")  # cluster 2: not ours
    assert decoder.take(parse_reply(_lines(other))) is None
    stopped = Reply("MD0044004601000", "50")
    with pytest.raises(
        DeviceError, match=r"^/dev/ttyACM7: the scanner stopped scanning: status 50"
    ):
        decoder.take(stopped)


# --- the emulated URG-04LX ----------------------------------------------------------------------


def _ramp_render(angles_rad: np.ndarray) -> np.ndarray:
    """1 m at step 0 growing 1 mm per step: a scan whose every value tells its step."""
    steps = np.round(np.asarray(angles_rad) / STEP_RAD) + 384
    return 1.0 + steps / 1000.0


def test_device_answers_vv_pp_bm_qt_as_the_specification_lays_them_out():
    device = Scip2Device(_ramp_render)
    vv = device.receive(b"VV\n", 0.0)
    lines = vv.split(b"\n")
    assert lines[:2] == [b"VV", b"00P"] and vv.endswith(b"\n\n")
    for line in lines[2:-2]:
        text, semicolon, check = line.rpartition(b";")
        assert semicolon and check == bytes([checksum(text)])
    assert parse_fields(parse_reply(_lines(vv)))["PROD"].endswith("URG-04LX")

    pp = device.receive(b"PP\n", 0.0)
    for expected in (b"DMIN:20;4\n", b"DMAX:5600;_\n", b"AMIN:44;7\n", b"AFRT:384;6\n"):
        assert expected in pp
    fields = parse_fields(parse_reply(_lines(pp)))
    assert {k: fields[k] for k in ("ARES", "AMAX", "SCAN")} == {
        "ARES": "1024",
        "AMAX": "725",
        "SCAN": "600",
    }
    assert device.receive(b"BM\n", 0.0) == b"BM\n00P\n\n"
    assert device.receive(b"BM\n", 0.0) == b"BM\n02R\n\n"
    assert device.receive(b"QT\n", 0.0) == b"QT\n00P\n\n"
    assert not device.laser_on


def test_device_buffers_partial_commands_and_takes_cr_lf():
    device = Scip2Device(_ramp_render)
    assert device.receive(b"B", 0.0) == b""
    assert device.receive(b"M\r\nQT\rX", 0.0) == b"BM\n00P\n\nQT\n00P\n\n"
    assert device.receive(b"Y\n", 0.0) == b"XY\n0Ee\n\n"  # unknown command


@pytest.mark.parametrize(
    ("command", "status"),
    [
        (b"MD00x4072501000", b"01"),
        (b"MD0044072x01000", b"02"),
        (b"GD004407250", b"03"),
        (b"MD004408000100", b"07"),
        (b"MD0044080001000", b"04"),
        (b"MD0725004401000", b"05"),
        (b"GD0044072501", b"10"),  # laser still off
    ],
)
def test_device_rejects_bad_scan_commands_with_the_specification_status(command, status):
    reply = Scip2Device(_ramp_render).receive(command + b"\n", 0.0)
    assert reply == command + b"\n" + status + bytes([checksum(status)]) + b"\n\n"


def test_device_md_stream_round_trips_through_the_host_parser():
    device = Scip2Device(_ramp_render, clock_start_ms=5000)
    assert device.receive(b"MD0044072501003\n", 0.05) == b"MD0044072501003\n00P\n\n"
    assert device.laser_on
    frames = device.poll(0.35) + device.poll(0.6)
    assert len(frames) == 3  # three asked for, due at 0.1, 0.2 and 0.3 s
    replies = _feed_all(b"".join(frames))
    assert [r.echo for r in replies] == ["MD0044072501002", "MD0044072501001", "MD0044072501000"]
    for k, reply in enumerate(replies):
        assert reply.status == "99"
        scan = decode_scan(reply)
        assert scan.timestamp_ms == 5000 + 100 * (k + 1)
        assert scan.values.tolist() == (1000 + np.arange(44, 726)).tolist()


def test_device_gd_cluster_takes_the_nearest_valid_range():
    def render(angles_rad: np.ndarray) -> np.ndarray:
        ranges = _ramp_render(angles_rad)
        ranges[0] = 0.0  # step 44: no return, so its cluster keeps step 45
        ranges[2:4] = [9.0, 0.01]  # steps 46, 47: beyond DMAX and below DMIN
        return ranges

    device = Scip2Device(render)
    device.receive(b"BM\n", 0.0)
    reply = device.receive(b"GD0044004902\n", 0.25)
    assert reply.startswith(b"GD0044004902\n00P\n")
    scan = decode_scan(_feed_all(reply)[0])
    assert scan.timestamp_ms == 250
    assert scan.values.tolist() == [1045, 1, 1048]  # (44, 45) (46, 47) (48, 49)


def test_device_ms_reports_ranges_beyond_12_bits_as_no_return():
    device = Scip2Device(lambda a: np.where(np.arange(a.size) % 2 == 0, 4.095, 4.2))
    device.receive(b"MS0044004701001\n", 0.0)
    scan = decode_scan(_feed_all(device.poll(0.1)[0])[0])
    assert values_to_ranges_m(scan.values, 20, 5600).tolist() == [4.095, 0.0, 4.095, 0.0]


def test_device_spoils_the_checksum_when_told():
    device = Scip2Device(_ramp_render, corrupt=lambda: True)
    device.receive(b"MD0044004501000\n", 0.0)
    items = _feed_all(device.poll(0.1)[0])
    assert len(items) == 1 and "bad checksum" in str(items[0])


# --- the host driver against scripted devices in another process -------------------------------


class NoisyUrg(Scip2Device):
    """A ramp URG that sends a burst of noise before every scan frame, the bursts in turn."""

    def __init__(self, bursts: list[bytes]):
        super().__init__(_ramp_render)
        self.bursts = itertools.cycle(bursts)

    def poll(self, now_s: float) -> list[bytes]:
        return [next(self.bursts) + frame for frame in super().poll(now_s)]


class WrappingUrg(Scip2Device):
    """A ramp URG whose clock reads 150 ms short of its 24-bit wrap at the first MD scan.

    Scans fall due on multiples of the period after the MD command, so the clock
    is set when MD is accepted: the scans then read 2²⁴ − 150, 2²⁴ − 50, 50, 150 ms.
    """

    def receive(self, data: bytes, now_s: float) -> bytes:
        reply = super().receive(data, now_s)
        if re.search(rb"MD\d{13}\n00P\n", reply):
            first_due_ms = round((math.floor(now_s / self.period_s) + 1) * self.period_s * 1000)
            self.clock_start_ms = (TIMESTAMP_MODULUS - 150 - first_due_ms) % TIMESTAMP_MODULUS
        return reply


@pytest.fixture
def urg(driver_on) -> Callable[..., Scip2Driver]:
    """``driver = urg(make_device, timeout_s)``: a driver opened on a device served by
    another process; closed at teardown."""
    return lambda make_device, timeout_s=1.0: driver_on(Scip2Driver, make_device, timeout_s)


def _ask(driver: Scip2Driver, command: str, within_s: float = 1.0) -> Reply:
    """Send ``command`` on the driver's port and return the device's reply to it."""
    stream = Scip2Stream()
    driver.write(command.encode("ascii") + b"\n")
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        for item in stream.feed(driver.read_available()):
            if isinstance(item, Reply) and item.echo == command:
                return item
    raise AssertionError(f"no reply to {command} within {within_s} s")


def _ramp_urg(corrupt: Callable[[], bool] = lambda: False) -> Callable[[], Scip2Device]:
    return lambda: Scip2Device(_ramp_render, corrupt=corrupt)


def test_driver_identifies_configures_and_reads_scans(urg):
    driver = urg(_ramp_urg())
    info = driver.identify()
    assert (info.model, info.serial_number) == ("SOKUIKI Sensor URG-04LX", "H0807301")
    assert info.extra["protocol_version"] == "SCIP 2.0"
    settings = driver.configure(None, 10.0)
    assert settings["readings"] == "682" and settings["cluster"] == "1"
    assert (settings["range_max_m"], settings["range_min_m"]) == ("5.6", "0.02")
    assert float(settings["angle_min_rad"]) == pytest.approx(URG_ANGLES[0], abs=1e-12)
    assert float(settings["angle_max_rad"]) == pytest.approx(URG_ANGLES[-1], abs=1e-12)
    assert settings["pp.AFRT"] == "384" and settings["encoding"] == "MD"
    driver.start()
    frames = [driver.read_scan() for _ in range(3)]
    assert [f.sequence for f in frames] == [0, 1, 2]
    assert np.diff([f.device_time_s for f in frames]) == pytest.approx([0.1, 0.1])
    for frame in frames:
        assert np.allclose(frame.angles_rad, URG_ANGLES, atol=1e-12)
        assert np.allclose(frame.ranges_m, 1.0 + np.arange(44, 726) / 1000.0)
        assert frame.range_max_m == 5.6
    driver.stop()
    state = parse_fields(_ask(driver, "II"))  # the device's own word on its laser
    assert (state["LASR"], state["MESM"]) == ("OFF", "Idle")
    assert driver.skipped == 0


def test_driver_skips_and_counts_a_corrupted_scan_and_decodes_the_next(urg):
    spoiled = itertools.chain([False, True], itertools.repeat(False))
    driver = urg(_ramp_urg(corrupt=spoiled.__next__))
    driver.identify()
    driver.configure(None, None)
    driver.start()
    first, second = driver.read_scan(), driver.read_scan()
    assert (first.sequence, second.sequence) == (0, 1)
    assert second.device_time_s - first.device_time_s == pytest.approx(0.2)  # one scan lost
    assert driver.skipped == 1


def test_driver_reads_through_garbage_between_frames(urg):
    driver = urg(lambda: NoisyUrg([b"\xfe\xff\n\x00zz", b"MD\n\n", b"\x07QT", b"99b\n"]))
    driver.identify()
    driver.configure(None, None)
    driver.start()
    times = [driver.read_scan().device_time_s for _ in range(6)]
    assert np.diff(times) == pytest.approx([0.1] * 5)
    assert driver.skipped == 0


def test_driver_unwraps_the_device_clock(urg):
    driver = urg(lambda: WrappingUrg(_ramp_render))
    driver.identify()
    driver.configure(341, None)
    driver.start()
    times = [driver.read_scan().device_time_s for _ in range(4)]
    wrap_s = TIMESTAMP_MODULUS / 1000.0
    assert times == pytest.approx([wrap_s - 0.15, wrap_s - 0.05, wrap_s + 0.05, wrap_s + 0.15])
    assert np.diff(times) == pytest.approx([0.1] * 3)


def test_driver_cluster_two_gives_341_readings_at_mean_angles(urg):
    driver = urg(_ramp_urg())
    driver.identify()
    assert driver.configure(341, None)["cluster"] == "2"
    driver.start()
    frame = driver.read_scan()
    assert frame.ranges_m.size == 341
    assert np.allclose(frame.angles_rad, (URG_ANGLES[0::2] + URG_ANGLES[1::2]) / 2, atol=1e-12)
    assert np.allclose(frame.ranges_m, 1.0 + np.arange(44, 726, 2) / 1000.0)  # the nearer step


def test_driver_refuses_settings_the_urg_cannot_take(urg):
    driver = urg(_ramp_urg())
    driver.identify()
    with pytest.raises(
        DeviceError, match=r"cannot give 500 readings.*possible: 682, 341, 62, 31, 22, 11$"
    ):
        driver.configure(500, None)
    with pytest.raises(DeviceError, match=r"fixed 10 rev/s \(600 rpm\).*5 rev/s"):
        driver.configure(None, 5.0)


def test_driver_without_an_answer_says_what_to_check(urg):
    driver = urg(SilentDevice, timeout_s=0.2)
    with pytest.raises(DeviceError) as err:
        driver.identify()
    assert str(err.value) == (
        f"{driver.port}: no answer to VV (version request) within 0.2 s; "
        "check the protocol name, baud rate and cable"
    )


def test_driver_facing_another_protocol_says_it_is_not_scip2(urg):
    driver = urg(lambda: ParrotDevice(bytes(range(256))), timeout_s=0.2)
    with pytest.raises(DeviceError, match=r"not in SCIP 2\.0.*other protocols: explorer"):
        driver.identify()


def test_driver_refuses_a_urg_reporting_an_impossible_last_step(urg):
    bogus = {**URG_04LX_PARAMETERS, "AMAX": "99999999999"}
    driver = urg(lambda: Scip2Device(_ramp_render, parameters=bogus))
    with pytest.raises(DeviceError) as error:
        driver.identify()
    assert str(error.value) == (
        f"{driver.port}: the device's PP parameter AMAX=99999999999 is out of bounds "
        "(the last step must be 0..1023: below ARES=1024, at most 9999); "
        "refusing a device that reports it"
    )


def test_driver_keeps_device_text_printable(urg):
    version = {**URG_04LX_VERSION, "PROD": "URG\x1b[31m", "SERI": "H\x07"}
    driver = urg(lambda: Scip2Device(_ramp_render, version=version))
    info = driver.identify()
    assert (info.model, info.serial_number) == ("URG\\x1b[31m", "H\\x07")


# --- through a pseudo-terminal, the emulator in another process ---------------------------------


def _expected_ranges_m(angles_rad: np.ndarray) -> np.ndarray:
    """What a URG-04LX at the fixture's pose reads without noise: 0 beyond 5.6 m."""
    pose = Pose2.from_deg(*HALL_POSE)
    rng = np.random.default_rng(0)  # unused by NOISE_FREE: glass is transparent, no noise
    exact = render_ranges(read_world(HALL_WORLD), pose, angles_rad, NOISE_FREE, rng)
    return np.where((exact >= 0.02) & (exact <= 5.6), exact, 0.0)


def _agreement(measured: np.ndarray, expected: np.ndarray, tol_m: float = 0.05) -> float:
    """Fraction of beams that agree within ``tol_m`` (both 0 counts as agreeing)."""
    return float(np.mean(np.abs(measured - expected) <= tol_m))


def test_pty_identify_configure_and_scan_the_hall(emulator):
    driver = Scip2Driver(emulator("scip2"), timeout_s=2.0)
    driver.open()
    try:
        info = driver.identify()
        assert "URG-04LX" in info.model and info.serial_number == "H0807301"
        with pytest.raises(DeviceError, match="possible: 682, 341"):
            driver.configure(500, None)
        assert driver.configure(None, 10.0)["readings"] == "682"
        driver.start()
        frames = [driver.read_scan() for _ in range(3)]
    finally:
        driver.stop()
        driver.close()
    expected = _expected_ranges_m(URG_ANGLES)
    assert np.count_nonzero(expected) > 100
    for frame in frames:
        assert np.allclose(frame.angles_rad, URG_ANGLES, atol=1e-12)
        # 1.2 cm noise, glass, dropouts and clutter: most beams, not all, within 5 cm. A
        # clutter object 0.3-0.6 m wide at 0.8-5 m covers about 30 of these 0.35° beams,
        # and 1.5 of them come per scan on average: some 7 % of the fan.
        assert _agreement(frame.ranges_m, expected) > 0.85
    assert np.diff([f.device_time_s for f in frames]) == pytest.approx([0.1, 0.1])
    assert driver.skipped == 0


def test_pty_cluster_of_two(emulator):
    driver = Scip2Driver(emulator("scip2"), timeout_s=2.0)
    driver.open()
    try:
        driver.identify()
        driver.configure(341, None)
        driver.start()
        frame = driver.read_scan()
    finally:
        driver.stop()
        driver.close()
    pairs = _expected_ranges_m(URG_ANGLES).reshape(-1, 2)
    nearest = np.where(pairs > 0, pairs, np.inf).min(axis=1)
    expected = np.where(np.isfinite(nearest), nearest, 0.0)
    assert frame.ranges_m.size == 341
    assert _agreement(frame.ranges_m, expected) > 0.9


def test_pty_checksum_faults_are_skipped_while_scans_keep_coming(emulator):
    port = emulator("scip2", "--faults", "checksum", "--fault-rate", "0.4")
    driver = Scip2Driver(port, timeout_s=2.0)
    driver.open()
    try:
        driver.identify()
        driver.configure(None, None)
        driver.start()
        frames = [driver.read_scan() for _ in range(12)]
    finally:
        driver.stop()
        driver.close()
    assert [f.sequence for f in frames] == list(range(12))
    gaps = np.diff([f.device_time_s for f in frames]) / 0.1
    scans_apart = np.round(gaps)
    assert np.allclose(gaps, scans_apart) and np.all(scans_apart >= 1)
    # Every scan lost between two delivered ones is counted (and any lost before the first).
    assert driver.skipped >= int(scans_apart.sum()) - 11 > 0


def test_pty_stalled_device_gives_none_not_a_hang(emulator):
    port = emulator("scip2", "--faults", "stall", "--fault-after", "2")
    driver = Scip2Driver(port, timeout_s=0.3)
    driver.open()
    try:
        driver.identify()
        driver.configure(None, None)
        driver.start()
        frames = [driver.read_scan() for _ in range(3)]
    finally:
        driver.stop()
        driver.close()
    assert [f is None for f in frames] == [False, False, True]


@pytest.mark.parametrize(
    ("status", "words"),
    [
        ("25", "processing stopped to check an error"),
        ("60", "hardware trouble (laser or motor)"),
        ("\u00b99", "unknown status"),  # a superscript one: a digit to str.isdigit, not to int()
        ("\u0661\u0662", "unknown status"),  # Arabic-Indic digits
        ("zz", "unknown status"),
    ],
)
def test_status_words_for_any_two_characters(status, words):
    assert describe_status(status) == words
