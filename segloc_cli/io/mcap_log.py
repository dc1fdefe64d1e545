"""The MCAP log: laser scans, odometry and the sensor settings of a recording.

Layout (JSON message encoding, opens in Foxglove as is):

- ``/scan``: ``foxglove.LaserScan`` in frame ``laser`` with an identity pose.
  Beam angles are evenly spaced from ``start_angle`` to ``end_angle`` inclusive;
  invalid readings (<= 0, non-finite, >= the maximum range) are written as 0.
- ``/odom``: ``foxglove.PoseInFrame``, the robot's pose in frame ``world``
  (x, y in metres, heading as a rotation about +z).
- Metadata record ``segloc.sensor``: the sensor settings as str → str,
  including ``range_max_m``. It is written first so that a log cut short keeps it.

Messages are written unchunked and the file is flushed after each one, so a
recorder killed mid-run loses at most the message being written; ``read_log``
reads such unfinished files record by record and keeps every complete message.
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType

import numpy as np
from mcap.exceptions import EndOfFile, McapError
from mcap.records import Channel, Footer, Message, Metadata
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from segloc_cli.errors import InputError
from segloc_cli.geometry import Pose2, heading_to_quaternion, quaternion_to_heading, wrap_angle
from segloc_cli.io.files import reading
from segloc_cli.scan import Scan, evenly_spaced_angles

SCAN_TOPIC = "/scan"
ODOM_TOPIC = "/odom"
SCAN_SCHEMA_NAME = "foxglove.LaserScan"
ODOM_SCHEMA_NAME = "foxglove.PoseInFrame"
SENSOR_METADATA_NAME = "segloc.sensor"
SCAN_FRAME_ID = "laser"
WORLD_FRAME_ID = "world"
ANGLE_SPACING_TOLERANCE_RAD = 1e-9
MCAP_MAGIC = b"\x89MCAP0\r\n"

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
    if not math.isfinite(time_s) or time_s < 0:
        raise ValueError(f"log times must be finite and >= 0 s, got {time_s}")
    return round(time_s * 1e9)


def _stamp(time_ns: int) -> dict:
    sec, nsec = divmod(time_ns, 1_000_000_000)
    return {"sec": sec, "nsec": nsec}


# --- writing -------------------------------------------------------------------


class LogWriter:
    """Writes a segloc MCAP log; use as a context manager.

    ``sensor`` holds the recording's settings as str → str and must include
    ``range_max_m`` (``"inf"`` when the sensor has none). The file is flushed
    after every message.
    """

    def __init__(self, path: str | Path, sensor: dict[str, str]):
        sensor = {str(k): str(v) for k, v in sensor.items()}
        if "range_max_m" not in sensor:
            raise ValueError("sensor settings must include 'range_max_m' (use 'inf' if none)")
        self.range_max_m = float(sensor["range_max_m"])
        self.path = Path(path)
        self._file = open(self.path, "wb")
        # Unchunked: each message goes to the file as its own record, so flushing
        # after it makes it durable without one compressed chunk per message.
        self._writer = Writer(self._file, use_chunking=False, compression=CompressionType.NONE)
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
        self._closed = False

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()

    def _add(self, channel_id: int, time_ns: int, message: dict) -> None:
        data = json.dumps(message, allow_nan=False, separators=(",", ":")).encode()
        self._writer.add_message(
            channel_id,
            log_time=time_ns,
            data=data,
            publish_time=time_ns,
            sequence=self._sequence[channel_id],
        )
        self._sequence[channel_id] += 1
        self._file.flush()

    def add_scan(self, scan: Scan) -> None:
        """Append a scan. Its angles must be evenly spaced (``ValueError`` otherwise)."""
        angles = np.asarray(scan.angles_rad, dtype=float).reshape(-1)
        ranges = np.asarray(scan.ranges_m, dtype=float).reshape(-1)
        n = len(angles)
        start, end = (float(angles[0]), float(angles[-1])) if n else (0.0, 0.0)
        if n and not np.all(np.isfinite(angles)):
            raise ValueError(f"scan at t={scan.time_s} s has non-finite beam angles")
        spacing_error = np.max(np.abs(angles - evenly_spaced_angles(n, start, end)), initial=0.0)
        if spacing_error > ANGLE_SPACING_TOLERANCE_RAD:
            raise ValueError(
                f"scan at t={scan.time_s} s: beam angles are not evenly spaced "
                f"(off by up to {spacing_error:.3g} rad); foxglove.LaserScan cannot store them"
            )
        # A reading is kept only if it is valid for the scan and for the log's sensor,
        # so that what is read back is valid exactly when it was written valid.
        with np.errstate(invalid="ignore"):
            keep = scan.valid.reshape(-1) & (ranges < self.range_max_m)
        ranges_out = np.where(keep, ranges, 0.0)
        intensities = np.asarray(scan.intensities, dtype=float).reshape(-1)
        intensities = np.where(np.isfinite(intensities), intensities, 0.0)
        time_ns = _time_ns(float(scan.time_s))
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
        )

    def add_odom(self, time_s: float, pose: Pose2) -> None:
        """Append an odometry pose (world frame) at ``time_s`` seconds."""
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
        )

    def close(self) -> None:
        """Write the summary and footer and close the file (idempotent)."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.finish()
        finally:
            self._file.close()


