"""Fuzzing the two scanner protocols' parsers with arbitrary and mangled bytes, in process.

Whatever a serial port delivers, each outcome must be one of: a scan with finite
angles and ranges within the device's bounds, a frame skipped and counted, or a
one-line ``DeviceError`` naming the port. Nothing else may escape, no buffer may
grow past its documented bound, and a device's reported geometry is either
accepted within bounds or refused naming the field.
"""

from __future__ import annotations

import itertools
import math
import re

import numpy as np
from fuzzing import byte_mutations, fuzz_settings, mutate
from hypothesis import given
from hypothesis import strategies as st

from segloc_cli.devices import explorer, scip2
from segloc_cli.devices.base import DeviceError, FrameError, ScanFrame
from segloc_cli.devices.explorer import (
    MAX_FRAME,
    ConfigAck,
    ExplorerDevice,
    ExplorerDriver,
    ExplorerStream,
    Kind,
    ScanMessage,
    encode_message,
)
from segloc_cli.devices.scip2 import (
    MAX_ARES,
    MAX_CLUSTER,
    MAX_LINE_BYTES,
    MAX_RANGE_MM,
    MAX_REPLY_LINES,
    MAX_STEP,
    PP_INTEGERS,
    SCAN_RPM_RANGE,
    STATUS_TEXT,
    URG_04LX_PARAMETERS,
    URG_04LX_VERSION,
    ScanRequest,
    Scip2Device,
    Scip2Driver,
    Scip2Stream,
    checksum,
    cluster_for,
    data_lines,
    encode_value,
    encode_values,
    field_lines,
    format_reply,
    parse_parameters,
    step_angles,
)

PORT = "/dev/ttyFUZZ"
URG = parse_parameters(URG_04LX_PARAMETERS, PORT)

_CHUNKS = st.lists(st.integers(1, 400), max_size=12)


def _pieces(data: bytes, chunks: list[int]) -> list[bytes]:
    """``data`` cut at the running sums of ``chunks`` (the rest in one piece)."""
    edges = [0, *itertools.accumulate(chunks)]
    edges = [e for e in edges if e < len(data)] + [len(data)]
    return [data[lo:hi] for lo, hi in itertools.pairwise(edges)]


def _one_line_naming_port(error: DeviceError) -> None:
    message = str(error)
    assert "\n" not in message and "\r" not in message, message
    assert message.startswith(f"{PORT}: "), message
    assert message.isprintable(), message


def _check_scan(frame: ScanFrame, readings: int, range_min_m: float, range_max_m: float) -> None:
    assert frame.angles_rad.shape == frame.ranges_m.shape == (readings,)
    assert np.all(np.isfinite(frame.angles_rad)) and np.all(np.isfinite(frame.ranges_m))
    assert np.all(np.abs(frame.angles_rad) < 4 * math.pi)  # a first angle plus one turn
    valid = frame.ranges_m > 0
    assert np.all(frame.ranges_m[valid] >= range_min_m)
    assert np.all(frame.ranges_m <= range_max_m) and np.all(frame.ranges_m >= 0)
    assert frame.range_max_m == range_max_m
    assert math.isfinite(frame.device_time_s)


# --- SCIP 2.0 -----------------------------------------------------------------------------------


def _md_stream(request: ScanRequest, scans: list[int]) -> bytes:
    """Scan replies to ``request``, one per seed, values drawn from the seed over 18 bits."""
    out = bytearray(format_reply(request.text().encode(), b"00"))
    for i, seed in enumerate(scans):
        values = np.random.default_rng(seed).integers(0, 1 << 18, request.readings)
        stamp = encode_value((seed + 100 * i) % (1 << 24), 4)
        body = stamp + bytes([checksum(stamp)]) + b"\n" + data_lines(encode_values(values, 3))
        out += format_reply(request.text(0).encode(), b"99", body)
    return bytes(out)


