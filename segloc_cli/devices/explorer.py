"""The Explorer scanner's serial protocol: host driver and emulated device.

The Schwartz Electro-Optics Explorer of Reina & Gonzalez (2000) turns a range
finder through 360° at 0.5 to 4 revolutions per second and takes 128, 256,
1024 or 2048 readings per revolution. Its own serial protocol is not
published; this module defines segloc's binary framing for it, documented in
docs/explorer-protocol.md. Someone holding the real manual replaces this one
file.

Every frame, in both directions::

    A5 5A | kind u8 | length u16 | sequence u16 | payload (length bytes) | CRC u16

little-endian, the CRC-16/CCITT-FALSE of everything between the sync bytes
and the CRC. The pure functions (``encode_frame``, ``decode_frame``,
``encode_message``, ``decode_message``, ``ExplorerStream``) need no port.

Units on the wire: ranges in millimetres (0 = no return), speed in hundredths
of a revolution per second, angles in 1/65536 of a revolution counter-clockwise
from forward, the device clock in microseconds (uint32, wraps every 71.6 min).
"""

from __future__ import annotations

import binascii
import struct
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum
from typing import Literal, overload

import numpy as np

from segloc_cli.devices.base import (
    ClockUnwrapper,
    DeviceError,
    DeviceInfo,
    Driver,
    EmulatedDevice,
    FrameError,
    ScanFrame,
    printable,
)
from segloc_cli.geometry import TWO_PI
from segloc_cli.wording import with_article

SYNC = b"\xa5\x5a"
HEADER_SIZE = 7
"""Sync (2), kind (1), payload length (2), sequence (2)."""
CRC_SIZE = 2
READINGS_OFFERED = (128, 256, 1024, 2048)
"""Readings per revolution the Explorer can take."""
REV_HUNDREDTHS_RANGE = (50, 400)
"""Speeds offered, hundredths of a revolution per second: 0.50 to 4.00 rev/s."""
DEFAULT_READINGS = 1024
DEFAULT_REV_HUNDREDTHS = 200
RANGE_MAX_MM = 30_000
"""Readings at or beyond 30 m are sent as 0 (no return)."""
ANGLE_UNITS_PER_REV = 1 << 16
CLOCK_WRAP_US = 1 << 32
SCAN_HEADER_SIZE = 10
"""Timestamp u32, readings u16, speed u16, first-reading angle u16."""
MAX_PAYLOAD = SCAN_HEADER_SIZE + 2 * max(READINGS_OFFERED)
"""Largest payload of any frame, bytes (a 2048-reading scan); a longer one is never waited for."""
MAX_FRAME = HEADER_SIZE + MAX_PAYLOAD + CRC_SIZE
"""Largest frame, bytes (4115); a receiver never holds more than this waiting."""

_HEADER = struct.Struct("<BHH")  # after the sync bytes
_CONFIGURE = struct.Struct("<HH")
_CONFIG_ACK = struct.Struct("<HHH")
_NAK = struct.Struct("<BB")
_IDENTITY_WIDTHS = (16, 16, 8)
_IDENTITY = struct.Struct("<{}s{}s{}s".format(*_IDENTITY_WIDTHS))
_SCAN_HEADER = struct.Struct("<IHHH")


class Kind(IntEnum):
    """Frame types: commands from the host below 0x80, device frames above."""

    IDENTIFY = 0x01
    CONFIGURE = 0x02
    START = 0x03
    STOP = 0x04
    IDENTITY = 0x81
    CONFIG_ACK = 0x82
    START_ACK = 0x83
    STOP_ACK = 0x84
    SCAN = 0x90
    NAK = 0xEE


class NakCode(IntEnum):
    """Why the device refused a command."""

    BAD_FRAME = 1
    UNKNOWN_COMMAND = 2
    BAD_READINGS = 3
    BAD_SPEED = 4


COMMANDS = frozenset({Kind.IDENTIFY, Kind.CONFIGURE, Kind.START, Kind.STOP})

# Payload length of every frame type: a header whose length is not in this table
# is rejected at once, so a corrupt length never makes the parser wait for bytes.
PAYLOAD_SIZES: dict[int, frozenset[int]] = {
    Kind.IDENTIFY: frozenset({0}),
    Kind.CONFIGURE: frozenset({_CONFIGURE.size}),
    Kind.START: frozenset({0}),
    Kind.STOP: frozenset({0}),
    Kind.IDENTITY: frozenset({_IDENTITY.size}),
    Kind.CONFIG_ACK: frozenset({_CONFIG_ACK.size}),
    Kind.START_ACK: frozenset({0}),
    Kind.STOP_ACK: frozenset({0}),
    Kind.SCAN: frozenset(SCAN_HEADER_SIZE + 2 * n for n in READINGS_OFFERED),
    Kind.NAK: frozenset({_NAK.size}),
}