def write_log(
    path: str | Path,
    scans: Iterable[Scan],
    odom: Iterable[tuple[float, Pose2]] = (),
    sensor: dict[str, str] | None = None,
) -> None:
    """Write scans and ``(time_s, Pose2)`` odometry to a new log.

    Without ``range_max_m`` in ``sensor``, the first scan's ``range_max_m`` is used.
    """
    scans = list(scans)
    settings = {str(k): str(v) for k, v in (sensor or {}).items()}
    if "range_max_m" not in settings:
        settings["range_max_m"] = str(scans[0].range_max_m if scans else math.inf)
    with LogWriter(path, settings) as writer:
        for scan in scans:
            writer.add_scan(scan)
        for time_s, pose in odom:
            writer.add_odom(time_s, pose)


# --- reading ---------------------------------------------------------------------


@dataclass(frozen=True)
class LogContents:
    """Everything ``read_log`` found in a log.

    ``scans`` in log order (each with the log's ``range_max_m``);
    ``odom_times_s`` (K,) seconds; ``odom_poses`` (K, 3) ``x_m, y_m, theta_rad``
    in the world frame; ``sensor`` the settings record (empty if absent);
    ``finished`` whether the file ends with its summary and footer;
    ``message_counts`` messages read per channel topic, including topics
    segloc does not use; ``warnings`` human-readable notes (e.g. a truncated file).
    """

    scans: list[Scan]
    odom_times_s: np.ndarray
    odom_poses: np.ndarray
    sensor: dict[str, str] = field(default_factory=dict)
    finished: bool = False
    warnings: list[str] = field(default_factory=list)
    message_counts: dict[str, int] = field(default_factory=dict)

    @property
    def scan_times_s(self) -> np.ndarray:
        """Acquisition times (S,) of the scans, seconds."""
        return np.array([scan.time_s for scan in self.scans], dtype=float)


def _decode(path: Path, topic: str, index: int, data: bytes) -> dict:
    try:
        message = json.loads(data)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{topic} message {index} is not valid JSON ({exc})", path=path) from None
    if not isinstance(message, dict):
        raise InputError(f"{topic} message {index} is not a JSON object", path=path)
    return message


def _get(path: Path, topic: str, index: int, message: dict, *keys: str):
    value = message
    for depth, key in enumerate(keys):
        if not isinstance(value, dict) or key not in value:
            name = ".".join(keys[: depth + 1])
            raise InputError(f"{topic} message {index} lacks field {name!r}", path=path)
        value = value[key]
    return value


def _number(path: Path, topic: str, index: int, message: dict, *keys: str) -> float:
    value = _get(path, topic, index, message, *keys)
    if isinstance(value, bool) or not isinstance(value, int | float):
        name = ".".join(keys)
        raise InputError(
            f"{topic} message {index}: field {name!r} is {value!r}, expected a number", path=path
        )
    return float(value)


def _stamp_s(path: Path, topic: str, index: int, message: dict) -> float:
    sec = _get(path, topic, index, message, "timestamp", "sec")
    nsec = _get(path, topic, index, message, "timestamp", "nsec")
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in (sec, nsec)):
        raise InputError(f"{topic} message {index}: timestamp sec/nsec must be integers", path=path)
    # Integer true division rounds once, so times written from float seconds read back
    # as the same float whenever they were whole nanoseconds.
    return (sec * 1_000_000_000 + nsec) / 1_000_000_000


def _number_array(path: Path, index: int, message: dict, key: str) -> np.ndarray:
    value = _get(path, SCAN_TOPIC, index, message, key)
    if not isinstance(value, list) or not all(
        isinstance(v, int | float) and not isinstance(v, bool) for v in value
    ):
        raise InputError(
            f"{SCAN_TOPIC} message {index}: field {key!r} must be a list of numbers", path=path
        )
    return np.array(value, dtype=float)


def _parse_scan(path: Path, index: int, data: bytes, range_max_m: float) -> Scan:
    message = _decode(path, SCAN_TOPIC, index, data)
    time_s = _stamp_s(path, SCAN_TOPIC, index, message)
    start = _number(path, SCAN_TOPIC, index, message, "start_angle")
    end = _number(path, SCAN_TOPIC, index, message, "end_angle")
    ranges = _number_array(path, index, message, "ranges")
    intensities = (
        _number_array(path, index, message, "intensities")
        if "intensities" in message
        else np.zeros(0)
    )
    return Scan(
        time_s=time_s,
        angles_rad=evenly_spaced_angles(len(ranges), start, end),
        ranges_m=ranges,
        range_max_m=range_max_m,
        intensities=intensities,
    )


