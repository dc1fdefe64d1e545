"""Hokuyo URG scanners over SCIP 2.0: the codec, the host driver and an emulated URG-04LX.

SCIP 2.0 is Hokuyo's public ASCII protocol. The host sends a command line
ending in LF; the device answers with the echoed command, a status line (two
characters and a checksum), data lines for commands that carry data, and an
empty line that ends the reply. A line's checksum character is the sum of its
bytes, kept to the low 6 bits, plus 0x30. Numbers are written six bits per
character (value + 0x30, most significant first) in 2, 3 or 4 characters, and
a number may straddle two data lines.

Scanner geometry (from the PP parameters): step ``s`` looks at
``(s - AFRT)·2π/ARES`` radians, counter-clockwise, 0 straight ahead; steps
``AMIN..AMAX`` are measured; ranges are millimetres and values below ``DMIN``
are error codes, read here as no return.

Nothing a device reports is trusted: the PP numbers must lie within the
bounds below (``parse_parameters``; a device outside them is refused naming
the field and its value), and a scan whose size disagrees with its request is
skipped and counted like one with a bad checksum. Text from VV and PP is
kept only as printable ASCII (other characters escaped) in the log and on screen.

The codec is plain functions on bytes and numpy arrays so it can be tested
without a port; ``Scip2Stream`` cuts a byte stream into replies and survives
garbage; ``ScanDecoder`` turns its replies into scans; ``Scip2Driver`` is the host
side and ``Scip2Device`` the emulator's.
"""

from __future__ import annotations

import math
import re
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from segloc_cli.devices import PROTOCOLS
from segloc_cli.devices.base import (
    SHOWN_CHARS,
    ClockUnwrapper,
    DeviceError,
    DeviceInfo,
    Driver,
    EmulatedDevice,
    FrameError,
    ScanFrame,
    printable,
)