def _run_scip2(data: bytes, chunks: list[int], request: ScanRequest) -> tuple[int, int]:
    """Feed ``data`` to the stream and decoder as the driver does; (scans, skipped)."""
    stream = Scip2Stream()
    decoder = scip2.ScanDecoder(URG, request, PORT)
    scans = skipped = 0
    for piece in _pieces(data, chunks):
        for item in stream.feed(piece):
            try:
                frame = decoder.take(item)
            except FrameError:
                skipped += 1
                continue
            except DeviceError as error:  # a scan reply with a stopped-scanning status
                _one_line_naming_port(error)
                continue
            if frame is not None:
                _check_scan(frame, request.readings, URG["DMIN"] / 1000, URG["DMAX"] / 1000)
                scans += 1
        assert stream.buffered <= MAX_LINE_BYTES * (MAX_REPLY_LINES + 1)
    return scans, skipped


_REQUESTS = st.builds(
    lambda cluster: ScanRequest("MD", URG["AMIN"], URG["AMAX"], cluster),
    st.sampled_from([1, 2, 3, 10, MAX_CLUSTER]),
)


@given(st.binary(max_size=4000), _CHUNKS, _REQUESTS)
@fuzz_settings
def test_scip2_random_bytes_give_only_bounded_scans_or_counted_skips(data, chunks, request):
    _run_scip2(data, chunks, request)


@given(_REQUESTS, st.lists(st.integers(0, 2**32), min_size=1, max_size=4), _CHUNKS)
@fuzz_settings
def test_scip2_intact_scan_stream_decodes_every_scan(request, seeds, chunks):
    assert _run_scip2(_md_stream(request, seeds), chunks, request) == (len(seeds), 0)


@given(
    _REQUESTS,
    st.lists(st.integers(0, 2**32), min_size=1, max_size=4),
    st.lists(byte_mutations(), min_size=1, max_size=6),
    _CHUNKS,
)
@fuzz_settings
def test_scip2_mangled_scan_stream_gives_bounded_scans_or_counted_skips(
    request, seeds, mutations, chunks
):
    data = mutate(_md_stream(request, seeds), mutations)
    scans, skipped = _run_scip2(data, chunks, request)
    assert scans + skipped <= data.count(b"\n")


_PP_NUMBER = st.one_of(
    st.integers(0, 70_000).map(str),
    st.integers(0, 10**40).map(str),
    st.sampled_from(["", " 12", "-5", "1e3", "٣", "0x10", "12\r", "\x00"]),
    st.text(max_size=12),
)
_PLAUSIBLE = {  # near real devices, so that some draws pass every check
    "DMIN": st.integers(0, 30),
    "DMAX": st.integers(0, 300_000),
    "ARES": st.sampled_from([0, 1024, 1440, 2880, MAX_ARES, MAX_ARES + 1]),
    "AMIN": st.integers(0, 1200),
    "AMAX": st.integers(0, 12_000),
    "AFRT": st.integers(0, 1200),
    "SCAN": st.sampled_from([0, 59, 60, 600, 2400, 6000, 6001]),
}


@st.composite
def _pp_fields(draw) -> dict[str, str]:
    fields = {}
    for name in PP_INTEGERS:
        choice = draw(st.integers(0, 9))
        if choice == 0:
            continue  # missing
        number = _PP_NUMBER if choice == 1 else _PLAUSIBLE[name].map(str)
        fields[name] = draw(number)
    return fields