def _parse_odom(path: Path, index: int, data: bytes) -> tuple[float, list[float]]:
    message = _decode(path, ODOM_TOPIC, index, data)
    time_s = _stamp_s(path, ODOM_TOPIC, index, message)
    x = _number(path, ODOM_TOPIC, index, message, "pose", "position", "x")
    y = _number(path, ODOM_TOPIC, index, message, "pose", "position", "y")
    q = [_number(path, ODOM_TOPIC, index, message, "pose", "orientation", k) for k in "xyzw"]
    theta = float(wrap_angle(quaternion_to_heading(*q)))
    return time_s, [x, y, theta]


def _sensor_range_max(path: Path, sensor: dict[str, str]) -> float:
    text = sensor.get("range_max_m")
    if text is None:
        return math.inf
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not value > 0:
        raise InputError(
            f"metadata {SENSOR_METADATA_NAME}: range_max_m is {text!r}, expected a positive "
            "number or 'inf'",
            path=path,
        )
    return value


def read_log(path: str | Path) -> LogContents:
    """Read a segloc MCAP log, including one that was cut short.

    Records are read in file order; at the first incomplete or corrupt record
    reading stops with a warning and every complete message before it is kept.
    Raises ``InputError`` naming the file when it is missing, not MCAP, has no
    ``/scan`` channel, or holds a ``/scan`` or ``/odom`` message that is not
    valid JSON or lacks fields (messages counted from 1 per topic).
    """
    path = Path(path)
    with reading(path, "an MCAP log file"):
        stream = open(path, "rb")

    channels: dict[int, Channel] = {}
    sensor: dict[str, str] = {}
    raw_scans: list[bytes] = []
    raw_odom: list[bytes] = []
    n_messages = 0
    counts: dict[str, int] = {}
    finished = False
    broken: str | None = None
    with stream:
        if stream.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise InputError(
                "not an MCAP file (it does not start with the MCAP magic bytes); expected a "
                "segloc log such as `segloc simulate` writes",
                path=path,
            )
        stream.seek(0)
        # A record longer than the file can only be a corrupt length field.
        reader = StreamReader(stream, record_size_limit=max(path.stat().st_size, 1))
        end_of_last_record = len(MCAP_MAGIC)
        try:
            for record in reader.records:
                end_of_last_record = stream.tell()
                if isinstance(record, Message):
                    n_messages += 1
                    channel = channels.get(record.channel_id)
                    if channel is not None:
                        counts[channel.topic] = counts.get(channel.topic, 0) + 1
                    if channel is not None and channel.topic == SCAN_TOPIC:
                        raw_scans.append(record.data)
                    elif channel is not None and channel.topic == ODOM_TOPIC:
                        raw_odom.append(record.data)
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Metadata) and record.name == SENSOR_METADATA_NAME:
                    sensor = dict(record.metadata)
                elif isinstance(record, Footer):
                    finished = True
        except (EndOfFile, struct.error):
            finished = False
            # Ending exactly after a whole record is a recording stopped between messages.
            if stream.tell() != end_of_last_record:
                broken = "ends mid-record"
        except (McapError, ValueError, UnicodeDecodeError, MemoryError):
            finished = False
            broken = "has a corrupt record"

    scan_channels = [c for c in channels.values() if c.topic == SCAN_TOPIC]
    if not scan_channels:
        found = ", ".join(sorted({c.topic for c in channels.values()})) or "none"
        cut = "" if broken is None else f"; the file {broken} after {n_messages} messages"
        raise InputError(
            f"no {SCAN_TOPIC} channel; record or import a log with laser scans on "
            f"{SCAN_TOPIC} (channels found: {found}){cut}",
            path=path,
        )
    for channel in [*scan_channels, *(c for c in channels.values() if c.topic == ODOM_TOPIC)]:
        if channel.message_encoding != "json":
            raise InputError(
                f"channel {channel.topic} uses message encoding {channel.message_encoding!r}; "
                "segloc reads JSON-encoded foxglove messages",
                path=path,
            )

    range_max_m = _sensor_range_max(path, sensor)
    scans = [_parse_scan(path, i, data, range_max_m) for i, data in enumerate(raw_scans, 1)]
    odom = [_parse_odom(path, i, data) for i, data in enumerate(raw_odom, 1)]
    odom_times_s = np.array([t for t, _ in odom], dtype=float)
    odom_poses = np.array([p for _, p in odom], dtype=float).reshape(-1, 3)

    warnings = []
    if broken is not None:
        warnings.append(
            f"{path.name}: file {broken} after {n_messages} messages; kept {len(scans)} scans"
        )
    elif not finished:
        warnings.append(
            f"{path.name}: file has no footer (recording was not finished); kept {len(scans)} scans"
        )
    return LogContents(
        scans=scans,
        odom_times_s=odom_times_s,
        odom_poses=odom_poses,
        sensor=sensor,
        finished=finished,
        warnings=warnings,
        message_counts={c.topic: counts.get(c.topic, 0) for c in channels.values()},
    )