LF = b"\n"
DATA_LINE_CHARS = 64
"""Data characters per line at most; the checksum character follows them."""
TIMESTAMP_MODULUS = 1 << 24
"""The device clock is 24 bits of milliseconds: it wraps every 4.66 hours."""
TIMESTAMP_CHARS = 4
SCAN_CHARS = {"MD": 3, "GD": 3, "MS": 2, "GS": 2}
"""Characters per range value: 3 (18 bits) for MD/GD, 2 (12 bits) for MS/GS."""
CONTINUOUS = ("MD", "MS")
FIELD_COMMANDS = (b"VV", b"PP", b"II")
"""Commands whose data lines are ``NAME:value;`` parameter lines."""
MAX_CLUSTER = 99
"""Largest cluster a scan command can ask for (two digits)."""
MAX_STEP = 9999
"""Largest step a scan command can name (four digits): AMAX above it cannot be scanned."""
MAX_ARES = 65_536
"""Most steps per revolution (ARES) accepted; real URG/UTM scanners have 1024, 1440 or 2880."""
MAX_RANGE_MM = (1 << 18) - 1
"""Largest DMAX accepted, mm: the largest range the 3-character MD encoding can carry."""
SCAN_RPM_RANGE = (60, 6000)
"""Motor speeds (SCAN, revolutions per minute) accepted: 1 to 100 scans per second."""
MAX_PP_DIGITS = 9
"""Digits a PP number may have; a longer one is out of every bound above."""
MAX_LINE_BYTES = 512
"""Longer runs without LF are garbage; only their tail is kept (it may end in an echo)."""
MAX_REPLY_LINES = 3 + -(-(MAX_STEP + 1) * SCAN_CHARS["MD"] // DATA_LINE_CHARS)
"""More lines than any reply has (echo, status, timestamp and the data lines of an MD
scan of every step up to ``MAX_STEP``, 472 in all): the end was lost."""

STATUS_TEXT = {
    "00": "command accepted",
    "01": "starting step is not a number",
    "02": "end step is not a number",
    "03": "cluster count is not a number",
    "04": "end step is out of range",
    "05": "end step is smaller than the starting step",
    "06": "scan interval is not a number",
    "07": "number of scans is not a number",
    "0E": "undefined command",
    "10": "the laser is off",
    "98": "resumed after checking the laser",
    "99": "scan data",
}

# An echo line: a command the host may have sent, optionally with a ";tag" string.
_ECHO = re.compile(
    rb"(?:[MG][DS]\d{10}(?:\d{3})?|VV|PP|II|BM|QT|RS|SCIP2\.0)(?:;[\x20-\x7e]{0,16})?\Z"
)


# --- the character codec ------------------------------------------------------------------------


def checksum(payload: bytes) -> int:
    """The checksum byte of a line's ``payload`` (the bytes before it, LF excluded)."""
    return (sum(payload) & 0x3F) + 0x30


def encode_value(value: int, chars: int) -> bytes:
    """``value`` in ``chars`` six-bit characters, most significant first.

    ``ValueError`` if it does not fit (a bug of the caller, not bad input).
    """
    if not 0 <= value < 1 << (6 * chars):
        raise ValueError(f"{value} does not fit in {chars} SCIP characters")
    return bytes(((value >> (6 * (chars - 1 - i))) & 0x3F) + 0x30 for i in range(chars))


def decode_value(text: bytes) -> int:
    """The number written by the six-bit characters ``text``; ``FrameError`` on a bad character."""
    return int(decode_values(text, max(len(text), 1))[0])


def encode_values(values: np.ndarray, chars: int) -> bytes:
    """Non-negative integers (N,) as N·``chars`` characters; ``ValueError`` if one does not fit."""
    values = np.asarray(values, dtype=np.int64).reshape(-1)
    if values.size and (values.min() < 0 or values.max() >= 1 << (6 * chars)):
        raise ValueError(f"values must lie in [0, {1 << (6 * chars)}) for {chars} characters")
    shifts = 6 * np.arange(chars - 1, -1, -1, dtype=np.int64)
    digits = ((values[:, None] >> shifts[None, :]) & 0x3F) + 0x30
    return digits.astype(np.uint8).tobytes()


def decode_values(text: bytes, chars: int) -> np.ndarray:
    """Integers (len(text)/chars,) int64 from six-bit characters.

    ``FrameError`` if the length is not a multiple of ``chars`` or a character
    lies outside 0x30..0x6F.
    """
    if chars < 1 or len(text) % chars:
        raise FrameError(f"{len(text)} data characters do not split into {chars}-character values")
    digits = np.frombuffer(bytes(text), dtype=np.uint8).astype(np.int64) - 0x30
    if digits.size and (digits.min() < 0 or digits.max() > 0x3F):
        raise FrameError("data character outside the SCIP range 0x30..0x6F")
    shifts = 6 * np.arange(chars - 1, -1, -1, dtype=np.int64)
    return (digits.reshape(-1, chars) << shifts[None, :]).sum(axis=1)


# --- reply layout -------------------------------------------------------------------------------


def data_lines(payload: bytes) -> bytes:
    """``payload`` cut into lines of at most 64 characters, each + checksum + LF."""
    out = bytearray()
    for i in range(0, len(payload), DATA_LINE_CHARS):
        chunk = payload[i : i + DATA_LINE_CHARS]
        out += chunk + bytes([checksum(chunk)]) + LF
    return bytes(out)


def field_lines(fields: dict[str, str]) -> bytes:
    """VV/PP/II data lines ``NAME:value;`` + checksum + LF (the checksum stops before ';')."""
    out = bytearray()
    for name, value in fields.items():
        text = f"{name}:{value}".encode("latin-1")
        out += text + b";" + bytes([checksum(text)]) + LF
    return bytes(out)


def format_reply(echo: bytes, status: bytes, body: bytes = b"") -> bytes:
    """A whole reply: echo, status + checksum, ``body`` (finished lines), empty line."""
    return echo + LF + status + bytes([checksum(status)]) + LF + body + LF


@dataclass(frozen=True)
class Reply:
    """One reply as received, checksums verified.

    ``echo``: the echoed command line (with its ";tag" if any); ``status``: two
    characters; ``lines``: the data lines without checksums (for VV/PP/II
    without the trailing ';').
    """

    echo: str
    status: str
    lines: tuple[bytes, ...] = ()

    @property
    def command(self) -> str:
        return self.echo[:2]


def parse_reply(lines: list[bytes]) -> Reply:
    """A ``Reply`` from its lines (echo first, LFs and the final empty line removed).

    ``FrameError`` for a missing status, a bad checksum or an overlong line.
    """
    if len(lines) < 2:
        raise FrameError("reply without a status line")
    echo, status_line = lines[0], lines[1]
    if not _ECHO.fullmatch(echo):
        raise FrameError(f"not an echo line: {echo[:32]!r}")
    if len(status_line) != 3 or status_line[2] != checksum(status_line[:2]):
        raise FrameError(f"bad status line {status_line[:8]!r}")
    fields = echo[:2] in FIELD_COMMANDS
    body = tuple(_field_text(line) if fields else _data_text(line) for line in lines[2:])
    return Reply(echo.decode("ascii"), status_line[:2].decode("latin-1"), body)


def _data_text(line: bytes) -> bytes:
    if not 2 <= len(line) <= DATA_LINE_CHARS + 1:
        raise FrameError(f"data line of {len(line)} bytes")
    if line[-1] != checksum(line[:-1]):
        raise FrameError("data line with a bad checksum")
    return line[:-1]


def _field_text(line: bytes) -> bytes:
    # The specification sums the text before ';'; some firmware sums the ';' too.
    if len(line) >= 3 and line[-2:-1] == b";":
        text = line[:-2]
        if line[-1] in (checksum(text), checksum(line[:-1])):
            return text
    elif len(line) >= 2 and line[-1] == checksum(line[:-1]):
        return line[:-1]
    raise FrameError(f"parameter line with a bad checksum: {line[:32]!r}")


def parse_fields(reply: Reply) -> dict[str, str]:
    """``{"DMIN": "20", ...}`` from a VV/PP/II reply; ``FrameError`` for a line without ':'."""
    out: dict[str, str] = {}
    for line in reply.lines:
        name, sep, value = line.decode("latin-1").partition(":")
        if not sep:
            raise FrameError(f"parameter line without ':': {line[:32]!r}")
        out[name] = value
    return out


class Scip2Stream:
    """Cuts a SCIP 2.0 byte stream into replies, whatever chunks it arrives in.

    ``feed`` returns, in order, a ``Reply`` for each well-formed reply and a
    ``FrameError`` (returned, not raised) for each reply that was broken: bad
    checksum, lost end, or lines that ran to an empty line without an echo
    (a reply whose echo was destroyed). Garbage between replies is dropped;
    the stream resynchronises on the next echo line, even one glued to
    garbage. Memory and work are bounded by the input.
    """

    def __init__(self) -> None:
        self._partial = bytearray()
        self._block: list[bytes] = []
        self._orphans = 0

    @property
    def buffered(self) -> int:
        """Bytes held for replies not yet complete: at most ``MAX_LINE_BYTES`` times
        ``MAX_REPLY_LINES + 1``, whatever was fed."""
        return len(self._partial) + sum(map(len, self._block))

    def feed(self, data: bytes) -> list[Reply | FrameError]:
        """Take the next bytes; return the replies (and broken replies) they complete."""
        self._partial += data
        *lines, rest = bytes(self._partial).split(LF)
        self._partial = bytearray(rest[-MAX_LINE_BYTES:])
        out: list[Reply | FrameError] = []
        for line in lines:
            self._take(line[:-1] if line.endswith(b"\r") else line, out)
        return out

    def _take(self, line: bytes, out: list[Reply | FrameError]) -> None:
        if not self._block:
            self._take_outside(line, out)
        elif not line:
            out.append(_parse_or_error(self._block))
            self._block = []
        elif _is_new_echo(line) or len(self._block) >= MAX_REPLY_LINES:
            out.append(FrameError("reply cut short: its end was lost"))
            self._block = []
            self._take_outside(line, out)
        else:
            self._block.append(line[-MAX_LINE_BYTES:])

    def _take_outside(self, line: bytes, out: list[Reply | FrameError]) -> None:
        if not line:
            if self._orphans >= 2:
                out.append(FrameError("reply lines without an echo line"))
            self._orphans = 0
            return
        echo = _ECHO.search(line)
        if echo:
            self._block = [echo.group()]
            self._orphans = 0
        else:
            self._orphans += 1


def _is_new_echo(line: bytes) -> bool:
    # An echo in the middle of a reply means the reply's empty last line was lost;
    # a data line that happens to look like an echo still passes its checksum.
    return bool(_ECHO.fullmatch(line)) and line[-1] != checksum(line[:-1])


def _parse_or_error(lines: list[bytes]) -> Reply | FrameError:
    try:
        return parse_reply(lines)
    except FrameError as exc:
        return exc


# --- scan requests and scan data ----------------------------------------------------------------


@dataclass(frozen=True)
class ScanRequest:
    """An MD/MS/GD/GS command: steps ``start_step..end_step`` grouped by ``cluster``.

    ``interval``: scans skipped between two sent (MD/MS); ``scans``: how many
    to send, 0 for until QT (MD/MS; in an echo of scan data, how many remain).
    """

    command: str
    start_step: int
    end_step: int
    cluster: int = 1
    interval: int = 0
    scans: int = 0

    @property
    def chars(self) -> int:
        return SCAN_CHARS[self.command]

    @property
    def readings(self) -> int:
        """Values per scan: one per cluster, the last cluster possibly short."""
        return -(-(self.end_step - self.start_step + 1) // max(self.cluster, 1))

    def text(self, scans: int | None = None) -> str:
        """The command line without LF; ``scans`` overrides the number-of-scans field."""
        head = f"{self.command}{self.start_step:04d}{self.end_step:04d}{self.cluster:02d}"
        if self.command in CONTINUOUS:
            head += f"{self.interval:01d}{self.scans if scans is None else scans:02d}"
        return head


def scan_request_fault(text: str) -> str | None:
    """The status a URG gives for a malformed MD/MS/GD/GS line (no ";tag"), or None.

    Checks the fields' digits, the length and the step order; the step range is
    the device's concern.
    """
    spans = [("01", 2, 6), ("02", 6, 10), ("03", 10, 12)]
    if text[:2] in CONTINUOUS:
        spans += [("06", 12, 13), ("07", 13, 15)]
    for status, lo, hi in spans:
        part = text[lo:hi]
        if len(part) != hi - lo or not (part.isascii() and part.isdigit()):
            return status
    if len(text) != spans[-1][2]:
        return "0E"
    if int(text[6:10]) < int(text[2:6]):
        return "05"
    return None


def parse_scan_request(echo: str) -> ScanRequest:
    """A ``ScanRequest`` from a command or echo line; ``FrameError`` if malformed."""
    text = echo.partition(";")[0]
    if text[:2] not in SCAN_CHARS:
        raise FrameError(f"not a scan command: {text[:16]!r}")
    fault = scan_request_fault(text)
    if fault:
        raise FrameError(f"bad scan command {text[:16]!r}: {STATUS_TEXT[fault]}")
    continuous = text[:2] in CONTINUOUS
    return ScanRequest(
        command=text[:2],
        start_step=int(text[2:6]),
        end_step=int(text[6:10]),
        cluster=int(text[10:12]),
        interval=int(text[12]) if continuous else 0,
        scans=int(text[13:15]) if continuous else 0,
    )


@dataclass(frozen=True)
class ScanData:
    """A decoded scan reply: the request as echoed, the device clock and the raw values.

    ``timestamp_ms``: 24-bit device clock, milliseconds; ``values`` (N,) int64:
    millimetres, or error codes below DMIN.
    """

    request: ScanRequest
    timestamp_ms: int
    values: np.ndarray


def decode_scan(reply: Reply) -> ScanData:
    """The scan in an MD/MS (status 99) or GD/GS (status 00) reply; ``FrameError`` otherwise.

    The data lines are joined before decoding, since a value may straddle two lines.
    """
    request = parse_scan_request(reply.echo)
    expected = "99" if request.command in CONTINUOUS else "00"
    if reply.status != expected:
        raise FrameError(f"{request.command} reply with status {reply.status}, not scan data")
    if not reply.lines or len(reply.lines[0]) != TIMESTAMP_CHARS:
        raise FrameError("scan reply without a timestamp line")
    timestamp_ms = decode_value(reply.lines[0])
    payload = b"".join(reply.lines[1:])
    if len(payload) != request.readings * request.chars:
        raise FrameError(
            f"scan of {len(payload)} data characters, expected "
            f"{request.readings} values × {request.chars}"
        )
    return ScanData(request, timestamp_ms, decode_values(payload, request.chars))


def step_angles(start_step: int, end_step: int, cluster: int, ares: int, afrt: int) -> np.ndarray:
    """Beam angles (readings,) in radians, scanner frame, of steps grouped by ``cluster``.

    Step ``s`` looks at ``(s - afrt)·2π/ares``; a cluster's angle is the mean of
    its steps' angles (the last cluster may hold fewer steps).
    """
    steps = np.arange(start_step, end_step + 1, dtype=float)
    angles = (steps - afrt) * (2.0 * math.pi / ares)
    starts = np.arange(0, steps.size, max(cluster, 1))
    counts = np.diff(np.append(starts, steps.size))
    return np.add.reduceat(angles, starts) / counts


def values_to_ranges_m(values: np.ndarray, dmin_mm: int, dmax_mm: int) -> np.ndarray:
    """Ranges (N,) in metres from raw values in mm; error codes (< DMIN) and > DMAX give 0."""
    values = np.asarray(values, dtype=np.int64)
    valid = (values >= dmin_mm) & (values <= dmax_mm)
    return np.where(valid, values / 1000.0, 0.0)


def describe_status(status: str) -> str:
    """Words for a status code, as the specification groups them."""
    if status in STATUS_TEXT:
        return STATUS_TEXT[status]
    # isdigit() alone takes superscripts and other scripts' digits, which int() refuses.
    code = int(status) if status.isascii() and status.isdigit() else -1
    if 21 <= code <= 49:
        return "processing stopped to check an error"
    if 50 <= code <= 97:
        return "hardware trouble (laser or motor)"
    return "unknown status"


# --- host side ----------------------------------------------------------------------------------

PP_INTEGERS = ("DMIN", "DMAX", "ARES", "AMIN", "AMAX", "AFRT", "SCAN")


def parse_parameters(fields: dict[str, str], port: str) -> dict[str, int]:
    """The PP numbers a driver relies on, each checked against its bounds.

    Steps: 1 ≤ ARES ≤ ``MAX_ARES``; 0 ≤ AMIN ≤ AFRT ≤ AMAX < ARES and AMAX ≤
    ``MAX_STEP``. Ranges, mm: 1 ≤ DMIN < DMAX ≤ ``MAX_RANGE_MM``. Speed, rpm: SCAN
    within ``SCAN_RPM_RANGE``. ``DeviceError`` naming ``port``, the first field
    at fault and its value (printable, cut short) otherwise.
    """
    raw = {name: fields.get(name, "").strip() for name in PP_INTEGERS}
    for name, text in raw.items():
        if not (text.isascii() and text.isdigit()):
            got = f"'{printable(text, SHOWN_CHARS)}'" if text else "nothing"
            raise DeviceError(f"{port}: the PP reply lacks a number for {name} (got {got})")
    # A number too long to matter is kept as text only for the message.
    pp = {name: int(text) if len(text) <= MAX_PP_DIGITS else -1 for name, text in raw.items()}

    def out_of_bounds(name: str, bound: str) -> DeviceError:
        return DeviceError(
            f"{port}: the device's PP parameter {name}={printable(raw[name], SHOWN_CHARS)} "
            f"is out of bounds ({bound}); refusing a device that reports it"
        )

    def within(name: str, low: int, high: int) -> bool:
        return len(raw[name]) <= MAX_PP_DIGITS and low <= pp[name] <= high

    if not within("ARES", 1, MAX_ARES):
        raise out_of_bounds("ARES", f"steps per revolution must be 1..{MAX_ARES}")
    last = min(pp["ARES"] - 1, MAX_STEP)
    if not within("AMAX", 0, last):
        raise out_of_bounds(
            "AMAX", f"the last step must be 0..{last}: below ARES={pp['ARES']}, at most {MAX_STEP}"
        )
    if not within("AFRT", 0, pp["AMAX"]):
        raise out_of_bounds("AFRT", f"the front step must be 0..AMAX={pp['AMAX']}")
    if not within("AMIN", 0, pp["AFRT"]):
        raise out_of_bounds("AMIN", f"the first step must be 0..AFRT={pp['AFRT']}")
    if not within("DMAX", 2, MAX_RANGE_MM):
        raise out_of_bounds("DMAX", f"the largest range must be 2..{MAX_RANGE_MM} mm")
    if not within("DMIN", 1, pp["DMAX"] - 1):
        raise out_of_bounds("DMIN", f"the smallest range must be 1..{pp['DMAX'] - 1} mm")
    if not within("SCAN", *SCAN_RPM_RANGE):
        low, high = SCAN_RPM_RANGE
        raise out_of_bounds("SCAN", f"the motor speed must be {low}..{high} rpm")
    return pp


def cluster_for(readings: int | None, first_step: int, last_step: int) -> int | None:
    """The cluster size (1..``MAX_CLUSTER``) giving ``readings`` values per scan over
    steps ``first_step..last_step``; 1 for None; None if no cluster size gives that many.

    Only sizes that divide the steps evenly count: a last, shorter cluster would put
    its value off the even spacing of the others, which a laser scan cannot hold.
    """
    if readings is None:
        return 1
    steps = last_step - first_step + 1
    cluster, rest = divmod(steps, readings) if readings > 0 else (0, 1)
    return cluster if rest == 0 and 1 <= cluster <= MAX_CLUSTER else None


def readings_offered(first_step: int, last_step: int) -> list[int]:
    """Every count of values per scan that a cluster size dividing these steps evenly gives,
    largest first."""
    steps = last_step - first_step + 1
    return [steps // c for c in range(1, MAX_CLUSTER + 1) if steps % c == 0]


class ScanDecoder:
    """The scans of one running MD/MS request among a ``Scip2Stream``'s items; needs no port.

    ``params`` are checked PP numbers (``parse_parameters``) and ``request`` the
    scan command sent. Each scan becomes a ``ScanFrame``: angles from the PP
    geometry (radians, scanner frame), ranges in metres within DMIN..DMAX and
    0 for no return, sequence numbers counted here from 0 and the device clock
    unwrapped to seconds. ``port`` only names the device in errors.
    """

    def __init__(self, params: dict[str, int], request: ScanRequest, port: str = "device"):
        self.params = params
        self.request = request
        self.port = port
        self.angles_rad = step_angles(
            request.start_step, request.end_step, request.cluster, params["ARES"], params["AFRT"]
        )
        self._sequence = 0
        self._clock = ClockUnwrapper(TIMESTAMP_MODULUS)

    def take(self, item: Reply | FrameError) -> ScanFrame | None:
        """The scan ``item`` carries; None if it carries none of this request's scans.

        Raises ``FrameError`` for a broken scan (damaged, or sized unlike the
        request): the caller skips and counts it. Raises ``DeviceError`` when the
        device reports that it stopped scanning.
        """
        if isinstance(item, FrameError):
            raise item
        if item.command not in CONTINUOUS:
            return None
        if item.status not in ("00", "98", "99"):
            raise DeviceError(
                f"{self.port}: the scanner stopped scanning: status {printable(item.status)} "
                f"({describe_status(item.status)})"
            )
        if item.status != "99":
            return None
        if replace(parse_scan_request(item.echo), scans=self.request.scans) != self.request:
            return None  # left over from an earlier scan request
        data = decode_scan(item)
        frame = ScanFrame(
            sequence=self._sequence,
            device_time_s=self._clock(data.timestamp_ms) / 1000.0,
            angles_rad=self.angles_rad.copy(),
            ranges_m=values_to_ranges_m(data.values, self.params["DMIN"], self.params["DMAX"]),
            range_max_m=self.params["DMAX"] / 1000.0,
        )
        self._sequence += 1
        return frame


class Scip2Driver(Driver):
    """A Hokuyo URG speaking SCIP 2.0 (USB URGs ignore the baud rate).

    ``identify`` reads VV and PP; ``configure`` picks steps AMIN..AMAX and a
    cluster count giving the readings asked for; ``start`` turns the laser on
    and asks for endless MD scans; ``read_scan`` returns them with sequence
    numbers counted here from 0 and the device clock unwrapped.
    """

    protocol = "scip2"
    default_baud = 115200

    def __init__(self, port: str, baud: int | None = None, timeout_s: float = 1.0):
        super().__init__(port, baud, timeout_s)
        self._stream = Scip2Stream()
        self._pending: deque[Reply | FrameError] = deque()
        self._heard = False
        self.parameters: dict[str, str] = {}
        self._pp: dict[str, int] = {}
        self._model = "URG"
        self._scan: ScanRequest | None = None
        self._decoder: ScanDecoder | None = None

    # -- requests and replies --
    def _next_item(self, deadline: float) -> Reply | FrameError | None:
        while not self._pending:
            if time.monotonic() >= deadline:
                return None
            data = self.read_available()
            if data:
                self._heard = True
                self._pending.extend(self._stream.feed(data))
        return self._pending.popleft()

    def _request(
        self, command: str, what: str, accept: Callable[[Reply], bool] = lambda r: True
    ) -> Reply:
        """Send ``command`` and wait for its reply, dropping anything else that comes."""
        self._heard = False
        self.write(command.encode("ascii") + LF)
        deadline = time.monotonic() + self.timeout_s
        while (item := self._next_item(deadline)) is not None:
            if isinstance(item, Reply) and item.echo == command and accept(item):
                return item
        if self._heard:
            others = ", ".join(sorted(set(PROTOCOLS) - {self.protocol})) or "none"
            raise DeviceError(
                f"{self.port}: the device answers, but not in SCIP 2.0 (no valid reply to "
                f"{what} within {self.timeout_s:g} s); check the protocol name "
                f"(other protocols: {others})"
            )
        raise DeviceError(
            f"{self.port}: no answer to {what} within {self.timeout_s:g} s; "
            "check the protocol name, baud rate and cable"
        )

    def _expect(self, reply: Reply, what: str, ok: tuple[str, ...] = ("00",)) -> None:
        if reply.status not in ok:
            raise DeviceError(
                f"{self.port}: the scanner refused {what}: status {printable(reply.status)} "
                f"({describe_status(reply.status)})"
            )

    # -- the protocol --
    def identify(self) -> DeviceInfo:
        # SCIP2.0 switches a URG still in SCIP 1.1 mode; QT stops a scan left running.
        self.write(b"SCIP2.0\nQT\n")
        version = self._request("VV", "VV (version request)")
        self._expect(version, "VV")
        params = self._request("PP", "PP (parameter request)")
        self._expect(params, "PP")
        try:
            info = parse_fields(version)
            self.parameters = parse_fields(params)
        except FrameError as exc:
            raise DeviceError(f"{self.port}: unreadable VV/PP reply ({exc})") from exc
        self._pp = parse_parameters(self.parameters, self.port)
        # Text from the device is stored and printed: keep it printable and on one line.
        info = {printable(k): printable(v) for k, v in info.items()}
        self.parameters = {printable(k): printable(v) for k, v in self.parameters.items()}
        self._model = info.get("PROD") or self.parameters.get("MODL") or "URG"
        extra = {"protocol_version": info.get("PROT", "")}
        if "VEND" in info:
            extra["vendor"] = info["VEND"]
        if "MODL" in self.parameters:
            extra["model_code"] = self.parameters["MODL"]
        return DeviceInfo(
            protocol=self.protocol,
            model=self._model,
            serial_number=info.get("SERI", ""),
            firmware=info.get("FIRM", ""),
            extra=extra,
        )

    def configure(self, readings: int | None, rev_per_s: float | None) -> dict[str, str]:
        if not self._pp:
            self.identify()
        pp = self._pp
        speed = pp["SCAN"] / 60.0
        if rev_per_s is not None and not math.isclose(rev_per_s, speed, rel_tol=1e-3):
            raise DeviceError(
                f"{self.port}: the {self._model} turns at a fixed {speed:g} rev/s "
                f"({pp['SCAN']} rpm); it cannot scan at {rev_per_s:g} rev/s"
            )
        cluster = self._cluster_for(readings)
        request = ScanRequest("MD", pp["AMIN"], pp["AMAX"], cluster)
        self._scan = request
        angles_rad = step_angles(
            request.start_step, request.end_step, cluster, pp["ARES"], pp["AFRT"]
        )
        settings = {
            "range_min_m": f"{pp['DMIN'] / 1000.0:g}",
            "range_max_m": f"{pp['DMAX'] / 1000.0:g}",
            "readings": str(request.readings),
            "rev_per_s": f"{speed:g}",
            "angle_min_rad": repr(float(angles_rad[0])),
            "angle_max_rad": repr(float(angles_rad[-1])),
            "angle_increment_rad": repr(cluster * 2.0 * math.pi / pp["ARES"]),
            "encoding": request.command,
            "cluster": str(cluster),
            "first_step": str(request.start_step),
            "last_step": str(request.end_step),
        }
        settings.update({f"pp.{k}": v for k, v in self.parameters.items()})
        return settings

    def _cluster_for(self, readings: int | None) -> int:
        first, last = self._pp["AMIN"], self._pp["AMAX"]
        cluster = cluster_for(readings, first, last)
        if cluster is None:
            possible = ", ".join(map(str, readings_offered(first, last)))
            raise DeviceError(
                f"{self.port}: the {self._model} cannot give {readings} readings per scan "
                f"over steps {first}..{last}; possible: {possible}"
            )
        return cluster

    def start(self) -> None:
        if self._scan is None:
            self.configure(None, None)
        assert self._scan is not None
        self._expect(self._request("BM", "BM (laser on)"), "BM", ("00", "02"))
        command = self._scan.text()
        reply = self._request(command, f"{command} (start scanning)", lambda r: r.status != "99")
        self._expect(reply, command)
        self._decoder = ScanDecoder(self._pp, self._scan, self.port)

    def read_scan(self) -> ScanFrame | None:
        if self._decoder is None:
            raise DeviceError(f"{self.port}: read_scan before start")
        deadline = time.monotonic() + self.timeout_s
        while (item := self._next_item(deadline)) is not None:
            try:
                frame = self._decoder.take(item)
            except FrameError:
                self.skipped += 1
                continue
            if frame is not None:
                return frame
        return None

    def stop(self) -> None:
        try:
            self._request("QT", "QT (laser off)")
        except DeviceError:
            pass


# --- device side --------------------------------------------------------------------------------

URG_04LX_VERSION = {
    "VEND": "Hokuyo Automatic Co.,Ltd.",
    "PROD": "SOKUIKI Sensor URG-04LX",
    "FIRM": "3.3.00,07/05/31(20-5600[mm],240[deg])",
    "PROT": "SCIP 2.0",
    "SERI": "H0807301",
}
URG_04LX_PARAMETERS = {
    "MODL": "URG-04LX(Hokuyo Automatic Co.,Ltd.)",
    "DMIN": "20",
    "DMAX": "5600",
    "ARES": "1024",
    "AMIN": "44",
    "AMAX": "725",
    "AFRT": "384",
    "SCAN": "600",
}
_URG_04LX = {k: int(v) for k, v in URG_04LX_PARAMETERS.items() if k != "MODL"}
URG_04LX_LAST_STEP = 768
"""Steps 0..768 may be asked for; outside AMIN..AMAX they read as error codes."""
NO_RETURN_CODE = 1
"""The error code sent for a beam without a valid return (any value below DMIN would do)."""
MAX_COMMAND_BYTES = 256
MAX_FRAMES_PER_POLL = 10
"""Scans sent at most by one poll; a clock further ahead skips the scans it missed."""


@dataclass
class _Streaming:
    request: ScanRequest
    tag: bytes
    remaining: int | None
    """Scans still to send; None for until QT."""
    next_due_s: float


class Scip2Device(EmulatedDevice):
    """An emulated Hokuyo URG-04LX answering SCIP 2.0 (VV PP II BM QT RS MD MS GD GS).

    Scans come every 60/SCAN s (0.1 s) of the device clock ``now_s``; the
    timestamps are that clock in milliseconds from ``clock_start_ms``, modulo 2²⁴.
    A cluster reports its smallest valid range, as a URG does; a step with no
    valid return (0, below DMIN, above DMAX or beyond the encoding) is sent as
    error code 1.

    ``version`` and ``parameters`` replace the VV and PP fields it reports (the
    URG-04LX's by default) without changing how it scans: a device that
    misreports itself, for testing a host.
    """

    protocol = "scip2"

    def __init__(
        self,
        render: Callable[[np.ndarray], np.ndarray],
        corrupt: Callable[[], bool] = lambda: False,
        clock_start_ms: int = 0,
        *,
        version: dict[str, str] | None = None,
        parameters: dict[str, str] | None = None,
    ):
        super().__init__(render, corrupt)
        self.clock_start_ms = clock_start_ms
        self.version = dict(URG_04LX_VERSION if version is None else version)
        self.parameters = dict(URG_04LX_PARAMETERS if parameters is None else parameters)
        self.laser_on = False
        self._buffer = bytearray()
        self._streaming: _Streaming | None = None

    @property
    def period_s(self) -> float:
        """Time of one revolution, seconds."""
        return 60.0 / _URG_04LX["SCAN"]

    def receive(self, data: bytes, now_s: float) -> bytes:
        self._buffer += data
        out = bytearray()
        while (end := _line_end(self._buffer)) >= 0:
            line = bytes(self._buffer[:end])
            del self._buffer[: end + 1]
            if line:
                out += self._answer(line, now_s)
        if len(self._buffer) > MAX_COMMAND_BYTES:
            self._buffer.clear()  # no command is this long: noise on the line
        return bytes(out)

    def poll(self, now_s: float) -> list[bytes]:
        frames: list[bytes] = []
        stream = self._streaming
        if stream is None:
            return frames
        step_s = self.period_s * (stream.request.interval + 1)
        if now_s - stream.next_due_s > MAX_FRAMES_PER_POLL * step_s:
            stream.next_due_s += math.floor((now_s - stream.next_due_s) / step_s) * step_s
        while self._streaming is stream and stream.next_due_s <= now_s:
            scans = 0
            if stream.remaining is not None:
                stream.remaining -= 1
                scans = stream.remaining
                if stream.remaining <= 0:
                    self._streaming = None
            echo = stream.request.text(scans).encode("ascii") + stream.tag
            frames.append(self._scan_reply(echo, b"99", stream.request, stream.next_due_s))
            stream.next_due_s += step_s
        return frames

    # -- commands --
    def _answer(self, line: bytes, now_s: float) -> bytes:
        text = line.decode("latin-1")
        command, semicolon, _ = text.partition(";")
        tag = line[len(command) :] if semicolon else b""
        name = command[:2]
        if command == "VV":
            return format_reply(line, b"00", field_lines(self.version))
        if command == "PP":
            return format_reply(line, b"00", field_lines(self.parameters))
        if command == "II":
            return format_reply(line, b"00", field_lines(self._state(now_s)))
        if command == "BM":
            status = b"02" if self.laser_on else b"00"
            self.laser_on = True
            return format_reply(line, status)
        if command in ("QT", "RS"):
            self._streaming = None
            self.laser_on = False
            return format_reply(line, b"00")
        if name in SCAN_CHARS:
            return self._scan_command(line, command, tag, now_s)
        return format_reply(line, b"0E")

    def _scan_command(self, line: bytes, command: str, tag: bytes, now_s: float) -> bytes:
        fault = scan_request_fault(command)
        request = None if fault else parse_scan_request(command)
        if request is None or request.end_step > URG_04LX_LAST_STEP:
            return format_reply(line, (fault or "04").encode("ascii"))
        if request.command in CONTINUOUS:
            self.laser_on = True  # MD/MS switch the laser on themselves
            first_due_s = (math.floor(now_s / self.period_s) + 1) * self.period_s
            remaining = request.scans or None
            self._streaming = _Streaming(request, tag, remaining, first_due_s)
            return format_reply(line, b"00")
        if not self.laser_on:
            return format_reply(line, b"10")
        return self._scan_reply(line, b"00", request, now_s)

    def _state(self, now_s: float) -> dict[str, str]:
        return {
            "MODL": URG_04LX_PARAMETERS["MODL"],
            "LASR": "ON" if self.laser_on else "OFF",
            "SCSP": f"Initial({URG_04LX_PARAMETERS['SCAN']}[rpm])",
            "MESM": "Measuring" if self._streaming else "Idle",
            "SBPS": "Initial(115200[bps])",
            "TIME": self._timestamp(now_s).decode("ascii"),
            "STAT": "Stable 000 no error.",
        }

    # -- scans --
    def _timestamp(self, now_s: float) -> bytes:
        ms = (self.clock_start_ms + round(now_s * 1000.0)) % TIMESTAMP_MODULUS
        return encode_value(ms, TIMESTAMP_CHARS)

    def _scan_reply(self, echo: bytes, status: bytes, request: ScanRequest, now_s: float) -> bytes:
        stamp = self._timestamp(now_s)
        body = bytearray(stamp + bytes([checksum(stamp)]) + LF)
        payload = encode_values(self.measure(request), request.chars)
        body += data_lines(payload)
        if self.corrupt():
            # Flip a bit of the first data line's checksum (it stays a SCIP character).
            body[TIMESTAMP_CHARS + 2 + min(len(payload), DATA_LINE_CHARS)] ^= 0x01
        return format_reply(echo, status, bytes(body))

    def measure(self, request: ScanRequest) -> np.ndarray:
        """Raw values (request.readings,) for one scan: mm, or the no-return error code."""
        pp = _URG_04LX
        steps = np.arange(request.start_step, request.end_step + 1)
        angles_rad = step_angles(request.start_step, request.end_step, 1, pp["ARES"], pp["AFRT"])
        ranges_m = np.asarray(self.render(angles_rad), dtype=float)
        with np.errstate(invalid="ignore"):
            mm = np.where(np.isfinite(ranges_m), np.round(ranges_m * 1000.0), 0.0)
        largest = min(pp["DMAX"], (1 << (6 * request.chars)) - 1)
        valid = (mm >= pp["DMIN"]) & (mm <= largest) & (steps >= pp["AMIN"]) & (steps <= pp["AMAX"])
        # The smallest valid range of each cluster: invalid steps never win the minimum.
        candidates = np.where(valid, mm, np.inf)
        starts = np.arange(0, steps.size, max(request.cluster, 1))
        nearest = np.minimum.reduceat(candidates, starts)
        return np.where(np.isfinite(nearest), nearest, NO_RETURN_CODE).astype(np.int64)


def _line_end(buffer: bytearray) -> int:
    """Index of the first CR or LF in ``buffer``, -1 if none (commands may end in either)."""
    ends = [i for i in (buffer.find(b"\n"), buffer.find(b"\r")) if i >= 0]
    return min(ends) if ends else -1