@given(_pp_fields(), st.integers(1, 20_000) | st.none())
@fuzz_settings
def test_pp_numbers_are_accepted_within_bounds_or_refused_naming_the_field(fields, readings):
    try:
        pp = parse_parameters(fields, PORT)
    except DeviceError as error:
        _one_line_naming_port(error)
        named = re.search(r"PP parameter (\w+)=|a number for (\w+) \(got", str(error))
        assert named and (named[1] or named[2]) in PP_INTEGERS, str(error)
        return
    assert 1 <= pp["ARES"] <= MAX_ARES
    assert 0 <= pp["AMIN"] <= pp["AFRT"] <= pp["AMAX"] < pp["ARES"] and pp["AMAX"] <= MAX_STEP
    assert 1 <= pp["DMIN"] < pp["DMAX"] <= MAX_RANGE_MM
    assert SCAN_RPM_RANGE[0] <= pp["SCAN"] <= SCAN_RPM_RANGE[1]
    cluster = cluster_for(readings, pp["AMIN"], pp["AMAX"])
    if cluster is None:
        return
    assert 1 <= cluster <= MAX_CLUSTER
    request = ScanRequest("MD", pp["AMIN"], pp["AMAX"], cluster)
    assert readings in (None, request.readings) and request.readings <= MAX_STEP + 1
    assert scip2.parse_scan_request(request.text()) == request  # the command can say it
    angles = step_angles(pp["AMIN"], pp["AMAX"], cluster, pp["ARES"], pp["AFRT"])
    assert angles.shape == (request.readings,) and np.all(np.abs(angles) < 2 * math.pi)
    # Evenly spaced, as a log's laser scan must be.
    if angles.size > 2:
        assert np.ptp(np.diff(angles)) < 1e-9, angles


def _latin1_line(text: str) -> str:
    """``text`` as the Latin-1 reading of its UTF-8 bytes, kept to one line."""
    return text.encode("utf-8").decode("latin-1").replace("\n", "?").replace("\r", "?")


class _ScriptedLink:
    """A stand-in for a serial port: answers each command line the host writes with a
    scripted reply (VV and PP from dicts, any other command status 00)."""

    def __init__(self, answers: dict[bytes, bytes]):
        self.answers = answers
        self.out = bytearray()
        self.pending = bytearray()

    def write(self, data: bytes) -> None:
        self.pending += data
        *lines, rest = bytes(self.pending).split(b"\n")
        self.pending = bytearray(rest)
        for line in lines:
            self.out += self.answers.get(line, format_reply(line, b"00"))

    def flush(self) -> None:
        pass

    def read(self, size: int) -> bytes:
        data = bytes(self.out[:size])
        del self.out[:size]
        return data

    @property
    def in_waiting(self) -> int:
        return len(self.out)

    def close(self) -> None:
        pass


_FIELD_TEXT = st.text(
    st.characters(min_codepoint=0, max_codepoint=0xFF, blacklist_characters="\n\r"), max_size=40
)


@given(_pp_fields(), st.dictionaries(st.sampled_from(["PROD", "SERI", "FIRM"]), _FIELD_TEXT))
@fuzz_settings
def test_scip2_driver_takes_a_sane_device_or_refuses_it_in_one_line(pp_fields, version):
    # Every PP field a URG sends, some replaced by the draw: field_lines needs no ':' in names.
    fields = {**URG_04LX_PARAMETERS, **{k: _latin1_line(v) for k, v in pp_fields.items()}}
    answers = {
        b"VV": format_reply(b"VV", b"00", field_lines({**URG_04LX_VERSION, **version})),
        b"PP": format_reply(b"PP", b"00", field_lines(fields)),
    }
    driver = Scip2Driver(PORT, timeout_s=0.05)
    driver._serial = _ScriptedLink(answers)
    try:
        info = driver.identify()
        settings = driver.configure(None, None)
    except DeviceError as error:
        _one_line_naming_port(error)
        return
    for text in (*info.as_metadata().values(), *settings.values()):
        assert text.isprintable(), text
    assert 0 < float(settings["range_max_m"]) <= MAX_RANGE_MM / 1000


@given(st.binary(max_size=600), _CHUNKS)
@fuzz_settings
def test_emulated_urg_answers_any_host_bytes_with_well_formed_replies(data, chunks):
    device = Scip2Device(np.ones_like)
    host = Scip2Stream()
    for i, piece in enumerate(_pieces(data, chunks)):
        out = device.receive(piece, 0.01 * i) + b"".join(device.poll(0.01 * i))
        # A line that is no command is echoed as it came, which the host cannot take
        # for a reply; every reply it can take carries a status of the specification.
        for item in host.feed(out):
            assert isinstance(item, FrameError) or item.status in {*STATUS_TEXT, "02"}


# --- Explorer -----------------------------------------------------------------------------------

