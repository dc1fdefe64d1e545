"""The Explorer protocol: codec, stream parser, emulated device and driver.

Pure codec and parser tests first (hand-made bytes, round trips, fuzzing),
then the device's answers read back through the host parser, then the driver
on a pseudo-terminal with the device in another process: scripted devices
served by the emulator's loop, and `segloc emulate` itself.
"""

from __future__ import annotations

import itertools
import re
import struct
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import HALL_POSE, HALL_WORLD, ParrotDevice, SilentDevice
from fuzzing import fuzz_settings
from hypothesis import given
from hypothesis import strategies as st

from segloc_cli.devices.base import ClockUnwrapper, DeviceError
from segloc_cli.devices.explorer import (
    CLOCK_WRAP_US,
    MAX_FRAME,
    ConfigAck,
    Configure,
    Empty,
    ExplorerDevice,
    ExplorerDriver,
    ExplorerStream,
    Frame,
    FrameError,
    Identity,
    Kind,
    Nak,
    NakCode,
    ScanDecoder,
    ScanMessage,
    crc16_ccitt_false,
    decode_frame,
    decode_message,
    encode_frame,
    encode_message,
    ranges_to_mm,
)
from segloc_cli.geometry import Pose2
from segloc_cli.io.maps import read_world
from segloc_cli.sim import NOISE_FREE, render_ranges

DOC = Path(__file__).resolve().parents[1] / "docs" / "explorer-protocol.md"


def scan_message(readings: int = 128, timestamp_us: int = 0, first: int = 0) -> ScanMessage:
    ranges = (np.arange(readings, dtype=np.uint16) * 7 + 1000).astype(np.uint16)
    return ScanMessage(timestamp_us, 250, first, ranges)


def spoil(frame: bytes) -> bytes:
    """The same frame with its CRC's last byte changed."""
    return frame[:-1] + bytes([frame[-1] ^ 0x5A])


def same_message(a, b) -> bool:
    if isinstance(a, ScanMessage) and isinstance(b, ScanMessage):
        return (a.timestamp_us, a.rev_hundredths, a.first_angle) == (
            b.timestamp_us,
            b.rev_hundredths,
            b.first_angle,
        ) and np.array_equal(a.ranges_mm, b.ranges_mm)
    return a == b


# -- CRC and codec -------------------------------------------------------------------