# -- messages ------------------------------------------------------------------------


@dataclass(frozen=True)
class Frame:
    """One checked frame: its type, sequence number and raw payload."""

    kind: int
    sequence: int
    payload: bytes


@dataclass(frozen=True)
class Empty:
    """A message without payload: IDENTIFY, START, STOP, START_ACK or STOP_ACK."""

    kind: Kind


@dataclass(frozen=True)
class Configure:
    """CONFIGURE: readings per revolution and speed in hundredths of rev/s."""

    readings: int
    rev_hundredths: int
    kind = Kind.CONFIGURE


@dataclass(frozen=True)
class Identity:
    """IDENTITY: the device's model (≤ 16), serial number (≤ 16) and firmware (≤ 8), ASCII."""

    model: str
    serial_number: str
    firmware: str
    kind = Kind.IDENTITY


@dataclass(frozen=True)
class ConfigAck:
    """CONFIG_ACK: the settings in effect; ``range_max_mm`` the largest range reported."""

    readings: int
    rev_hundredths: int
    range_max_mm: int
    kind = Kind.CONFIG_ACK


@dataclass(frozen=True)
class Nak:
    """NAK: a ``NakCode`` and the type of the refused command (0 if unreadable)."""

    code: int
    command: int
    kind = Kind.NAK


@dataclass(frozen=True, eq=False)
class ScanMessage:
    """SCAN: one revolution.

    ``timestamp_us`` device clock at the first reading (uint32, wraps);
    ``rev_hundredths`` the speed in effect; ``first_angle`` the first reading's
    angle in 1/65536 revolution counter-clockwise from forward; ``ranges_mm``
    (readings,) uint16 millimetres, 0 = no return, later readings further
    counter-clockwise at 1/readings of a revolution apart.
    """

    timestamp_us: int
    rev_hundredths: int
    first_angle: int
    ranges_mm: np.ndarray
    kind = Kind.SCAN


Message = Empty | Configure | Identity | ConfigAck | Nak | ScanMessage


# -- frames --------------------------------------------------------------------------