_SCANS = st.builds(
    lambda n, speed, first, seed, top: ScanMessage(
        seed % (1 << 32),
        speed,
        first,
        np.random.default_rng(seed).integers(0, top, n).astype(np.uint16),
    ),
    st.sampled_from([128, 256, 1024]),
    st.sampled_from([200, 200, 200, 50, 400, 0, 65_535]),
    st.integers(0, 65_535),
    st.integers(0, 2**40),
    st.sampled_from([30_000, 30_001, 65_536]),
)


def _run_explorer(data: bytes, chunks: list[int], decoder: explorer.ScanDecoder) -> list:
    """Feed ``data`` as the driver does; the scans decoded, checking each and the buffer."""
    stream = ExplorerStream()
    scans = []
    for piece in _pieces(data, chunks):
        for frame in stream.feed(piece):
            try:
                scan = decoder.take(frame)
            except FrameError:
                continue
            if scan is not None:
                readings = decoder.readings or scan.ranges_m.size
                assert readings in explorer.READINGS_OFFERED
                _check_scan(scan, readings, 0.0, decoder.range_max_mm / 1000)
                scans.append(scan)
        assert stream.buffered < MAX_FRAME
    return scans


_DECODERS = st.sampled_from(
    [explorer.ScanDecoder(), explorer.ScanDecoder(1024, 200, 30_000), explorer.ScanDecoder(128)]
)


@given(st.binary(max_size=6000), _CHUNKS, _DECODERS)
@fuzz_settings
def test_explorer_random_bytes_give_only_bounded_scans_or_counted_skips(data, chunks, decoder):
    _run_explorer(data, chunks, decoder)


@given(
    st.lists(_SCANS, min_size=1, max_size=5),
    st.lists(byte_mutations(), max_size=5),
    _CHUNKS,
    _DECODERS,
)
@fuzz_settings
def test_explorer_mangled_scans_give_bounded_scans_or_counted_skips(
    messages, mutations, chunks, decoder
):
    data = mutate(b"".join(encode_message(m, i) for i, m in enumerate(messages)), mutations)
    _run_explorer(data, chunks, decoder)


class _ExplorerLink:
    """A stand-in for a serial port with an Explorer behind it whose CONFIG_ACK is ``ack``."""

    def __init__(self, ack: ConfigAck):
        self.device = ExplorerDevice(np.ones_like)
        self.ack = ack
        self.stream = ExplorerStream()
        self.out = bytearray()

    def write(self, data: bytes) -> None:
        for frame in self.stream.feed(data):
            if frame.kind == Kind.CONFIGURE:
                self.out += encode_message(self.ack, frame.sequence)
            else:
                raw = explorer.encode_frame(frame.kind, frame.sequence, frame.payload)
                self.out += self.device.receive(raw, 0.0)

    def flush(self) -> None:
        pass

    read = _ScriptedLink.read
    in_waiting = _ScriptedLink.in_waiting


@given(st.integers(0, 65_535), st.integers(0, 65_535), st.integers(0, 65_535))
@fuzz_settings
def test_explorer_driver_takes_only_the_settings_it_asked_for(readings, speed, range_max):
    driver = ExplorerDriver(PORT, timeout_s=0.05)
    driver._serial = _ExplorerLink(ConfigAck(readings, speed, range_max))
    try:
        settings = driver.configure(1024, 2.0)
    except DeviceError as error:
        _one_line_naming_port(error)
        assert not (readings == 1024 and speed == 200 and range_max > 0), str(error)
        return
    assert readings == 1024 and speed == 200 and range_max > 0
    assert settings["range_max_m"] == str(range_max / 1000)


@given(st.binary(max_size=600), _CHUNKS)
@fuzz_settings
def test_emulated_explorer_answers_any_host_bytes_with_well_formed_frames(data, chunks):
    device = ExplorerDevice(np.ones_like)
    host = ExplorerStream()
    for i, piece in enumerate(_pieces(data, chunks)):
        out = device.receive(piece, 0.01 * i) + b"".join(device.poll(0.01 * i))
        for frame in host.feed(out):
            explorer.decode_message(frame)  # raises FrameError for a frame that makes no sense
    assert host.dropped == 0 and host.buffered == 0
