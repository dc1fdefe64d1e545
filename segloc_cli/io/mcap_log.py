"""The MCAP log: laser scans, odometry and the sensor settings of a recording.

Layout (JSON message encoding, opens in Foxglove as is):

- ``/scan``: ``foxglove.LaserScan`` in frame ``laser`` (the scanner's own) with an
  identity pose. Beam angles are evenly spaced from ``start_angle`` to ``end_angle``
  inclusive; invalid readings (<= 0, non-finite, >= the maximum range or
  ``MAX_RANGE_M``) are written as 0.
- ``/odom``: ``foxglove.PoseInFrame``, the robot's pose in frame ``world``
  (x, y in metres, heading as a rotation about +z).
- Metadata record ``segloc.sensor``: the sensor settings as str → str,
  including ``range_max_m`` and, when the scanner is not at the robot's origin, its
  pose on the robot (``laser_x_m``, ``laser_y_m``, ``laser_theta_deg``,
  ``laser_offset_source``: see ``segloc_cli.io.log``), which ``read_log`` gives every
  scan as ``Scan.mount``. It is written first so that a log cut short keeps it.

Each ``/scan`` record's log time is the scan's time; its publish time is the
scan's original time when an importer had to make colliding times distinct
(else the same), so the source's own times survive the conversion.

Messages go into zstd-compressed chunks of up to ``CHUNK_BYTES`` (uncompressed), each
followed by its message indexes and listed in the summary's chunk indexes, so a reader
can seek to any time. A writer given ``durable_every_s`` (the recorder) also ends its chunk
and flushes the file once the chunk's first message is that old, so a recorder killed
mid-run loses at most the messages of that last stretch; ``read_log`` reads such
unfinished files record by record and keeps every complete chunk. The file is written in
place, not renamed into place: a recording is read while it grows. An OS error while
writing is an ``OutputError`` naming the file.

Reading a log nobody tuned segloc for. ``read_log`` refuses the whole file
(``InputError``, one line naming it) only for what spoils every message: not
MCAP, no ``/scan`` channel, a ``/scan`` or ``/odom`` channel that is not JSON,
an unusable ``range_max_m`` or laser offset in ``segloc.sensor`` (they apply to every
scan), or
``/scan`` messages none of which is usable. A single bad message is skipped and
counted instead, with one warning line per kind of fault giving the count and
the first message numbers (counted from 1 per topic), so that every good scan
is kept. Skipped ``/scan`` messages: not a JSON object (malformed, nested too
deep, numbers too long to read); larger than ``MAX_MESSAGE_BYTES`` or with more
than ``MAX_READINGS`` readings; a timestamp that is not whole ``sec``/``nsec``
within 0 to ``MAX_TIME_NS``; ``start_angle``/``end_angle`` missing, not numbers
or not finite; a fan that is not one (``segloc_cli.scan.fan_defect``: angles that
decrease, more than one reading with ``start_angle == end_angle``, a span over a
full turn, angles beyond ±4π); ``ranges`` missing or not a list of numbers. Skipped ``/odom``
messages: not a JSON object, too large, a bad timestamp, a position or
orientation missing, not numbers or not finite, an all-zero quaternion.
Intensities that are not one number per reading are dropped (the scan is kept).
Readings that are invalid (``Scan.valid``: non-finite, <= 0, at or beyond the
sensor's range or ``MAX_RANGE_M``) read back as 0. Scans whose times repeat or
go back get a warning; their times are left as they are. Chunked and compressed
files (zstd, lz4) are read too; a chunk that would decompress to more than
``MAX_CHUNK_BYTES``, or that cannot be decompressed, ends the reading there like
a corrupt record (a warning, the messages before it kept).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import struct
import time
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import TracebackType
from typing import IO, cast

import numpy as np
from mcap.exceptions import EndOfFile
from mcap.records import Channel, Chunk, Footer, Message, Metadata
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import CompressionType, Writer

from segloc_cli.errors import InputError
from segloc_cli.geometry import Pose2, heading_to_quaternion, quaternion_to_heading, wrap_angle
from segloc_cli.io.files import reading, writing_error
from segloc_cli.io.log import SENSOR_METADATA_NAME, Log, laser_offset_of
from segloc_cli.io.other_logs import (
    HEAD_BYTES,
    ROS2_METADATA,
    conversion,
    inside_ros2_bag,
    other_log,
)
from segloc_cli.io.runview import RUN_METADATA_NAME
from segloc_cli.limits import MAX_COORDINATE_M
from segloc_cli.progress import SILENT, Progress
from segloc_cli.scan import MAX_READINGS, Scan, evenly_spaced_angles, fan_defect
from segloc_cli.wording import counted, plural

SCAN_TOPIC = "/scan"
ODOM_TOPIC = "/odom"
SCAN_SCHEMA_NAME = "foxglove.LaserScan"
ODOM_SCHEMA_NAME = "foxglove.PoseInFrame"
SCAN_FRAME_ID = "laser"
WORLD_FRAME_ID = "world"
ANGLE_SPACING_TOLERANCE_RAD = 1e-9
MCAP_MAGIC = b"\x89MCAP0\r\n"

ROS_ENCODINGS = ("cdr", "ros1", "ros2msg")
"""Message encodings of ROS bags written as MCAP (``segloc import rosbag`` reads them)."""
MAX_MESSAGE_BYTES = 16 * 2**20
"""Largest ``/scan`` or ``/odom`` message (bytes) that is decoded: ``MAX_READINGS`` readings
and their intensities take about 5 MB of JSON, so a larger message is skipped unread."""

MAX_CHUNK_BYTES = 512 * 2**20
"""Largest decompressed MCAP chunk (bytes); a chunk claiming more is taken as corrupt, so that
a small compressed file cannot expand to fill memory."""

MAX_TIME_NS = 2**63 - 1
"""Latest time (ns since the epoch of the log's clock) in a log: the signed 64-bit range that
ROS and MCAP tools use; a later timestamp is corrupt."""

# --- schemas (field layout of the Foxglove JSON schemas) -------------------------


def _time_schema(what: str) -> dict:
    return {
        "type": "object",
        "title": "time",
        "properties": {
            "sec": {"type": "integer", "minimum": 0},
            "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
        },
        "description": f"Timestamp of {what}",
    }


def _xyz_properties(names: str) -> dict:
    return {n: {"type": "number", "description": f"{n} value"} for n in names}


def _pose_schema(description: str) -> dict:
    return {
        "title": "foxglove.Pose",
        "description": description,
        "type": "object",
        "properties": {
            "position": {
                "title": "foxglove.Vector3",
                "description": "Position in 3D space",
                "type": "object",
                "properties": _xyz_properties("xyz"),
            },
            "orientation": {
                "title": "foxglove.Quaternion",
                "description": "Orientation in 3D space",
                "type": "object",
                "properties": _xyz_properties("xyzw"),
            },
        },
    }


LASER_SCAN_SCHEMA = {
    "title": SCAN_SCHEMA_NAME,
    "description": "A single scan from a planar laser range-finder",
    "type": "object",
    "properties": {
        "timestamp": _time_schema("scan"),
        "frame_id": {"type": "string", "description": "Frame of reference"},
        "pose": _pose_schema("Origin of the scan relative to the frame of reference"),
        "start_angle": {"type": "number", "description": "Bearing of the first point, radians"},
        "end_angle": {"type": "number", "description": "Bearing of the last point, radians"},
        "ranges": {
            "type": "array",
            "items": {"type": "number"},
            "description": "Ranges at equally spaced angles from start_angle to end_angle",
        },
        "intensities": {
            "type": "array",
            "items": {"type": "number"},
            "description": "Intensity of each detection",
        },
    },
}

POSE_IN_FRAME_SCHEMA = {
    "title": ODOM_SCHEMA_NAME,
    "description": "A timestamped pose in a frame of reference",
    "type": "object",
    "properties": {
        "timestamp": _time_schema("pose"),
        "frame_id": {"type": "string", "description": "Frame of reference of the pose"},
        "pose": _pose_schema("Pose in 3D space"),
    },
}

_IDENTITY_POSE = {
    "position": {"x": 0.0, "y": 0.0, "z": 0.0},
    "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
}


# --- time ----------------------------------------------------------------------


def _time_ns(time_s: float) -> int:
    if not math.isfinite(time_s) or time_s < 0 or round(time_s * 1e9) > MAX_TIME_NS:
        raise ValueError(f"log times must be finite and from 0 to 2^63 ns, got {time_s} s")
    return round(time_s * 1e9)


def _range_max(text: str) -> float | None:
    """The sensor's ``range_max_m`` setting as metres, or None when it is not a positive
    finite number or an explicit infinity ("inf"): "1e400" overflows and is refused."""
    if text.strip().lower().lstrip("+") in ("inf", "infinity"):
        return math.inf
    try:
        value = float(text)
    except ValueError:
        return None
    return value if math.isfinite(value) and value > 0 else None


def _spacing_error(scan: Scan) -> tuple[float, float, float]:
    """First and last beam angle of ``scan`` and how far (rad) its angles are from evenly
    spaced between them."""
    angles = np.asarray(scan.angles_rad, dtype=float).reshape(-1)
    n = len(angles)
    start, end = (float(angles[0]), float(angles[-1])) if n else (0.0, 0.0)
    error = np.max(np.abs(angles - evenly_spaced_angles(n, start, end)), initial=0.0)
    return start, end, float(error)


def _check_scan(scan: Scan, original_time_s: float | None) -> tuple[float, float, int, int]:
    """``start, end, time_ns, publish_ns`` of a scan to write; ``ValueError`` if it cannot be."""
    start, end, spacing_error = _spacing_error(scan)
    if spacing_error > ANGLE_SPACING_TOLERANCE_RAD:
        raise ValueError(
            f"scan at t={scan.time_s} s: beam angles are not evenly spaced "
            f"(off by up to {spacing_error:.3g} rad); foxglove.LaserScan cannot store them"
        )
    time_ns = _time_ns(float(scan.time_s))
    publish_ns = time_ns if original_time_s is None else _time_ns(float(original_time_s))
    return start, end, time_ns, publish_ns


def _stamp(time_ns: int) -> dict:
    sec, nsec = divmod(time_ns, 1_000_000_000)
    return {"sec": sec, "nsec": nsec}


# --- writing -------------------------------------------------------------------


CHUNK_BYTES = 4 * 1024 * 1024
"""Largest chunk (uncompressed bytes) before the writer starts another: about 4,000 scans of
180 readings, compressed to a few hundred kB."""


class LogWriter:
    """Writes a segloc MCAP log; use as a context manager.

    ``sensor`` holds the recording's settings as str → str and must include
    ``range_max_m``, a positive number or ``"inf"`` when the sensor has none
    (``ValueError`` otherwise, before the file is created). Its laser offset
    (``segloc_cli.io.log.laser_offset_of``; the robot's origin when absent) is the
    mounting every scan written must have, as the scans are stored in the scanner's
    frame and the offset only in the settings (``ValueError`` for a malformed offset
    or a scan mounted otherwise). With
    ``durable_every_s`` (seconds) no message waits longer than that in memory
    once ``make_durable_if_due`` or another message comes: the chunk is ended and
    the file flushed. An OS error while writing raises ``OutputError`` naming
    the file.
    """

    def __init__(
        self, path: str | Path, sensor: dict[str, str], durable_every_s: float | None = None
    ):
        sensor = {str(k): str(v) for k, v in sensor.items()}
        if "range_max_m" not in sensor:
            raise ValueError("sensor settings must include 'range_max_m' (use 'inf' if none)")
        range_max_m = _range_max(sensor["range_max_m"])
        if range_max_m is None:
            raise ValueError(
                f"sensor range_max_m must be a positive number or 'inf', "
                f"got {sensor['range_max_m']!r}"
            )
        self.range_max_m = range_max_m
        try:
            self.laser_offset = laser_offset_of(sensor)
        except InputError as exc:
            raise ValueError(str(exc)) from None
        self.path = Path(path)
        self._durable_every_s = durable_every_s
        # Monotonic time of the oldest message not yet on disk; the first is due at once, so
        # that the channels (written with it, in its chunk) are on disk from the first scan.
        self._pending_since: float | None = -math.inf
        self._closed = True
        try:
            self._file = open(self.path, "wb")
        except OSError as exc:
            raise writing_error(self.path, exc) from None
        self._closed = False
        try:
            self._writer = Writer(
                self._file, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD
            )
            self._writer.start(profile="", library="segloc")
            self._writer.add_metadata(SENSOR_METADATA_NAME, sensor)
            scan_schema = self._writer.register_schema(
                SCAN_SCHEMA_NAME, "jsonschema", json.dumps(LASER_SCAN_SCHEMA).encode()
            )
            odom_schema = self._writer.register_schema(
                ODOM_SCHEMA_NAME, "jsonschema", json.dumps(POSE_IN_FRAME_SCHEMA).encode()
            )
            self._scan_channel = self._writer.register_channel(SCAN_TOPIC, "json", scan_schema)
            self._odom_channel = self._writer.register_channel(ODOM_TOPIC, "json", odom_schema)
            self._sequence = {self._scan_channel: 0, self._odom_channel: 0}
            self._file.flush()
        except OSError as exc:
            self._closed = True
            with contextlib.suppress(OSError):
                self._file.close()
            raise writing_error(self.path, exc) from None

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()

    def _add(self, channel_id: int, time_ns: int, message: dict, publish_ns: int) -> None:
        if self._closed:
            raise ValueError(f"{self.path}: the log is closed")
        data = json.dumps(message, allow_nan=False, separators=(",", ":")).encode()
        try:
            self._writer.add_message(
                channel_id,
                log_time=time_ns,
                data=data,
                publish_time=publish_ns,
                sequence=self._sequence[channel_id],
            )
        except OSError as exc:
            raise writing_error(self.path, exc) from None
        self._sequence[channel_id] += 1
        if self._pending_since is None:
            self._pending_since = time.monotonic()
        self.make_durable_if_due()

    def make_durable_if_due(self) -> None:
        """With ``durable_every_s``: end the chunk and flush the file if its oldest message
        has waited that long (a recorder calls this while it waits for the next scan)."""
        if self._durable_every_s is None or self._pending_since is None or self._closed:
            return
        if time.monotonic() - self._pending_since < self._durable_every_s:
            return
        try:
            self._writer.flush()  # ends the chunk in progress
        except OSError as exc:
            raise writing_error(self.path, exc) from None
        self._pending_since = None

    def add_scan(
        self, scan: Scan, original_time_s: float | None = None, number: int | None = None
    ) -> None:
        """Append a scan. Its angles must be evenly spaced and its time finite and >= 0
        (``ValueError`` otherwise, nothing written).

        ``original_time_s`` (seconds), when given, is the time the scan had in its source
        before an importer made colliding times distinct; it becomes the record's publish
        time, and ``read_log`` returns it in ``Log.original_times_s``. ``number``, when
        given, is the scan's number in its source (``Log.numbers``; give every scan one,
        no two alike, or none); by default the scan after the last one. It is kept as the
        record's sequence number (``number`` − 1) and ``read_log`` returns it.
        """
        start, end, time_ns, publish_ns = _check_scan(scan, original_time_s)
        if number is not None and not 1 <= number <= 2**32:
            raise ValueError(f"scan number {number} is not in 1 to 2**32")
        if scan.mount != self.laser_offset:
            raise ValueError(
                f"scan at t={scan.time_s} s is mounted at {scan.mount}, but the log's sensor "
                f"settings give the laser offset {self.laser_offset}"
            )
        ranges = np.asarray(scan.ranges_m, dtype=float).reshape(-1)
        # A reading is kept only if it is valid for the scan and for the log's sensor,
        # so that what is read back is valid exactly when it was written valid.
        with np.errstate(invalid="ignore"):
            keep = scan.valid.reshape(-1) & (ranges < self.range_max_m)
        ranges_out = np.where(keep, ranges, 0.0)
        intensities = np.asarray(scan.intensities, dtype=float).reshape(-1)
        intensities = np.where(np.isfinite(intensities), intensities, 0.0)
        if number is not None:
            self._sequence[self._scan_channel] = int(number) - 1
        self._add(
            self._scan_channel,
            time_ns,
            {
                "timestamp": _stamp(time_ns),
                "frame_id": SCAN_FRAME_ID,
                "pose": _IDENTITY_POSE,
                "start_angle": start,
                "end_angle": end,
                "ranges": ranges_out.tolist(),
                "intensities": intensities.tolist(),
            },
            publish_ns,
        )

    def add_odom(self, time_s: float, pose: Pose2) -> None:
        """Append an odometry pose (world frame) at ``time_s`` seconds; ``ValueError`` for a
        non-finite pose or a time that is not finite and >= 0."""
        if not all(math.isfinite(float(v)) for v in (pose.x, pose.y, pose.theta)):
            raise ValueError(f"odometry at t={time_s} s is not finite: {pose}")
        qx, qy, qz, qw = heading_to_quaternion(pose.theta).tolist()
        time_ns = _time_ns(float(time_s))
        self._add(
            self._odom_channel,
            time_ns,
            {
                "timestamp": _stamp(time_ns),
                "frame_id": WORLD_FRAME_ID,
                "pose": {
                    "position": {"x": float(pose.x), "y": float(pose.y), "z": 0.0},
                    "orientation": {"x": qx, "y": qy, "z": qz, "w": qw},
                },
            },
            time_ns,
        )

    def close(self) -> None:
        """Write the summary and footer and close the file (idempotent)."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.finish()
            self._file.close()
        except OSError as exc:
            with contextlib.suppress(OSError):
                self._file.close()
            raise writing_error(self.path, exc) from None


def write_log(
    path: str | Path,
    scans: Iterable[Scan],
    odom: Iterable[tuple[float, Pose2]] = (),
    sensor: dict[str, str] | None = None,
    original_times_s: Iterable[float] | None = None,
    progress: Progress = SILENT,
    numbers: Iterable[int] | None = None,
) -> None:
    """Write scans and ``(time_s, Pose2)`` odometry to a new log; each scan written is a
    step of ``progress``.

    Without ``range_max_m`` in ``sensor``, the first scan's ``range_max_m`` is used.
    ``original_times_s`` (one per scan, seconds) are the scans' times in their source
    when they differ from ``Scan.time_s``, and ``numbers`` (one per scan, distinct, from 1)
    their numbers there (``Log.numbers``; see ``LogWriter.add_scan``). Every argument
    is checked (``ValueError``) before the file is created.
    """
    scans = list(scans)
    odom = list(odom)
    originals = None if original_times_s is None else [float(t) for t in original_times_s]
    if originals is not None and len(originals) != len(scans):
        raise ValueError(f"{len(originals)} original times for {len(scans)} scans")
    given = None if numbers is None else [int(n) for n in numbers]
    if given is not None and not len(set(given)) == len(given) == len(scans):
        raise ValueError(f"{len(given)} scan numbers for {len(scans)} scans, or some alike")
    for k, scan in enumerate(scans):
        _check_scan(scan, None if originals is None else originals[k])
    for time_s, pose in odom:
        _time_ns(float(time_s))
        if not all(math.isfinite(float(v)) for v in (pose.x, pose.y, pose.theta)):
            raise ValueError(f"odometry at t={time_s} s is not finite: {pose}")
    settings = {str(k): str(v) for k, v in (sensor or {}).items()}
    if "range_max_m" not in settings:
        settings["range_max_m"] = str(scans[0].range_max_m if scans else math.inf)
    with LogWriter(path, settings) as writer:
        for k, scan in enumerate(scans):
            writer.add_scan(
                scan,
                None if originals is None else originals[k],
                None if given is None else given[k],
            )
            progress.advance()
        for time_s, pose in odom:
            writer.add_odom(time_s, pose)


# --- reading ---------------------------------------------------------------------


class _Skip(Exception):
    """A message that cannot be used: ``kind`` picks its warning, ``detail`` says why."""

    def __init__(self, kind: str, detail: str):
        super().__init__(detail)
        self.kind = kind
        self.detail = detail


class _CorruptChunk(Exception):
    """A chunk record that cannot be decompressed or split into records."""


_NOT_JSON = "not a JSON object: malformed, nested too deep or numbers too long to read"
_BAD_TIME = "no valid timestamp: whole sec and nsec, from 0 to 2^63 ns"
_SCAN_FAULTS = {
    "json": _NOT_JSON,
    "size": f"over {MAX_MESSAGE_BYTES} bytes or over {MAX_READINGS} readings",
    "time": _BAD_TIME,
    "angles": "start_angle or end_angle missing, not a number or not finite",
    "fan": (
        "not a fan: angles that decrease, all beams on one ray, over a full turn, or angles "
        "beyond ±4π"
    ),
    "ranges": "ranges missing or not a list of numbers",
}
_ODOM_FAULTS = {
    "json": _NOT_JSON,
    "size": f"over {MAX_MESSAGE_BYTES} bytes",
    "time": _BAD_TIME,
    "pose": "position or orientation missing, not numbers or not finite",
    "far": f"position beyond ±{MAX_COORDINATE_M:g} m",
    "quaternion": "orientation quaternion all zeros",
}
_LISTED_NUMBERS = 5


class _Faults:
    """Message numbers per kind of fault, and the first such message's detail."""

    def __init__(self) -> None:
        self.numbers: dict[str, list[int]] = {}
        self.first: dict[str, str] = {}
        self.first_of_all: str | None = None

    def add(self, kind: str, number: int, detail: str) -> None:
        if self.first_of_all is None:
            self.first_of_all = f"message {number}: {detail}"
        if kind not in self.numbers:
            self.numbers[kind] = []
            self.first[kind] = detail
        self.numbers[kind].append(number)

    def total(self) -> int:
        return sum(len(numbers) for numbers in self.numbers.values())

    def lines(self, name: str, verb: str, topic: str, texts: dict[str, str]) -> list[str]:
        """One warning per kind, e.g. ``log.mcap: skipped 2 /scan messages [what is wrong]:
        messages 3, 9 (first: why message 3 is)``."""
        lines = []
        for kind, text in texts.items():
            numbers = self.numbers.get(kind)
            if numbers:
                first = "first: " if len(numbers) > 1 else ""
                lines.append(
                    f"{name}: {verb} {counted(len(numbers), topic + ' message')} [{text}]: "
                    f"{_message_list(numbers)} ({first}{self.first[kind]})"
                )
        return lines


def _message_list(numbers: list[int]) -> str:
    shown = ", ".join(str(n) for n in numbers[:_LISTED_NUMBERS])
    more = len(numbers) - _LISTED_NUMBERS
    word = plural(len(numbers), "message")
    return f"{word} {shown}" + (f" and {more} more" if more > 0 else "")


def _show(value: object) -> str:
    """A short, one-line rendering of a JSON value for a message."""
    if isinstance(value, list):
        return f"an array of {len(value)}"
    if isinstance(value, dict):
        return "an object"
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**15:
        return f"an integer of {len(str(abs(value)))} digits"
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _clip(text: str, limit: int = 40) -> str:
    """``text`` with control characters escaped, cut to ``limit`` characters."""
    text = repr(text)[1:-1]
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _decode(data: bytes) -> dict:
    if len(data) > MAX_MESSAGE_BYTES:
        raise _Skip("size", f"{len(data)} bytes")
    try:
        message = json.loads(data)
    except (ValueError, RecursionError) as exc:
        # ValueError covers malformed JSON, bad UTF-8 and integers too long to convert.
        reason = "nested too deep" if isinstance(exc, RecursionError) else str(exc)
        raise _Skip("json", f"not valid JSON: {_clip(reason, 100)}") from None
    if not isinstance(message, dict):
        raise _Skip("json", f"{_show(message)}, not a JSON object")
    return message


def _get(message: dict, kind: str, *keys: str):
    value = message
    for depth, key in enumerate(keys):
        if not isinstance(value, dict) or key not in value:
            raise _Skip(kind, f"lacks field {'.'.join(keys[: depth + 1])!r}")
        value = value[key]
    return value


_NUMBER_TYPES = {float, int}
"""What JSON numbers decode to (``bool``, a subclass of ``int``, is not one)."""


def _is_number(value: object) -> bool:
    return type(value) in _NUMBER_TYPES


def _to_float(value: int | float) -> float:
    try:
        return float(value)
    except OverflowError:  # an integer beyond the float range
        return math.inf if value > 0 else -math.inf


def _number(message: dict, kind: str, *keys: str) -> float:
    """The finite number at ``keys``, else ``_Skip(kind)``."""
    value = _get(message, kind, *keys)
    name = ".".join(keys)
    if not _is_number(value):
        raise _Skip(kind, f"field {name!r} is {_show(value)}, expected a number")
    number = _to_float(value)
    if not math.isfinite(number):
        raise _Skip(kind, f"field {name!r} is {_show(value)}, expected a finite number")
    return number


def _stamp_ns(message: dict) -> int:
    """The message's timestamp in whole nanoseconds, else ``_Skip("time")``."""
    pieces = []
    for key in ("sec", "nsec"):
        value = _get(message, "time", "timestamp", key)
        if type(value) is float and math.isfinite(value) and value.is_integer():
            value = int(value)
        if type(value) is not int:
            raise _Skip("time", f"timestamp.{key} is {_show(value)}, expected an integer")
        pieces.append(value)
    time_ns = pieces[0] * 1_000_000_000 + pieces[1]
    if not 0 <= time_ns <= MAX_TIME_NS:
        raise _Skip("time", f"timestamp {_show(pieces[0])} s {_show(pieces[1])} ns out of range")
    return time_ns


def _number_list(value: object) -> np.ndarray | None:
    """A JSON array of numbers as floats (beyond the float range → ±inf), else None."""
    # The types, not ``_is_number`` value by value: a scan's readings number thousands.
    if not isinstance(value, list) or not set(map(type, value)) <= _NUMBER_TYPES:
        return None
    try:
        return np.array(value, dtype=float)
    except OverflowError:
        return np.array([_to_float(v) for v in value], dtype=float)


def _first_non_number(value: object) -> str:
    if not isinstance(value, list):
        return _show(value)
    bad = next(v for v in value if not _is_number(v))
    return f"an array holding {_show(bad)}"


@dataclass(frozen=True)
class _ScanRecord:
    """A usable ``/scan`` message: its place among the file's ``/scan`` messages (from 1) and
    the record's sequence number, times in ns, fan in rad, readings as in the file."""

    number: int
    sequence: int
    time_ns: int
    original_ns: int
    start_rad: float
    end_rad: float
    ranges: np.ndarray
    intensities: np.ndarray


def _parse_scan(number: int, record: Message, dropped: _Faults) -> _ScanRecord:
    """A ``/scan`` message, else ``_Skip``; intensities that do not fit are dropped (and
    noted in ``dropped``)."""
    message = _decode(record.data)
    time_ns = _stamp_ns(message)
    start = _number(message, "angles", "start_angle")
    end = _number(message, "angles", "end_angle")
    raw_ranges = _get(message, "ranges", "ranges")
    if isinstance(raw_ranges, list) and len(raw_ranges) > MAX_READINGS:
        raise _Skip("size", f"{len(raw_ranges)} readings")
    ranges = _number_list(raw_ranges)
    if ranges is None:
        raise _Skip("ranges", f"field 'ranges' is {_first_non_number(raw_ranges)}")
    defect = fan_defect(len(ranges), start, end)
    if defect is not None:
        raise _Skip("fan", defect)
    raw_intensities = message.get("intensities")
    intensities = np.zeros(0) if raw_intensities is None else _number_list(raw_intensities)
    if intensities is None or len(intensities) not in (0, len(ranges)):
        shown = "not numbers" if intensities is None else f"{len(intensities)} values"
        dropped.add("intensities", number, f"{shown} for {len(ranges)} readings")
        intensities = np.zeros(0)
    intensities = np.where(np.isfinite(intensities), intensities, 0.0)
    # The publish time holds the original time only in files that follow segloc's own
    # layout, where the log time is the scan's timestamp.
    original_ns = record.publish_time if record.log_time == time_ns else time_ns
    return _ScanRecord(
        number, record.sequence, time_ns, original_ns, start, end, ranges, intensities
    )


def _parse_odom(data: bytes) -> tuple[int, list[float]]:
    """A ``/odom`` message as ``time_ns, [x_m, y_m, theta_rad]``, else ``_Skip``."""
    message = _decode(data)
    time_ns = _stamp_ns(message)
    x = _number(message, "pose", "pose", "position", "x")
    y = _number(message, "pose", "pose", "position", "y")
    q = [_number(message, "pose", "pose", "orientation", k) for k in "xyzw"]
    if max(abs(x), abs(y)) > MAX_COORDINATE_M:
        raise _Skip("far", f"position ({x:.6g}, {y:.6g}) m")
    largest = max(abs(c) for c in q)
    if largest == 0.0:
        raise _Skip("quaternion", "orientation is (0, 0, 0, 0)")
    # Scale by a power of two (exact) so that the products in the heading formula neither
    # overflow nor underflow for quaternions far from unit length.
    exponent = math.frexp(largest)[1]
    q = [math.ldexp(c, -exponent) for c in q]
    theta = float(wrap_angle(quaternion_to_heading(*q)))
    return time_ns, [x, y, theta]


def _sensor_range_max(path: Path, sensor: dict[str, str]) -> float:
    text = sensor.get("range_max_m")
    if text is None:
        return math.inf
    value = _range_max(text)
    if value is None:
        raise InputError(
            f"metadata {SENSOR_METADATA_NAME}: range_max_m is {_show(text)}, expected a "
            "positive finite number in metres or 'inf'",
            path=path,
        )
    return value


class _Bounded:
    """A binary file whose reads never ask for more than what is left of it, so that a
    corrupt length field inside a record gives a short read, not a huge allocation."""

    def __init__(self, stream, size: int):
        self._stream = stream
        self._size = size
        self.position = stream.tell()

    def read(self, n: int = -1) -> bytes:
        left = max(self._size - self.position, 0)
        data = self._stream.read(left if n < 0 else min(n, left))
        self.position += len(data)
        return data


def _decompressed(chunk: Chunk) -> bytes:
    if chunk.uncompressed_size > MAX_CHUNK_BYTES:
        raise _CorruptChunk(f"chunk of {chunk.uncompressed_size} bytes")
    if chunk.compression == "":
        return chunk.data
    if chunk.compression == "zstd":
        import zstandard

        if zstandard.frame_content_size(chunk.data) > MAX_CHUNK_BYTES:
            raise _CorruptChunk("zstd frame too large")
        decompressor = zstandard.ZstdDecompressor()
        return decompressor.decompress(chunk.data, max_output_size=chunk.uncompressed_size)
    if chunk.compression == "lz4":
        import lz4.frame

        lz4_decompressor = lz4.frame.LZ4FrameDecompressor()
        return lz4_decompressor.decompress(chunk.data, max_length=chunk.uncompressed_size)
    raise _CorruptChunk(f"unknown compression {chunk.compression!r}")


def _records(reader: StreamReader):
    """The file's records in order, chunks opened; a chunk that cannot be opened raises
    ``_CorruptChunk``."""
    for record in reader.records:
        if not isinstance(record, Chunk):
            yield record
            continue
        try:
            inner = breakup_chunk(replace(record, compression="", data=_decompressed(record)))
        except Exception as exc:  # any failure of the decompressors or parsers
            raise _CorruptChunk(str(exc)) from None
        yield from inner


@dataclass
class _Found:
    """What reading a log's records has found so far.

    ``scan_records`` and ``odom`` (``time_ns, [x_m, y_m, theta_rad]`` in the world
    frame) the usable messages in file order; the faults those skipped and the
    intensities dropped; ``n_messages`` every message record read and ``counts``
    the messages per topic; ``finished`` whether the footer was read; ``broken``
    how the file is damaged where reading stopped (None when it read to the end).
    """

    channels: dict[int, Channel] = field(default_factory=dict)
    sensor: dict[str, str] = field(default_factory=dict)
    scan_records: list[_ScanRecord] = field(default_factory=list)
    odom: list[tuple[int, list[float]]] = field(default_factory=list)
    scan_faults: _Faults = field(default_factory=_Faults)
    odom_faults: _Faults = field(default_factory=_Faults)
    dropped: _Faults = field(default_factory=_Faults)
    n_messages: int = 0
    counts: dict[str, int] = field(default_factory=dict)
    finished: bool = False
    broken: str | None = None
    run_view: bool = False


def read_log(path: str | Path) -> Log:
    """Read a segloc MCAP log, including one that was cut short or that another tool wrote.

    Records are read in file order (chunked and compressed files too); at the
    first incomplete or corrupt record reading stops with a warning and every
    complete message before it is kept. Messages that cannot be used are
    skipped and counted in warnings (see the module docstring for the kinds).
    Raises ``InputError`` naming the file when it is missing, not MCAP (naming the
    ``segloc import`` that converts another tool's log: a ROS 1 bag, a ROS 2 bag folder or
    a file inside one, a CARMEN log; ``other_logs``), has no
    ``/scan`` channel or a non-JSON one, has an unusable ``range_max_m`` or laser offset
    (naming the setting), or none of its ``/scan`` messages can be used.
    """
    path = Path(path)
    if path.is_dir() and (path / ROS2_METADATA).is_file():
        raise InputError(
            f"a ROS 2 bag folder, not a segloc log; {conversion('rosbag', path)}",
            path=path,
        )
    bag = inside_ros2_bag(path)
    if bag is not None:
        raise InputError(
            f"a file inside a ROS 2 bag, not a segloc log; "
            f"{conversion('rosbag', bag, 'the bag folder')}",
            path=path,
        )
    with reading(path, "an MCAP log file"):
        stream = open(path, "rb")
        size = os.fstat(stream.fileno()).st_size
    with stream:
        _check_magic(path, stream)
        found = _read_records(stream, size)
    _check_channels(path, found)
    range_max_m = _sensor_range_max(path, found.sensor)
    mount = laser_offset_of(found.sensor, path)
    scans = [_scan(record, range_max_m, mount) for record in found.scan_records]
    return Log(
        scans=scans,
        original_times_s=np.array(
            [r.original_ns / 1_000_000_000 for r in found.scan_records], dtype=float
        ),
        odom_times_s=np.array([t / 1_000_000_000 for t, _ in found.odom], dtype=float),
        odom_poses=np.array([p for _, p in found.odom], dtype=float).reshape(-1, 3),
        sensor=found.sensor,
        finished=found.finished,
        message_counts={c.topic: found.counts.get(c.topic, 0) for c in found.channels.values()},
        warnings=_read_warnings(path.name, found, len(scans)),
        numbers=_scan_numbers(found.scan_records),
    )


def _scan_numbers(records: list[_ScanRecord]) -> np.ndarray:
    """Each scan's number from 1: its record's sequence number + 1 where no two scans share
    one (segloc writes a scan's number − 1 there, MCAP counting from 0), else its place
    among the file's ``/scan`` messages, unreadable ones included."""
    sequences = np.array([r.sequence for r in records], dtype=np.int64)
    if np.unique(sequences).size == sequences.size:
        return sequences + 1
    return np.array([r.number for r in records], dtype=np.int64)


def _check_magic(path: Path, stream) -> None:
    """Refuse a file that does not start as MCAP, naming the import for another tool's log
    (a ROS 1 bag, a CARMEN log: ``other_logs``); leaves ``stream`` at its start."""
    start = stream.read(len(MCAP_MAGIC))
    if not start.startswith(MCAP_MAGIC):
        other = other_log(path, start + stream.read(HEAD_BYTES - len(start)))
        raise InputError(
            other
            or "not an MCAP file (it does not start with the MCAP magic bytes); expected a "
            "segloc log such as `segloc simulate` writes",
            path=path,
        )
    stream.seek(0)


def _read_records(stream, size: int) -> _Found:
    """Every record of the MCAP file ``stream`` of ``size`` bytes up to its end or to the
    first record that is incomplete or corrupt (``_Found.broken`` then says which, and the
    file does not count as finished)."""
    found = _Found()
    bounded = _Bounded(stream, size)
    # A record longer than the file can only be a corrupt length field.
    # StreamReader only ever calls ``read`` on a stream that is not a path or a RawIOBase.
    reader = StreamReader(
        cast("IO[bytes]", bounded), emit_chunks=True, record_size_limit=max(size, 1)
    )
    records = _records(reader)
    end_of_last_record = len(MCAP_MAGIC)
    while True:
        try:
            record = next(records)
        except StopIteration:
            break
        except _CorruptChunk:
            found.broken = "has a corrupt chunk"
            break
        except (EndOfFile, struct.error):
            # Ending exactly after a whole record is a recording stopped between messages.
            if bounded.position != end_of_last_record:
                found.broken = "ends mid-record"
            break
        except Exception:  # the mcap parser's many ways to fail on corrupt bytes
            found.broken = "has a corrupt record"
            break
        end_of_last_record = bounded.position
        _take_record(found, record)
    if found.broken is not None:
        found.finished = False  # a footer before the damage does not make the file whole
    return found


def _take_record(found: _Found, record: object) -> None:
    """Note one record of the file in ``found``."""
    if isinstance(record, Message):
        found.n_messages += 1
        _take_message(found, record)
    elif isinstance(record, Channel):
        found.channels[record.id] = record
    elif isinstance(record, Metadata) and record.name == SENSOR_METADATA_NAME:
        found.sensor = dict(record.metadata)
    elif isinstance(record, Metadata) and record.name == RUN_METADATA_NAME:
        found.run_view = True
    elif isinstance(record, Footer):
        found.finished = True


def _take_message(found: _Found, record: Message) -> None:
    """Count a message on its topic and keep it if it is a usable ``/scan`` or ``/odom``
    one; an unusable one is counted as a fault."""
    channel = found.channels.get(record.channel_id)
    if channel is None:
        return
    number = found.counts[channel.topic] = found.counts.get(channel.topic, 0) + 1
    if channel.message_encoding != "json":
        return  # refused by _check_channels, once the whole file is read
    try:
        if channel.topic == SCAN_TOPIC:
            found.scan_records.append(_parse_scan(number, record, found.dropped))
        elif channel.topic == ODOM_TOPIC:
            found.odom.append(_parse_odom(record.data))
    except _Skip as skip:
        faults = found.scan_faults if channel.topic == SCAN_TOPIC else found.odom_faults
        faults.add(skip.kind, number, skip.detail)


def _check_channels(path: Path, found: _Found) -> None:
    """Refuse a run view, a log without a ``/scan`` channel, with a ``/scan`` or ``/odom``
    channel that is not JSON, or whose ``/scan`` messages are all unusable."""
    if found.run_view:
        raise InputError(
            "a run view (written by --mcap), not a log: it shows a run's answers; "
            f"`segloc info {path}` names the log it shows",
            path=path,
        )
    channels = found.channels.values()
    # A ROS 2 bag stored as MCAP is an MCAP file too, but of ROS messages.
    ros = any(c.message_encoding in ROS_ENCODINGS for c in channels)
    to_import = f"; it is a ROS bag: {conversion('rosbag', path)}" if ros else ""
    scan_channels = [c for c in channels if c.topic == SCAN_TOPIC]
    if not scan_channels:
        found_topics = ", ".join(sorted({_clip(c.topic) for c in channels})) or "none"
        cut = (
            ""
            if found.broken is None
            else f"; the file {found.broken} after {counted(found.n_messages, 'message')}"
        )
        raise InputError(
            f"no {SCAN_TOPIC} channel; record or import a log with laser scans on "
            f"{SCAN_TOPIC} (channels found: {found_topics}){cut}{to_import}",
            path=path,
        )
    for channel in [*scan_channels, *(c for c in channels if c.topic == ODOM_TOPIC)]:
        if channel.message_encoding != "json":
            raise InputError(
                f"channel {channel.topic} uses message encoding "
                f"{_show(channel.message_encoding)}; segloc reads JSON-encoded foxglove messages"
                f"{to_import}",
                path=path,
            )
    faults = found.scan_faults
    if not found.scan_records and faults.total():
        raise InputError(
            f"every {SCAN_TOPIC} message is unusable ({faults.total()} skipped; first, "
            f"{faults.first_of_all})",
            path=path,
        )


def _read_warnings(name: str, found: _Found, n_scans: int) -> list[str]:
    """The warnings on the log file ``name``: damage, skipped messages, dropped intensities
    and scan times out of order, one line each."""
    warnings = []
    if found.broken is not None:
        warnings.append(
            f"{name}: file {found.broken} after {counted(found.n_messages, 'message')}; kept "
            f"{counted(n_scans, 'scan')}"
        )
    elif not found.finished:
        warnings.append(
            f"{name}: file has no footer (recording was not finished); kept "
            f"{counted(n_scans, 'scan')}"
        )
    warnings += found.scan_faults.lines(name, "skipped", SCAN_TOPIC, _SCAN_FAULTS)
    warnings += found.odom_faults.lines(name, "skipped", ODOM_TOPIC, _ODOM_FAULTS)
    warnings += found.dropped.lines(
        name,
        "dropped the intensities of",
        SCAN_TOPIC,
        {"intensities": "not one number per reading; the scans are kept"},
    )
    warnings += _time_order_warnings(name, found.scan_records)
    return warnings


def _scan(record: _ScanRecord, range_max_m: float, mount: Pose2) -> Scan:
    """The scan of a usable message, mounted at ``mount`` (the scanner's pose in the robot
    frame), invalid readings as 0."""
    scan = Scan(
        # Integer true division rounds once, so times written from float seconds read back
        # as the same float whenever they were whole nanoseconds.
        time_s=record.time_ns / 1_000_000_000,
        angles_rad=evenly_spaced_angles(len(record.ranges), record.start_rad, record.end_rad),
        ranges_m=record.ranges,
        range_max_m=range_max_m,
        intensities=record.intensities,
        mount=mount,
    )
    return replace(scan, ranges_m=np.where(scan.valid, scan.ranges_m, 0.0))


def _time_order_warnings(name: str, records: list[_ScanRecord]) -> list[str]:
    """A warning when scans repeat an earlier scan's time or go back in time."""
    if len(records) < 2:
        return []
    times = np.array([r.time_ns for r in records], dtype=np.int64)
    behind = np.flatnonzero(times[1:] <= np.maximum.accumulate(times)[:-1]) + 1
    if behind.size == 0:
        return []
    first = records[int(behind[0])]
    return [
        f"{name}: {counted(int(behind.size), 'scan')} repeat an earlier scan's time or go back "
        f"in time (first: {SCAN_TOPIC} message {first.number} at "
        f"{first.time_ns / 1_000_000_000:.9f} s); pairing scans by time may refuse them"
    ]