def crc16_ccitt_false(data: bytes | bytearray) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor)."""
    return binascii.crc_hqx(data, 0xFFFF)


def plausible_length(kind: int, length: int) -> bool:
    """Whether a frame of type ``kind`` can have a payload of ``length`` bytes."""
    sizes = PAYLOAD_SIZES.get(kind)
    return sizes is not None and length in sizes


def encode_frame(kind: int, sequence: int, payload: bytes = b"") -> bytes:
    """Sync, header, payload and CRC; ``ValueError`` for a length the type cannot have."""
    if not plausible_length(kind, len(payload)):
        raise ValueError(f"frame type 0x{kind:02X} cannot carry {len(payload)} payload bytes")
    body = _HEADER.pack(kind, len(payload), sequence & 0xFFFF) + payload
    return SYNC + body + crc16_ccitt_false(body).to_bytes(2, "little")


def decode_frame(data: bytes) -> Frame:
    """Exactly one frame from ``data``; ``FrameError`` saying what is wrong."""
    if len(data) < HEADER_SIZE + CRC_SIZE:
        raise FrameError(f"{len(data)} bytes is shorter than any frame")
    if data[:2] != SYNC:
        raise FrameError(f"no sync bytes at the start (got {data[:2].hex(' ')})")
    kind, length, sequence = _HEADER.unpack_from(data, 2)
    if not plausible_length(kind, length):
        raise FrameError(
            f"frame type 0x{kind:02X} with {with_article(f'{length}-byte')} payload does not exist"
        )
    if len(data) != HEADER_SIZE + length + CRC_SIZE:
        raise FrameError(f"{len(data)} bytes for a frame of {HEADER_SIZE + length + CRC_SIZE}")
    expected = crc16_ccitt_false(data[2:-CRC_SIZE])
    got = int.from_bytes(data[-CRC_SIZE:], "little")
    if got != expected:
        raise FrameError(f"CRC 0x{got:04X}, expected 0x{expected:04X}")
    return Frame(kind, sequence, bytes(data[HEADER_SIZE:-CRC_SIZE]))


def encode_message(message: Message, sequence: int) -> bytes:
    """One message as a complete frame with ``sequence`` (taken modulo 65536).

    ``ValueError`` for a field that does not fit its place in the frame.
    """
    try:
        payload = _payload(message)
    except struct.error as exc:
        raise ValueError(f"{type(message).__name__} does not fit its frame: {exc}") from exc
    return encode_frame(message.kind, sequence, payload)


def decode_message(frame: Frame) -> Message:
    """The message a checked frame carries; ``FrameError`` for contents that make no sense."""
    payload = frame.payload
    if not plausible_length(frame.kind, len(payload)):
        raise FrameError(
            f"frame type 0x{frame.kind:02X} with {with_article(f'{len(payload)}-byte')} payload"
        )
    kind = Kind(frame.kind)
    if kind == Kind.CONFIGURE:
        return Configure(*_CONFIGURE.unpack(payload))
    if kind == Kind.CONFIG_ACK:
        return ConfigAck(*_CONFIG_ACK.unpack(payload))
    if kind == Kind.NAK:
        return Nak(*_NAK.unpack(payload))
    if kind == Kind.IDENTITY:
        return Identity(*(_ascii_field(field) for field in _IDENTITY.unpack(payload)))
    if kind == Kind.SCAN:
        return _decode_scan(payload)
    return Empty(kind)


def ranges_to_mm(ranges_m: np.ndarray) -> np.ndarray:
    """Ranges in metres → uint16 millimetres as sent; 0 for no return or ≥ 30 m."""
    ranges_m = np.asarray(ranges_m, dtype=float)
    valid = np.isfinite(ranges_m) & (ranges_m > 0.0)
    mm = np.round(np.where(valid, ranges_m, 0.0) * 1000.0)
    return np.where(mm < RANGE_MAX_MM, mm, 0.0).astype(np.uint16)


def _payload(message: Message) -> bytes:
    if isinstance(message, Configure):
        return _CONFIGURE.pack(message.readings, message.rev_hundredths)
    if isinstance(message, ConfigAck):
        return _CONFIG_ACK.pack(message.readings, message.rev_hundredths, message.range_max_mm)
    if isinstance(message, Nak):
        return _NAK.pack(message.code, message.command)
    if isinstance(message, Identity):
        fields = [
            t.encode("ascii") for t in (message.model, message.serial_number, message.firmware)
        ]
        if any(len(f) > n for f, n in zip(fields, _IDENTITY_WIDTHS, strict=True)):
            raise ValueError(f"identity fields are at most {_IDENTITY_WIDTHS} characters")
        return _IDENTITY.pack(*fields)
    if isinstance(message, ScanMessage):
        ranges = np.asarray(message.ranges_mm, dtype="<u2")
        header = _SCAN_HEADER.pack(
            message.timestamp_us, ranges.size, message.rev_hundredths, message.first_angle
        )
        return header + ranges.tobytes()
    return b""


def _ascii_field(raw: bytes) -> str:
    text, _, padding = raw.partition(b"\x00")
    if padding.strip(b"\x00") or not all(0x20 <= b < 0x7F for b in text):
        raise FrameError(f"identity field {raw!r} is not NUL-padded printable ASCII")
    return text.decode("ascii")


def _decode_scan(payload: bytes) -> ScanMessage:
    timestamp_us, readings, rev_hundredths, first_angle = _SCAN_HEADER.unpack_from(payload)
    if SCAN_HEADER_SIZE + 2 * readings != len(payload):
        raise FrameError(f"scan says {readings} readings but carries {len(payload)} bytes")
    ranges = np.frombuffer(payload, dtype="<u2", offset=SCAN_HEADER_SIZE).astype(np.uint16)
    return ScanMessage(timestamp_us, rev_hundredths, first_angle, ranges)


# -- the stream parser ---------------------------------------------------------------


class ExplorerStream:
    """Frames from a byte stream fed in pieces of any size.

    ``feed`` returns the frames completed so far. It hunts for the sync bytes,
    rejects a header whose type and length are not in ``PAYLOAD_SIZES`` at
    once, and a complete candidate with a wrong CRC; after a rejected
    candidate it searches again from the candidate's second byte, so a real
    frame hidden behind a false start is still found. It never raises, and it
    never holds more than one frame's worth of bytes waiting.

    ``dropped`` counts the damage: each run of bytes between two good frames
    that belongs to no good frame counts one, and each further candidate
    rejected in the run (bad CRC, or a header no frame can have) one more. A
    false start inside a candidate already counted is not counted again.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._pos = 0  # stream offset of _buf[0]
        self._rejected_end = 0  # stream offset where the last counted rejected candidate ends
        self._damaged = False  # bytes dropped since the last good frame
        self._rejections = 0  # candidates counted since the last good frame
        self.dropped = 0

    @property
    def buffered(self) -> int:
        """Bytes held waiting for the rest of a frame: always fewer than ``MAX_FRAME``."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[Frame]:
        """Take the next bytes; return the frames they complete, in order."""
        self._buf += data
        frames: list[Frame] = []
        while True:
            start = self._buf.find(SYNC)
            if start < 0:
                keep = 1 if self._buf.endswith(SYNC[:1]) else 0
                self._drop(len(self._buf) - keep)
                return frames
            self._drop(start)
            if len(self._buf) < HEADER_SIZE:
                return frames
            kind, length, sequence = _HEADER.unpack_from(self._buf, 2)
            if not plausible_length(kind, length):
                self._reject(HEADER_SIZE)
                self._drop(1)
                continue
            size = HEADER_SIZE + length + CRC_SIZE
            if len(self._buf) < size:
                return frames
            crc = int.from_bytes(self._buf[size - CRC_SIZE : size], "little")
            if crc != crc16_ccitt_false(self._buf[2 : size - CRC_SIZE]):
                self._reject(size)
                self._drop(1)
                continue
            frames.append(Frame(kind, sequence, bytes(self._buf[HEADER_SIZE : size - CRC_SIZE])))
            self._take(size)

    def _drop(self, n: int) -> None:
        if n <= 0:
            return
        if not self._damaged:
            self._damaged = True
            self.dropped += 1
        del self._buf[:n]
        self._pos += n

    def _reject(self, span: int) -> None:
        """Count the candidate at the buffer's start, ``span`` bytes long, as rejected."""
        # A false start inside a candidate already counted is part of that candidate.
        if self._pos < self._rejected_end:
            return
        self._rejected_end = self._pos + span
        self._rejections += 1
        if self._rejections > 1:  # the first is the run's own count, made by _drop
            self.dropped += 1

    def _take(self, size: int) -> None:
        del self._buf[:size]
        self._pos += size
        self._rejected_end = self._pos
        self._damaged = False
        self._rejections = 0