def crc_bitwise(data: bytes) -> int:
    """CRC-16/CCITT-FALSE the slow way, straight from its definition."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


def test_crc_matches_the_catalogued_check_value():
    assert crc16_ccitt_false(b"123456789") == 0x29B1
    assert crc16_ccitt_false(b"") == 0xFFFF


@given(st.binary(max_size=64))
@fuzz_settings
def test_crc_matches_its_definition(data):
    assert crc16_ccitt_false(data) == crc_bitwise(data)


EVERY_MESSAGE = [
    Empty(Kind.IDENTIFY),
    Configure(2048, 50),
    Empty(Kind.START),
    Empty(Kind.STOP),
    Identity("SEO Explorer", "SN-12345", "3.1"),
    ConfigAck(128, 400, 30000),
    Empty(Kind.START_ACK),
    Empty(Kind.STOP_ACK),
    Nak(NakCode.BAD_SPEED, Kind.CONFIGURE),
    scan_message(128, 123_456, 40_000),
    scan_message(2048, CLOCK_WRAP_US - 1, 65_535),
]


@pytest.mark.parametrize("message", EVERY_MESSAGE, ids=lambda m: m.kind.name)
@pytest.mark.parametrize("sequence", [0, 65_535])
def test_every_message_survives_a_round_trip(message, sequence):
    data = encode_message(message, sequence)
    frame = decode_frame(data)
    assert (frame.kind, frame.sequence) == (message.kind, sequence)
    assert same_message(decode_message(frame), message)
    assert ExplorerStream().feed(data) == [frame]


def test_a_hand_made_scan_frame_decodes_exactly():
    ranges = [1000, 0, 29_999, 0x5AA5] + [0x1234] * 124
    body = (
        bytes([0x90, 0x0A, 0x01, 0x34, 0x12])  # SCAN, length 266, sequence 0x1234
        + bytes([0x04, 0x03, 0x02, 0x01])  # timestamp 0x01020304 µs
        + bytes([0x80, 0x00, 0xC8, 0x00, 0x00, 0x40])  # 128 readings, 2.00 rev/s, 90°
        + b"".join(r.to_bytes(2, "little") for r in ranges)
    )
    data = b"\xa5\x5a" + body + crc_bitwise(body).to_bytes(2, "little")
    frame = decode_frame(data)
    assert (frame.kind, frame.sequence) == (Kind.SCAN, 0x1234)
    scan = decode_message(frame)
    assert (scan.timestamp_us, scan.rev_hundredths, scan.first_angle) == (0x01020304, 200, 0x4000)
    assert scan.ranges_mm.dtype == np.uint16
    assert scan.ranges_mm.tolist() == ranges


def test_frames_that_are_wrong_say_why():
    good = encode_message(Configure(256, 400), 1)
    cases = [
        (good[:5], "shorter than any frame"),
        (b"\x00" + good[1:], "no sync bytes"),
        (good[:3] + b"\x05\x00" + good[5:], "type 0x02 with a 5-byte payload does not exist"),
        (b"\xa5\x5a\x42\x00\x00\x00\x00\x00\x00", "type 0x42"),
        (good + b"\x00", "14 bytes for a frame of 13"),
        (spoil(good), "CRC 0x"),
    ]
    for data, reason in cases:
        with pytest.raises(FrameError, match=re.escape(reason)):
            decode_frame(data)


def test_a_scan_whose_count_disagrees_with_its_length_is_a_frame_error():
    payload = struct.pack("<IHHH", 0, 256, 200, 0) + bytes(2 * 128)
    frame = decode_frame(_raw_frame(Kind.SCAN, 0, payload))
    with pytest.raises(FrameError, match="says 256 readings but carries 266 bytes"):
        decode_message(frame)


def test_identity_text_must_be_padded_ascii():
    payload = b"Explorer\x00x" + bytes(6) + bytes(16) + bytes(8)
    with pytest.raises(FrameError, match="not NUL-padded printable ASCII"):
        decode_message(Frame(Kind.IDENTITY, 0, payload))
    with pytest.raises(ValueError, match="at most"):
        encode_message(Identity("a" * 17, "", ""), 0)


def test_ranges_are_millimetres_with_zero_for_no_return_or_beyond_30_m():
    ranges_m = np.array([1.2344, 1.2346, 0.0, -1.0, np.nan, np.inf, 29.999, 29.9996, 30.0, 45.0])
    assert ranges_to_mm(ranges_m).tolist() == [1234, 1235, 0, 0, 0, 0, 29_999, 0, 0, 0]


def _raw_frame(kind: int, sequence: int, payload: bytes) -> bytes:
    body = struct.pack("<BHH", kind, len(payload), sequence) + payload
    return b"\xa5\x5a" + body + crc_bitwise(body).to_bytes(2, "little")


# -- the document's worked example -----------------------------------------------------


def worked_example_frames() -> list[bytes]:
    """The hex blocks of the document's "Worked example" section, as bytes."""
    text = DOC.read_text(encoding="utf-8")
    section = text.split("## Worked example", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```text\n(.*?)```", section, flags=re.DOTALL)
    return [bytes.fromhex(block) for block in blocks]


def test_the_documented_example_frames_decode_as_documented():
    request, reply = worked_example_frames()
    frame = decode_frame(request)
    assert (frame.kind, frame.sequence) == (Kind.CONFIGURE, 7)
    assert decode_message(frame) == Configure(readings=256, rev_hundredths=400)
    assert int.from_bytes(request[-2:], "little") == crc_bitwise(request[2:-2]) == 0x26C3
    frame = decode_frame(reply)
    assert (frame.kind, frame.sequence) == (Kind.CONFIG_ACK, 7)
    assert decode_message(frame) == ConfigAck(256, 400, 30_000)
    assert encode_message(ConfigAck(256, 400, 30_000), 7) == reply
    # and the emulated device gives exactly that answer to exactly that request
    assert ExplorerDevice(np.zeros_like).receive(request, 0.0) == reply


# -- the stream parser ---------------------------------------------------------------


def some_frames() -> list[bytes]:
    return [encode_message(m, i) for i, m in enumerate(EVERY_MESSAGE[:-1])]


def feed_all(stream: ExplorerStream, data: bytes, chunk: int | None = None) -> list[Frame]:
    if chunk is None:
        return stream.feed(data)
    frames = []
    for i in range(0, len(data), chunk):
        frames += stream.feed(data[i : i + chunk])
    return frames


def test_a_spoiled_frame_is_skipped_counted_and_the_next_one_decoded():
    a, b, c, d = (encode_message(scan_message(256, t), t) for t in range(4))
    stream = ExplorerStream()
    frames = stream.feed(a + spoil(b) + c)
    assert [f.sequence for f in frames] == [0, 2]
    assert stream.dropped == 1
    # two spoiled frames in a row count as two
    frames = stream.feed(spoil(a) + spoil(b) + d)
    assert [f.sequence for f in frames] == [3]
    assert stream.dropped == 3


@pytest.mark.parametrize("chunk", [None, 1, 7])
def test_garbage_between_frames_and_frames_split_in_pieces(chunk):
    frames = some_frames()
    garbage = b"\x00\xa5\x13\xa5\xa5\x5a\x42" + bytes(range(200, 256))
    data = garbage + frames[0] + frames[1] + garbage + b"".join(frames[2:]) + b"\xa5"
    stream = ExplorerStream()
    found = feed_all(stream, data, chunk)
    assert found == [decode_frame(f) for f in frames]
    assert stream.dropped == 2


def test_a_corrupt_huge_length_does_not_hold_up_the_frames_after_it():
    frames = some_frames()
    stream = ExplorerStream()
    # a SCAN header claiming 65535 bytes, then a CONFIGURE header claiming 4000
    false_starts = b"\xa5\x5a\x90\xff\xff\x00\x00" + b"\xa5\x5a\x02\xa0\x0f\x00\x00"
    found = stream.feed(false_starts + b"".join(frames))
    assert found == [decode_frame(f) for f in frames]
    assert stream.dropped == 2  # one per false start
    alone = ExplorerStream()
    assert alone.feed(false_starts[:7]) == [] and alone.buffered == 0  # nothing waits


def test_a_false_start_inside_a_spoiled_frame_counts_once():
    # Ranges whose bytes spell a plausible CONFIGURE header inside the scan.
    ranges = np.full(128, 1000, dtype=np.uint16)
    ranges[5:8] = [0x5AA5, 0x0402, 0x0000]
    bad = spoil(encode_message(ScanMessage(0, 200, 0, ranges), 0))
    good = encode_message(Empty(Kind.STOP_ACK), 1)
    stream = ExplorerStream()
    assert stream.feed(bad + good) == [decode_frame(good)]
    assert stream.dropped == 1


def test_a_frame_hidden_behind_a_false_start_is_found():
    good = encode_message(Configure(256, 400), 9)
    # sync + a valid header for a 0-byte frame whose CRC bytes are the real frame's start
    data = b"\xa5\x5a\x01\x00\x00\x00\x00" + good
    assert ExplorerStream().feed(data) == [decode_frame(good)]


def test_scan_decoder_holds_scans_to_the_settings_in_effect():
    decoder = ScanDecoder(readings=128, rev_hundredths=250, range_max_mm=20_000)
    good = decode_frame(encode_message(scan_message(128, 1_000_000, 0x8000), 5))
    frame = decoder.take(good)
    assert (frame.sequence, frame.device_time_s, frame.range_max_m) == (5, 1.0, 20.0)
    assert frame.angles_rad[0] == pytest.approx(np.pi)
    assert frame.ranges_m[:2].tolist() == [1.0, 1.007]
    far = scan_message(128)
    far.ranges_mm[3] = 20_001
    cases = [
        (scan_message(256), "scan of 256 readings while 128 are set"),
        (ScanMessage(0, 200, 0, scan_message(128).ranges_mm), "scan at speed 200 while 250 is set"),
        (far, "scan with a range of 20001 mm, beyond range_max"),
    ]
    for message, reason in cases:
        with pytest.raises(FrameError, match=re.escape(reason)):
            decoder.take(decode_frame(encode_message(message, 6)))
    assert decoder.take(decode_frame(encode_message(Empty(Kind.STOP_ACK), 7))) is None


def test_scan_decoder_without_settings_takes_any_offered_count_at_a_speed_on_offer():
    decoder = ScanDecoder()
    assert decoder.take(decode_frame(encode_message(scan_message(2048), 0))).ranges_m.size == 2048
    with pytest.raises(FrameError, match="speed 0 while None"):
        decoder.take(
            decode_frame(encode_message(ScanMessage(0, 0, 0, scan_message().ranges_mm), 1))
        )


# -- fuzzing ---------------------------------------------------------------------------

messages = st.one_of(
    st.sampled_from([m for m in EVERY_MESSAGE if not isinstance(m, ScanMessage)]),
    st.builds(
        lambda n, t, a, seed: ScanMessage(
            t, 200, a, np.random.default_rng(seed).integers(0, 65_536, n).astype(np.uint16)
        ),
        st.sampled_from([128, 256]),
        st.integers(0, CLOCK_WRAP_US - 1),
        st.integers(0, 65_535),
        st.integers(0, 2**32),
    ),
)
damage = st.one_of(
    st.none(),
    st.tuples(st.just("insert"), st.floats(0, 1), st.binary(min_size=1, max_size=40)),
    st.tuples(st.just("delete"), st.floats(0, 1), st.integers(1, 30)),
    st.tuples(st.just("flip"), st.floats(0, 1), st.integers(0, 7)),
    st.tuples(st.just("truncate"), st.floats(0, 1)),
    st.tuples(st.just("garbage before"), st.binary(min_size=1, max_size=60)),
)


def damaged(frame: bytes, how) -> tuple[bytes, bool]:
    """``frame`` with ``how`` done to it, and whether the frame itself is still intact."""
    if how is None:
        return frame, True
    if how[0] == "garbage before":
        return how[1] + frame, True
    at = 1 + int(how[1] * (len(frame) - 2))  # strictly inside the frame
    if how[0] == "insert":
        return frame[:at] + how[2] + frame[at:], False
    if how[0] == "delete":
        return frame[:at] + frame[at + how[2] :], False
    if how[0] == "flip":
        return frame[:at] + bytes([frame[at] ^ (1 << how[2])]) + frame[at + 1 :], False
    return frame[:at], False


def fed_in_pieces(data: bytes, cuts: list[int]) -> tuple[ExplorerStream, list[Frame]]:
    stream = ExplorerStream()
    edges = sorted({0, len(data), *(c % (len(data) + 1) for c in cuts)})
    frames = []
    for lo, hi in itertools.pairwise(edges):
        frames += stream.feed(data[lo:hi])
    return stream, frames


def is_subsequence(wanted: list, found: list) -> bool:
    rest = iter(found)
    return all(any(f == w for f in rest) for w in wanted)


@given(st.binary(max_size=6000), st.lists(st.integers(0, 6000), max_size=20))
@fuzz_settings
def test_random_bytes_never_raise_and_only_real_frames_come_out(data, cuts):
    stream, frames = fed_in_pieces(data, cuts)
    for frame in frames:
        assert encode_frame(frame.kind, frame.sequence, frame.payload) in data
    assert len(stream._buf) <= MAX_FRAME


@given(
    st.lists(st.tuples(messages, damage), min_size=1, max_size=12),
    st.lists(st.integers(0, 20_000), max_size=20),
)
@fuzz_settings
def test_every_intact_frame_after_damage_is_found(plan, cuts):
    pieces, intact, any_damage = [], [], False
    for sequence, (message, how) in enumerate(plan):
        frame = encode_message(message, sequence)
        piece, whole = damaged(frame, how)
        pieces.append(piece)
        any_damage |= how is not None
        if whole:
            intact.append(decode_frame(frame))
    # The stream goes on after the last frame, as a serial line does (here with a
    # frame of the largest size): a false start near the end cannot keep the frames
    # behind it waiting for ever.
    tail = encode_message(scan_message(2048), len(plan))
    assert len(tail) == MAX_FRAME
    intact.append(decode_frame(tail))
    data = b"".join(pieces) + tail
    stream, frames = fed_in_pieces(data, cuts)
    assert is_subsequence(intact, frames)
    for frame in frames:
        assert encode_frame(frame.kind, frame.sequence, frame.payload) in data
    assert (stream.dropped > 0) == any_damage


@given(st.lists(messages, min_size=1, max_size=8), st.floats(0, 1))
@fuzz_settings
def test_a_truncated_stream_gives_every_frame_before_the_cut(plan, where):
    frames = [encode_message(m, i) for i, m in enumerate(plan)]
    data = b"".join(frames)
    cut = int(where * len(data))
    complete, end = [], 0
    for frame in frames:
        end += len(frame)
        if end <= cut:
            complete.append(decode_frame(frame))
    stream = ExplorerStream()
    assert stream.feed(data[:cut]) == complete
    assert stream.dropped == 0


# -- the device's side -------------------------------------------------------------------


def flat_world(angles_rad: np.ndarray) -> np.ndarray:
    """A stand-in for the world: range 1 m + 1 m per radian of beam angle."""
    return 1.0 + np.asarray(angles_rad)


def ask(device: ExplorerDevice, data: bytes, now_s: float = 0.0) -> list[tuple[int, object]]:
    """The device's replies to ``data`` as (sequence, message) pairs, through the host parser."""
    stream = ExplorerStream()
    frames = stream.feed(device.receive(data, now_s))
    assert stream.dropped == 0
    return [(f.sequence, decode_message(f)) for f in frames]


def test_device_answers_each_command_with_its_sequence():
    device = ExplorerDevice(flat_world)
    assert ask(device, encode_message(Empty(Kind.IDENTIFY), 40)) == [
        (40, Identity("SEO Explorer", "EMU-0001", "emu-1.0"))
    ]
    assert ask(device, encode_message(Configure(256, 400), 41)) == [
        (41, ConfigAck(256, 400, 30_000))
    ]
    assert ask(device, encode_message(Empty(Kind.START), 42)) == [(42, Empty(Kind.START_ACK))]
    assert ask(device, encode_message(Empty(Kind.STOP), 65_535)) == [(65_535, Empty(Kind.STOP_ACK))]


def test_device_refuses_what_it_cannot_do_and_keeps_its_settings():
    device = ExplorerDevice(flat_world)
    assert ask(device, encode_message(Configure(300, 200), 1)) == [
        (1, Nak(NakCode.BAD_READINGS, Kind.CONFIGURE))
    ]
    assert ask(device, encode_message(Configure(256, 401), 2)) == [
        (2, Nak(NakCode.BAD_SPEED, Kind.CONFIGURE))
    ]
    assert ask(device, encode_message(Configure(256, 49), 3)) == [
        (3, Nak(NakCode.BAD_SPEED, Kind.CONFIGURE))
    ]
    assert (device.readings, device.rev_hundredths) == (1024, 200)
    assert ask(device, encode_message(Empty(Kind.START_ACK), 4)) == [
        (4, Nak(NakCode.UNKNOWN_COMMAND, Kind.START_ACK))
    ]


def test_device_naks_a_damaged_host_frame_and_then_answers_the_good_one():
    device = ExplorerDevice(flat_world)
    bad = spoil(encode_message(Empty(Kind.IDENTIFY), 5))
    assert ask(device, bad) == [(0, Nak(NakCode.BAD_FRAME, 0))]
    # a header no frame can have (CONFIGURE with 3 bytes) is refused without waiting
    assert ask(device, b"\xa5\x5a\x02\x03\x00\x06\x00") == [(0, Nak(NakCode.BAD_FRAME, 0))]
    replies = ask(device, encode_message(Empty(Kind.IDENTIFY), 7))
    assert [(s, type(m)) for s, m in replies] == [(7, Identity)]


def test_device_waits_for_the_rest_of_a_split_command():
    device = ExplorerDevice(flat_world)
    data = encode_message(Configure(128, 100), 3) + encode_message(Empty(Kind.START), 4)
    replies = b"".join(device.receive(data[i : i + 1], 0.0) for i in range(len(data)))
    frames = ExplorerStream().feed(replies)
    assert [(f.sequence, decode_message(f)) for f in frames] == [
        (3, ConfigAck(128, 100, 30_000)),
        (4, Empty(Kind.START_ACK)),
    ]


def test_device_sends_one_scan_per_revolution_while_started():
    spoiled_calls = iter([False, True, False, False])
    device = ExplorerDevice(flat_world, lambda: next(spoiled_calls))
    device.receive(encode_message(Configure(256, 400), 0), 10.0)
    assert device.poll(11.0) == []  # not started
    device.receive(encode_message(Empty(Kind.START), 1), 20.0)
    assert device.poll(20.2) == []
    out = device.poll(20.25) + device.poll(20.3) + device.poll(20.75)
    assert len(out) == 3
    stream = ExplorerStream()
    frames = stream.feed(b"".join(out))
    assert stream.dropped == 1  # the second one had its CRC spoiled
    scans = [decode_message(f) for f in frames]
    assert [f.sequence for f in frames] == [0, 2]
    assert [s.timestamp_us for s in scans] == [20_000_000, 20_500_000]
    angles = 2 * np.pi * np.arange(256) / 256
    np.testing.assert_array_equal(scans[0].ranges_mm, ranges_to_mm(flat_world(angles)))
    assert (scans[0].rev_hundredths, scans[0].first_angle) == (400, 0)
    device.receive(encode_message(Empty(Kind.STOP), 2), 20.8)
    assert device.poll(30.0) == []


def test_device_clock_wraps_and_the_unwrapper_undoes_it():
    offset_us = CLOCK_WRAP_US - 600_000  # 0.6 s before the wrap
    device = ExplorerDevice(flat_world, clock_offset_us=offset_us)
    device.receive(encode_message(Configure(128, 400), 0), 0.0)
    device.receive(encode_message(Empty(Kind.START), 1), 0.0)
    out = [frame for k in range(6) for frame in device.poll(0.26 + 0.25 * k)]
    frames = ExplorerStream().feed(b"".join(out))
    raw = [decode_message(f).timestamp_us for f in frames]
    assert raw == [CLOCK_WRAP_US - 600_000 + k * 250_000 for k in range(3)] + [
        (k * 250_000 - 600_000) % CLOCK_WRAP_US for k in range(3, 6)
    ]
    unwrap = ClockUnwrapper(CLOCK_WRAP_US)
    times = [unwrap(t) for t in raw]
    assert np.diff(times).tolist() == [250_000] * 5


def test_clock_unwrapper_takes_the_shorter_way_round():
    unwrap = ClockUnwrapper(CLOCK_WRAP_US)
    readings = [CLOCK_WRAP_US - 10, 5, 1_000, 900, CLOCK_WRAP_US - 20, 40]
    assert [unwrap(r) for r in readings] == [
        CLOCK_WRAP_US - 10,
        CLOCK_WRAP_US + 5,
        CLOCK_WRAP_US + 1_000,
        CLOCK_WRAP_US + 900,  # a small step back, not a wrap
        CLOCK_WRAP_US - 20,  # back across the wrap
        CLOCK_WRAP_US + 40,
    ]


# -- the driver against scripted devices in another process ---------------------------


class ScriptedExplorer(ExplorerDevice):
    """An Explorer that answers commands as usual but, once started, sends ``script``
    (bytes of any kind) a single time instead of scanning."""

    def __init__(self, script: bytes):
        super().__init__(np.zeros_like)
        self.script = script
        self.sent = False

    def poll(self, now_s: float) -> list[bytes]:
        if not self.scanning or self.sent:
            return []
        self.sent = True
        return [self.script]


class SlowOnlyExplorer(SilentDevice):
    """Refuses the CONFIGURE a driver sends for its defaults (1024 readings at 2.00 rev/s)
    as too fast; any other frame, that one sent differently included, goes unanswered."""

    def __init__(self):
        super().__init__()
        self.stream = ExplorerStream()

    def receive(self, data: bytes, now_s: float) -> bytes:
        refusal = Nak(NakCode.BAD_SPEED, Kind.CONFIGURE)
        return b"".join(
            encode_message(refusal, frame.sequence)
            for frame in self.stream.feed(data)
            if decode_message(frame) == Configure(1024, 200)
        )


@pytest.fixture
def explorer_on(driver_on):
    """``driver = explorer_on(make_device)``: a driver (0.3 s timeout) opened on a device
    served by another process; closed at teardown."""
    return lambda make_device: driver_on(ExplorerDriver, make_device, 0.3)


def test_driver_reports_a_silent_device_in_one_line(explorer_on):
    driver = explorer_on(SilentDevice)
    started = time.monotonic()
    with pytest.raises(DeviceError) as error:
        driver.identify()
    assert time.monotonic() - started < 1.0  # the timeout holds; no hang
    assert str(error.value) == (
        f"{driver.port}: no answer to IDENTIFY within 0.3 s; "
        "check the protocol name, baud rate (115200) and cable"
    )


def test_driver_says_when_the_device_speaks_another_protocol(explorer_on):
    driver = explorer_on(lambda: ParrotDevice(b"VV\n00P\nMODL:URG-04LX\n\n" * 4))
    with pytest.raises(DeviceError, match="does not speak the explorer protocol") as error:
        driver.identify()
    assert "\n" not in str(error.value)


def test_driver_decodes_scans_unwraps_the_clock_and_counts_skipped(explorer_on):
    first = 0x4000  # a quarter turn
    ranges = np.array([1000, 0, 29_999] + [2500] * 125, dtype=np.uint16)
    times = [CLOCK_WRAP_US - 100_000, 150_000]
    frames = [
        encode_message(ScanMessage(t, 200, first, ranges), 7 + i) for i, t in enumerate(times)
    ]
    script = b"\x01\x02" + frames[0] + spoil(frames[1]) + frames[1]
    driver = explorer_on(lambda: ScriptedExplorer(script))
    driver.start()
    a, b = driver.read_scan(), driver.read_scan()
    assert (a.sequence, b.sequence) == (7, 8)
    assert b.device_time_s - a.device_time_s == pytest.approx(0.25, abs=1e-9)
    assert a.angles_rad[0] == pytest.approx(np.pi / 2)
    np.testing.assert_allclose(np.diff(a.angles_rad), 2 * np.pi / 128)
    assert a.ranges_m[:3].tolist() == [1.0, 0.0, 29.999]
    assert a.range_max_m == 30.0
    assert driver.skipped == 2  # the garbage, then the spoiled frame
    assert driver.read_scan() is None


def test_driver_checks_settings_before_sending_them():
    # Never opened: had the driver tried to send, it would fail with "port is not open".
    driver = ExplorerDriver("/dev/ttyUSB0", timeout_s=0.3)
    with pytest.raises(DeviceError, match="300 readings per revolution is not offered"):
        driver.configure(300, None)
    with pytest.raises(DeviceError, match=r"4\.5 rev/s is not offered; .* 0\.5 to 4\.0 rev/s"):
        driver.configure(1024, 4.5)
    with pytest.raises(DeviceError, match="port is not open"):
        driver.configure(1024, 4.0)  # settings on offer do go to the port


class MisreportingExplorer(ExplorerDevice):
    """Acknowledges every CONFIGURE with ``ack`` instead of the settings taken."""

    def __init__(self, ack: ConfigAck):
        super().__init__(np.zeros_like)
        self.ack = ack

    def _configure(self, command: Configure, now_s: float):
        super()._configure(command, now_s)
        return self.ack


@pytest.mark.parametrize(
    ("ack", "message"),
    [
        (ConfigAck(512, 200, 30_000), "with readings=512, not the 1024 asked for"),
        (ConfigAck(1024, 400, 30_000), "with speed=400, not the 200 asked for"),
        (ConfigAck(1024, 200, 0), "with range_max=0 mm; a scanner that sees nothing"),
    ],
)
def test_driver_refuses_an_acknowledgement_of_other_settings(ack, message, explorer_on):
    driver = explorer_on(lambda: MisreportingExplorer(ack))
    with pytest.raises(DeviceError) as error:
        driver.configure(1024, 2.0)
    assert str(error.value).startswith(f"{driver.port}: the device acknowledged CONFIGURE ")
    assert message in str(error.value) and "\n" not in str(error.value)


def test_driver_skips_and_counts_scans_unlike_the_settings(explorer_on):
    good = encode_message(scan_message(128), 1)  # 128 readings at 2.50 rev/s, as configured
    script = encode_message(scan_message(256), 0) + good
    driver = explorer_on(lambda: ScriptedExplorer(script))
    driver.configure(128, 2.5)
    driver.start()
    assert driver.read_scan().sequence == 1
    assert driver.skipped == 1


def test_driver_turns_the_devices_refusal_into_an_error(explorer_on):
    driver = explorer_on(SlowOnlyExplorer)
    with pytest.raises(DeviceError, match=r"2 rev/s is not offered; the Explorer turns at 0\.5"):
        driver.configure(None, None)


# -- against `segloc emulate` in another process -----------------------------------------

# The emulated Explorer's range noise is σ = 1.2 cm (plus 1 mm quantisation): 5 cm is
# four σ. Beams that meet a glass pane, a passer-by or a dropout differ by more,
# so the bound is asked of 90 % of the beams.
TOLERANCE_M = 0.05


def true_ranges(angles_rad: np.ndarray) -> np.ndarray:
    x, y, theta_deg = HALL_POSE
    world = read_world(HALL_WORLD)
    pose = Pose2(x, y, np.deg2rad(theta_deg))
    return render_ranges(world, pose, angles_rad, NOISE_FREE, np.random.default_rng(0))


@pytest.fixture
def emulated(emulator):
    def connect(*args: str) -> ExplorerDriver:
        driver = ExplorerDriver(emulator("explorer", *args), timeout_s=1.0)
        driver.open()
        opened.append(driver)
        return driver

    opened: list[ExplorerDriver] = []
    yield connect
    for driver in opened:
        driver.stop()
        driver.close()


def test_emulated_explorer_identifies_configures_and_scans(emulated):
    driver = emulated()
    info = driver.identify()
    assert (info.protocol, info.model, info.serial_number) == (
        "explorer",
        "SEO Explorer",
        "EMU-0001",
    )
    settings_ = driver.configure(256, 4.0)
    assert settings_ == {
        "range_max_m": "30.0",
        "readings": "256",
        "rev_per_s": "4.0",
        "field_of_view_deg": "360",
        "range_resolution_m": "0.001",
    }
    with pytest.raises(DeviceError, match=r"300 readings .* takes 128, 256, 1024 or 2048"):
        driver.configure(300, 2.0)
    driver.start()
    scans, arrivals = [], []
    for _ in range(6):
        scans.append(driver.read_scan())
        arrivals.append(time.monotonic())
    assert all(s is not None and s.ranges_m.shape == (256,) for s in scans)
    assert np.diff([s.sequence for s in scans]).tolist() == [1] * 5
    np.testing.assert_allclose(np.diff([s.device_time_s for s in scans]), 0.25, atol=1e-6)
    assert 3.0 < 5 / (arrivals[-1] - arrivals[0]) < 5.5  # scans per second on the host
    truth = true_ranges(scans[0].angles_rad)
    hit = truth > 0  # the others leave the hall through a door or a window
    assert hit.sum() > 150
    for scan in scans:
        error = np.abs(scan.ranges_m - truth)[hit]
        assert np.mean(error < TOLERANCE_M) > 0.9
        assert np.median(error) < 0.015  # σ·0.67 ≈ 0.8 cm expected
    assert driver.skipped == 0


def test_emulated_checksum_faults_are_skipped_and_counted(emulated):
    driver = emulated("--faults", "checksum", "--fault-rate", "0.5")
    driver.configure(128, 4.0)
    driver.start()
    scans = [driver.read_scan() for _ in range(5)]
    assert all(s is not None and s.ranges_m.shape == (128,) for s in scans)
    sequences = [s.sequence for s in scans]
    lost = int(np.sum(np.diff(sequences) - 1))
    assert driver.skipped > 0
    assert lost > 0  # the spoiled scans are missing from the sequence, not misread