# -- host side -----------------------------------------------------------------------


class ScanDecoder:
    """The scans among checked frames, held to the settings in effect; needs no port.

    ``readings`` and ``rev_hundredths`` are the settings the device acknowledged
    (None: any it may offer) and ``range_max_mm`` its largest range. A SCAN that
    disagrees with them, or that holds a range beyond ``range_max_mm``, is
    broken: ``take`` raises ``FrameError`` for it and the caller counts it as
    skipped. Each good scan becomes a ``ScanFrame``: angles in radians in the
    scanner frame, ranges in metres within 0..range_max, the device's revolution
    counter as sequence and its clock unwrapped to seconds.
    """

    def __init__(
        self,
        readings: int | None = None,
        rev_hundredths: int | None = None,
        range_max_mm: int = RANGE_MAX_MM,
    ):
        self.readings = readings
        self.rev_hundredths = rev_hundredths
        self.range_max_mm = range_max_mm
        self._clock = ClockUnwrapper(CLOCK_WRAP_US)

    def take(self, frame: Frame) -> ScanFrame | None:
        """The scan ``frame`` carries; None for a frame of another type."""
        if frame.kind != Kind.SCAN:
            return None
        if not plausible_length(frame.kind, len(frame.payload)):
            raise FrameError(
                f"scan frame with {with_article(f'{len(frame.payload)}-byte')} payload"
            )
        scan = _decode_scan(frame.payload)
        n = scan.ranges_mm.size
        if self.readings is not None and n != self.readings:
            raise FrameError(f"scan of {n} readings while {self.readings} are set")
        low, high = REV_HUNDREDTHS_RANGE
        expected = self.rev_hundredths
        if not low <= scan.rev_hundredths <= high or expected not in (None, scan.rev_hundredths):
            raise FrameError(f"scan at speed {scan.rev_hundredths} while {expected} is set")
        if n and int(scan.ranges_mm.max()) > self.range_max_mm:
            raise FrameError(
                f"scan with a range of {int(scan.ranges_mm.max())} mm, beyond range_max"
            )
        first_rad = scan.first_angle * TWO_PI / ANGLE_UNITS_PER_REV
        return ScanFrame(
            sequence=frame.sequence,
            device_time_s=self._clock(scan.timestamp_us) / 1e6,
            angles_rad=first_rad + TWO_PI * np.arange(n) / n,
            ranges_m=scan.ranges_mm / 1000.0,
            range_max_m=self.range_max_mm / 1000.0,
        )


_RESENDS = 2
"""Times a command is sent again after the device reports it arrived damaged."""


def _readings_offered() -> str:
    return ", ".join(map(str, READINGS_OFFERED[:-1])) + f" or {READINGS_OFFERED[-1]}"


def _speeds_offered() -> str:
    low, high = (h / 100 for h in REV_HUNDREDTHS_RANGE)
    return f"{low} to {high} rev/s in steps of 0.01"


class ExplorerDriver(Driver):
    """The Explorer on a serial port (segloc's framing; see docs/explorer-protocol.md)."""

    protocol = "explorer"
    default_baud = 115200

    def __init__(self, port: str, baud: int | None = None, timeout_s: float = 1.0):
        super().__init__(port, baud, timeout_s)
        self._stream = ExplorerStream()
        self._pending: deque[Frame] = deque()
        self._next_sequence = 0
        self._scans = ScanDecoder()

    def identify(self) -> DeviceInfo:
        """IDENTIFY → the model, serial number and firmware the device reports."""
        reply = self._request(Empty(Kind.IDENTIFY), Kind.IDENTITY, "IDENTIFY")
        if isinstance(reply, Nak):
            raise self._refused("IDENTIFY", reply)
        return DeviceInfo(
            self.protocol,
            printable(reply.model),
            printable(reply.serial_number),
            printable(reply.firmware),
        )

    def configure(self, readings: int | None, rev_per_s: float | None) -> dict[str, str]:
        """Readings per revolution and speed (rev/s); None keeps 1024 and 2.0.

        Returns the settings in effect for the log's metadata; ``DeviceError``
        naming what is offered for a value the Explorer cannot take.
        """
        readings = DEFAULT_READINGS if readings is None else int(readings)
        rev_per_s = DEFAULT_REV_HUNDREDTHS / 100 if rev_per_s is None else float(rev_per_s)
        if readings not in READINGS_OFFERED:
            raise self._bad_readings(readings)
        rev_hundredths = round(rev_per_s * 100) if np.isfinite(rev_per_s) else -1
        if not REV_HUNDREDTHS_RANGE[0] <= rev_hundredths <= REV_HUNDREDTHS_RANGE[1]:
            raise self._bad_speed(rev_per_s)
        reply = self._request(Configure(readings, rev_hundredths), Kind.CONFIG_ACK, "CONFIGURE")
        if isinstance(reply, Nak):
            if reply.code == NakCode.BAD_READINGS:
                raise self._bad_readings(readings)
            if reply.code == NakCode.BAD_SPEED:
                raise self._bad_speed(rev_per_s)
            raise self._refused("CONFIGURE", reply)
        for name, got, wanted in (
            ("readings", reply.readings, readings),
            ("speed", reply.rev_hundredths, rev_hundredths),
        ):
            if got != wanted:
                raise DeviceError(
                    f"{self.port}: the device acknowledged CONFIGURE with {name}={got}, "
                    f"not the {wanted} asked for; refusing its scans"
                )
        if reply.range_max_mm == 0:
            raise DeviceError(
                f"{self.port}: the device acknowledged CONFIGURE with range_max=0 mm; "
                "a scanner that sees nothing cannot be recorded"
            )
        self._scans = ScanDecoder(reply.readings, reply.rev_hundredths, reply.range_max_mm)
        return {
            "range_max_m": str(reply.range_max_mm / 1000.0),
            "readings": str(reply.readings),
            "rev_per_s": str(reply.rev_hundredths / 100),
            "field_of_view_deg": "360",
            "range_resolution_m": "0.001",
        }

    def start(self) -> None:
        """START, waiting for its acknowledgement; scans follow one revolution later."""
        reply = self._request(Empty(Kind.START), Kind.START_ACK, "START")
        if isinstance(reply, Nak):
            raise self._refused("START", reply)

    def read_scan(self) -> ScanFrame | None:
        """The next good SCAN frame, or None if none completes within ``timeout_s``."""
        deadline = time.monotonic() + self.timeout_s
        while True:
            while self._pending:
                frame = self._pending.popleft()
                try:
                    scan = self._scans.take(frame)  # None for a late or repeated reply
                except FrameError:
                    self.skipped += 1
                    continue
                if scan is not None:
                    return scan
            if time.monotonic() >= deadline:
                return None
            self._fill()

    def stop(self) -> None:
        """STOP (best effort: a device that has gone or does not answer is left alone)."""
        try:
            self._request(Empty(Kind.STOP), Kind.STOP_ACK, "STOP")
        except DeviceError:
            pass
        self._pending.clear()

    # -- helpers ---------------------------------------------------------------------
    def _send(self, message: Message) -> int:
        sequence = self._next_sequence
        self._next_sequence = (sequence + 1) & 0xFFFF
        self.write(encode_message(message, sequence))
        return sequence

    def _fill(self) -> int:
        """Read what has arrived into the frame queue; the number of bytes read."""
        data = self.read_available()
        if data:
            dropped = self._stream.dropped
            self._pending.extend(self._stream.feed(data))
            self.skipped += self._stream.dropped - dropped
        return len(data)

    def _decode(self, frame: Frame) -> Message | None:
        try:
            return decode_message(frame)
        except FrameError:
            self.skipped += 1
            return None

    # A reply of kind ``expected`` is what ``decode_message`` makes of that kind.
    @overload
    def _request(
        self, message: Message, expected: Literal[Kind.IDENTITY], what: str
    ) -> Identity | Nak: ...
    @overload
    def _request(
        self, message: Message, expected: Literal[Kind.CONFIG_ACK], what: str
    ) -> ConfigAck | Nak: ...
    @overload
    def _request(
        self, message: Message, expected: Literal[Kind.START_ACK, Kind.STOP_ACK], what: str
    ) -> Empty | Nak: ...
    def _request(self, message: Message, expected: Kind, what: str) -> Message:
        """Send a command and wait for its reply (or a NAK); frames before it are dropped."""
        sequence = self._send(message)
        resends = _RESENDS
        heard_bytes = 0
        heard_frames = 0
        deadline = time.monotonic() + self.timeout_s
        while True:
            while self._pending:
                frame = self._pending.popleft()
                heard_frames += 1
                if frame.kind not in (expected, Kind.NAK):
                    continue
                reply = self._decode(frame)
                if isinstance(reply, Nak) and reply.code == NakCode.BAD_FRAME:
                    # The device could not read a frame; it can only have been ours.
                    if resends == 0:
                        return reply
                    resends -= 1
                    sequence = self._send(message)
                elif reply is not None and frame.sequence == sequence:
                    return reply
            if time.monotonic() >= deadline:
                raise self._silence(what, heard_bytes, heard_frames)
            heard_bytes += self._fill()

    def _silence(self, what: str, heard_bytes: int, heard_frames: int) -> DeviceError:
        if heard_bytes and not heard_frames:
            return DeviceError(
                f"{self.port}: the device answered {what} with {heard_bytes} bytes that hold no "
                f"Explorer frame; it does not speak the explorer protocol "
                f"(check the protocol name and baud rate)"
            )
        return DeviceError(
            f"{self.port}: no answer to {what} within {self.timeout_s:g} s; "
            f"check the protocol name, baud rate ({self.baud}) and cable"
        )

    def _refused(self, what: str, nak: Nak) -> DeviceError:
        try:
            reason = NakCode(nak.code).name.lower().replace("_", " ")
        except ValueError:
            reason = "unknown error"
        return DeviceError(f"{self.port}: the device refused {what} (error {nak.code}: {reason})")

    def _bad_readings(self, readings: int) -> DeviceError:
        return DeviceError(
            f"{self.port}: {readings} readings per revolution is not offered; "
            f"the Explorer takes {_readings_offered()}"
        )

    def _bad_speed(self, rev_per_s: float) -> DeviceError:
        return DeviceError(
            f"{self.port}: {rev_per_s:g} rev/s is not offered; "
            f"the Explorer turns at {_speeds_offered()}"
        )


# -- device side ---------------------------------------------------------------------

DEFAULT_IDENTITY = Identity(model="SEO Explorer", serial_number="EMU-0001", firmware="emu-1.0")
_MAX_BACKLOG = 4
"""Revolutions a late poll still delivers; older ones are lost, as on a scanner."""


class ExplorerDevice(EmulatedDevice):
    """The Explorer's side of the protocol for ``segloc emulate``.

    Powers up at 1024 readings and 2.00 rev/s, not scanning. While started it
    sends one SCAN frame per revolution, when the revolution ends, stamped
    with the clock at its first reading (``now_s`` plus ``clock_offset_us``,
    modulo 2³²); the first reading points forward.
    """

    protocol = "explorer"

    def __init__(
        self,
        render: Callable[[np.ndarray], np.ndarray],
        corrupt: Callable[[], bool] = lambda: False,
        *,
        identity: Identity = DEFAULT_IDENTITY,
        clock_offset_us: int = 0,
    ):
        super().__init__(render, corrupt)
        self.identity = identity
        self.readings = DEFAULT_READINGS
        self.rev_hundredths = DEFAULT_REV_HUNDREDTHS
        self.scanning = False
        self._clock_offset_us = clock_offset_us
        self._stream = ExplorerStream()
        self._scan_sequence = 0
        self._sweep_start_s = 0.0  # when revolution 0 of the current run began
        self._revolutions = 0  # revolutions of the current run already sent or lost

    def receive(self, data: bytes, now_s: float) -> bytes:
        """Replies to the complete commands in ``data`` (plus earlier partial ones)."""
        dropped = self._stream.dropped
        frames = self._stream.feed(data)
        unreadable = Nak(NakCode.BAD_FRAME, 0)
        replies = [encode_message(unreadable, 0)] * (self._stream.dropped - dropped)
        replies += [encode_message(self._answer(f, now_s), f.sequence) for f in frames]
        return b"".join(replies)

    def poll(self, now_s: float) -> list[bytes]:
        """SCAN frames for the revolutions completed by ``now_s``."""
        if not self.scanning:
            return []
        period_s = 100.0 / self.rev_hundredths
        completed = int((now_s - self._sweep_start_s) / period_s)
        lost = completed - self._revolutions - _MAX_BACKLOG
        if lost > 0:
            self._revolutions += lost
            self._scan_sequence = (self._scan_sequence + lost) & 0xFFFF
        frames = []
        while self._revolutions < completed:
            frames.append(self._scan(self._sweep_start_s + self._revolutions * period_s))
            self._revolutions += 1
        return frames

    def _answer(self, frame: Frame, now_s: float) -> Message:
        if frame.kind not in COMMANDS:
            return Nak(NakCode.UNKNOWN_COMMAND, frame.kind)
        command = decode_message(frame)  # commands have fixed layouts: cannot fail
        if isinstance(command, Configure):
            return self._configure(command, now_s)
        if command.kind == Kind.IDENTIFY:
            return self.identity
        if command.kind == Kind.START:
            if not self.scanning:
                self.scanning = True
                self._restart(now_s)
            return Empty(Kind.START_ACK)
        self.scanning = False
        return Empty(Kind.STOP_ACK)

    def _configure(self, command: Configure, now_s: float) -> Message:
        if command.readings not in READINGS_OFFERED:
            return Nak(NakCode.BAD_READINGS, Kind.CONFIGURE)
        if not REV_HUNDREDTHS_RANGE[0] <= command.rev_hundredths <= REV_HUNDREDTHS_RANGE[1]:
            return Nak(NakCode.BAD_SPEED, Kind.CONFIGURE)
        self.readings = command.readings
        self.rev_hundredths = command.rev_hundredths
        self._restart(now_s)
        return ConfigAck(self.readings, self.rev_hundredths, RANGE_MAX_MM)

    def _restart(self, now_s: float) -> None:
        self._sweep_start_s = now_s
        self._revolutions = 0

    def _scan(self, start_s: float) -> bytes:
        angles_rad = TWO_PI * np.arange(self.readings) / self.readings
        ranges_mm = ranges_to_mm(self.render(angles_rad))
        timestamp_us = (self._clock_offset_us + round(start_s * 1e6)) % CLOCK_WRAP_US
        scan = ScanMessage(timestamp_us, self.rev_hundredths, 0, ranges_mm)
        frame = encode_message(scan, self._scan_sequence)
        self._scan_sequence = (self._scan_sequence + 1) & 0xFFFF
        if self.corrupt():
            frame = frame[:-1] + bytes([frame[-1] ^ 0xFF])
        return frame
