"""ROS bags: laser scans and odometry from a ROS 1 ``.bag`` file, a ROS 2 bag
folder (sqlite3 or MCAP storage, with ``metadata.yaml``) or a single ROS 2
``.mcap`` file, read with the ``rosbags`` package.

What comes out, in segloc's units and frames:

- Scans: the ``sensor_msgs/LaserScan`` messages on the scan topic, sorted by
  ``header.stamp``, in the scanner's own frame (``header.frame_id``; x forward,
  angles counter-clockwise), mounted on the robot as below. Beam ``i`` lies at
  ``angle_min + i·angle_increment`` radians; ranges and range limits are metres, each
  the shortest decimal that reads back as the message's float32 (1.07, not
  1.0700000524520874: the same reading, written in a log as briefly as the scanner
  gave it; a comparison of two gives what it gave).
  A reading is invalid when it is non-finite, below ``range_min`` or at/above the scan's
  range limit, and is returned as 0.0. The limit (``Scan.range_max_m``) is the
  ``range_max_m`` given, else the message's ``range_max`` (the bags write it, or a value
  above it, for "no return"), unless the scanner's returns lie beyond it: then, as
  ``segloc_cli.io.range_limits`` says, it is the no-return value the readings from
  ``range_max`` on repeat (none: inf), and a warning says how many readings ``range_max``
  would have dropped. The sensor setting ``range_max_from`` says which.
- Odometry: ``nav_msgs/Odometry`` ``pose.pose`` as (x m, y m, yaw rad): the robot's
  pose (its ``child_frame_id``, e.g. ``base_link``) in the odometry frame (the
  messages' ``header.frame_id``), interpolated to each scan time that lies within
  the odometry's time span: linearly in x and y, along the shorter arc in heading.
  Scans outside that span get no odometry.
- The scanner's mounting, its pose in the robot frame: the chain of ``/tf_static``
  transforms (and ``/tf`` ones that never change) from the odometry's child frame
  (without odometry, the top of the scanner's tree) to the scans' ``header.frame_id``,
  composed and projected onto the floor plane (``segloc_cli.io.tf``), or the
  ``laser_offset`` given instead, which wins (a warning says so when the bag's chain
  places the scanner elsewhere). A frame of the chain given two different poses takes
  tf2's choice (the latest ``/tf_static`` one, ``/tf_static`` over ``/tf``) with a
  warning; transforms that form a loop on the way up from the robot or the scanner are
  refused, unless ``laser_offset`` is given. The mounting becomes the sensor settings
  ``laser_x_m``, ``laser_y_m``, ``laser_theta_deg`` and ``laser_offset_source`` and every scan's
  ``Scan.mount``, so that the scans' points, local maps and every pose are the
  robot's. With no chain the scanner is at the robot's origin (source ``none``, a
  warning). A scan plane tilted more than ``MAX_TILT_DEG`` is read as level with a
  warning, one tilted more than ``MAX_PLANAR_TILT_DEG`` is refused; an upside-down
  scanner's scans are mirrored (beam order reversed, angles negated) into those of
  an upright one, with a warning and ``laser_upside_down`` set.
- Times are ``header.stamp`` in seconds (not the times the bag recorded them);
  scans stamped before 0 (possible in ROS 2), with more than
  ``segloc_cli.scan.MAX_READINGS`` readings or with a beam fan that
  ``segloc_cli.scan.fan_defect`` refuses are skipped and counted in a warning.
  Scans whose stamps collide (a driver that stamps every scan 0, or stamps
  coarser than the scan rate) are given distinct times by the rule of
  ``segloc_cli.io.times``, in stamp order and among equal stamps in bag order;
  one warning says how many. ``Log.original_times_s`` keeps the stamps. The
  odometry is looked up at the stamps, the real times of the scans, and filed
  under the scans' distinct times, so that each scan and its odometry share
  one time in the log.
"""

from __future__ import annotations

import contextlib
import math
import struct
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import Connection
from rosbags.rosbag1 import ReaderError as Ros1ReaderError
from rosbags.rosbag2 import ReaderError as Ros2ReaderError
from rosbags.typesys import Stores, get_typestore

from segloc_cli.errors import InputError
from segloc_cli.geometry import Pose2, quaternion_to_heading, wrap_angle
from segloc_cli.io.log import (
    MAX_LASER_OFFSET_M,
    Log,
    laser_offset_of,
    laser_offset_settings,
)
from segloc_cli.io.other_logs import refuse_inside_ros2_bag
from segloc_cli.io.range_limits import stated_limit
from segloc_cli.io.ros1_salvage import salvage_ros1
from segloc_cli.io.tf import (
    TF_STATIC_TOPIC,
    TF_TOPIC,
    TF_TYPES,
    Mounting,
    Transform,
    ancestors,
    bare,
    disagreements,
    find_mounting,
    fixed_links,
    loop_above,
    root_of,
    transform_matrix,
)
from segloc_cli.io.times import NS_PER_S, importer_times
from segloc_cli.limits import MAX_PLANAR_TILT_DEG, MAX_TILT_DEG
from segloc_cli.progress import Progress, ProgressFactory, silent
from segloc_cli.scan import MAX_RANGE_M, MAX_READINGS, Scan, fan_defect
from segloc_cli.wording import counted, plural

SCAN_TYPE = "sensor_msgs/msg/LaserScan"
ODOM_TYPE = "nav_msgs/msg/Odometry"
EXPECTED_BAG = "a ROS 1 .bag file, a ROS 2 bag folder with metadata.yaml, or a ROS 2 .mcap file"
TF_TOPICS = (TF_STATIC_TOPIC, TF_TOPIC)
NO_OFFSET = "none"
"""The laser offset's source when neither the bag nor ``--laser-offset`` gives one."""
OFFSET_TOLERANCE_M = 1e-3
OFFSET_TOLERANCE_DEG = 0.01
"""How far (m, degrees) ``--laser-offset`` may lie from the bag's own mounting unremarked:
the rounding of a value copied from the bag."""


class _RawScan(NamedTuple):
    stamp_ns: int
    frame_id: str
    angle_min: float
    angle_max: float
    angle_increment: float
    range_min: float
    range_max: float
    ranges: np.ndarray
    intensities: np.ndarray
    number: int = 0
    """Its place among the scan topic's messages in bag order, from 1, undecodable ones
    included."""


# Stamp (ns), x, y, and the orientation quaternion qx, qy, qz, qw.
_RawOdom = tuple[int, float, float, float, float, float, float]


class _Messages(NamedTuple):
    """What the messages of a bag held, in bag order: decoded scans, odometry and
    transforms, the first non-empty ``child_frame_id`` of the odometry (the robot's frame,
    or ""), and per topic the errors of the messages that could not be decoded."""

    scans: list[_RawScan]
    odom: list[_RawOdom]
    transforms: list[Transform]
    robot_frame: str
    failures: dict[str, list[str]]


def header_stamp_ns(message: Any) -> int:
    """A stamped message's ``header.stamp`` in integer nanoseconds."""
    stamp = message.header.stamp
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def _raw_scan(m: Any) -> _RawScan:
    return _RawScan(
        stamp_ns=header_stamp_ns(m),
        frame_id=str(m.header.frame_id),
        angle_min=float(m.angle_min),
        angle_max=float(m.angle_max),
        angle_increment=float(m.angle_increment),
        range_min=float(shortest_decimals(m.range_min)[0]),
        range_max=float(shortest_decimals(m.range_max)[0]),
        ranges=shortest_decimals(m.ranges),
        intensities=shortest_decimals(m.intensities),
    )


def shortest_decimals(values_float32: Any) -> np.ndarray:
    """Float32 values as float64 (N,), each the shortest decimal that reads back as the same
    float32 (non-finite values stay as they are)."""
    return np.asarray(values_float32, dtype=np.float32).reshape(-1).astype(str).astype(float)


def _raw_transforms(topic: str, message: Any) -> list[Transform]:
    """The transforms of a TFMessage; ``ValueError`` (the message is skipped and counted)
    when one of them is not finite or its rotation is no rotation."""
    transforms = []
    for stamped in message.transforms:
        t, q = stamped.transform.translation, stamped.transform.rotation
        translation, rotation = (t.x, t.y, t.z), (q.x, q.y, q.z, q.w)
        try:
            transform_matrix(translation, rotation)  # the one check of a transform
        except ValueError as exc:
            raise ValueError(f"{exc} (to {stamped.child_frame_id})") from None
        parent, child = str(stamped.header.frame_id), str(stamped.child_frame_id)
        transforms.append(Transform(topic, parent, child, translation, rotation))
    return transforms


def _raw_odom(message: Any) -> _RawOdom:
    """The pose of an Odometry message; ``ValueError`` (the message is skipped and counted)
    when it is not finite or its orientation is no rotation."""
    pose = message.pose.pose
    q = pose.orientation
    row = (header_stamp_ns(message), pose.position.x, pose.position.y, q.x, q.y, q.z, q.w)
    values = np.array(row[1:], dtype=float)
    if not np.all(np.isfinite(values)):
        raise ValueError("the pose is not finite")
    if not np.any(values[2:]):
        raise ValueError("the orientation quaternion is all zeros")
    return row


# --- opening -------------------------------------------------------------------------


def ros1_typestore():
    """The ROS 1 (Noetic) message types, with ``tf2_msgs/TFMessage``, which the store
    lacks, for bags that carry no definitions of their own (a salvaged bag's are not read)."""
    from rosbags.typesys import get_types_from_msg

    store = get_typestore(Stores.ROS1_NOETIC)
    store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TF_TYPES[0]))
    return store


def open_bag(path: Path) -> AnyReader:
    """Open ``path`` as a bag (an opened ``AnyReader``, the caller closes it); every way that
    fails becomes an ``InputError``, a file inside a ROS 2 bag folder (its ``metadata.yaml``
    or a ``.db3``) one that names the folder."""
    if not path.exists():
        raise InputError("file or folder not found; check the path", path=path)
    refuse_inside_ros2_bag(path)
    if not path.is_file() and not path.is_dir():
        raise InputError(
            f"is not a regular file (a pipe, socket or device); expected {EXPECTED_BAG}", path=path
        )
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        raise InputError(f"folder has no metadata.yaml; expected {EXPECTED_BAG}", path=path)
    # AnyReader reads a path ending in .bag as ROS 1 and anything else as ROS 2. The
    # default typestore only serves bags that carry no message definitions (ROS 2
    # before Iron); LaserScan and Odometry have one layout in every ROS 2 release.
    store = Stores.ROS1_NOETIC if path.suffix == ".bag" else Stores.LATEST
    try:
        reader = AnyReader([path], default_typestore=get_typestore(store))
        reader.open()
    except PermissionError as exc:
        raise InputError(f"cannot read ({exc.strerror or exc})", path=path) from None
    except Exception as exc:  # the bag library meets damaged bytes in many ways
        raise InputError(
            f"not a readable ROS bag ({failure_text(exc)}); expected {EXPECTED_BAG}", path=path
        ) from None
    return reader


def failure_text(exc: Exception) -> str:
    """An exception as a short phrase for a one-line message."""
    text = " ".join(str(exc).split())[:200]
    return (
        text
        if isinstance(exc, AnyReaderError | Ros1ReaderError | Ros2ReaderError)
        else (f"{type(exc).__name__}: {text}")
    )


def _topic_connections(path: Path, reader: AnyReader, topic: str, msgtype: str) -> list[Connection]:
    topics = reader.topics
    if topic not in topics:
        found = ", ".join(
            f"{name} ({info.msgtype or 'several types'})" for name, info in sorted(topics.items())
        )
        raise InputError(f"no topic {topic} in the bag; topics found: {found or 'none'}", path=path)
    connections = topics[topic].connections
    types = sorted({c.msgtype for c in connections})
    if types != [msgtype]:
        raise InputError(
            f"topic {topic} has type {', '.join(types)}; expected {msgtype}", path=path
        )
    return connections


def _read_messages(
    path: Path,
    reader: AnyReader,
    scan_topic: str,
    odom_topic: str | None,
    tf_topics: set[str],
    progress: ProgressFactory,
) -> _Messages:
    """The bag's scans, odometry and, from those of ``tf_topics`` it holds as transforms,
    its transforms (``_Messages``)."""
    scan_connections = _topic_connections(path, reader, scan_topic, SCAN_TYPE)
    odom_connections = (
        [] if odom_topic is None else _topic_connections(path, reader, odom_topic, ODOM_TYPE)
    )
    tf_connections = [
        connection
        for topic, info in reader.topics.items()
        if topic in tf_topics
        for connection in info.connections
        if connection.msgtype in TF_TYPES
    ]
    wanted = [*scan_connections, *odom_connections, *tf_connections]
    messages = (
        (connection.topic, connection.msgtype, data)
        for connection, _, data in reader.messages(wanted)
    )
    total = sum(connection.msgcount for connection in wanted)
    with progress("reading the bag", total, "message") as shown:
        return _decoded(messages, reader.deserialize, scan_topic, shown)


def _decoded(
    messages: Iterable[tuple[str, str, bytes]],
    deserialize: Callable,
    scan_topic: str,
    progress: Progress,
) -> _Messages:
    """``_Messages`` from (topic, type, raw bytes) in bag order: the scan topic holds scans,
    ``TF_TOPICS`` transforms and every other topic odometry. Each message is a step of
    ``progress``."""
    decoded = _Messages([], [], [], "", {})
    robot_frame = ""
    n_scan_messages = 0
    for topic, msgtype, data in messages:
        progress.advance()
        n_scan_messages += topic == scan_topic
        wanted: tuple[str, ...]
        if topic == scan_topic:
            wanted = (SCAN_TYPE,)
        else:
            wanted = TF_TYPES if topic in TF_TOPICS else (ODOM_TYPE,)
        try:
            if msgtype not in wanted:
                raise ValueError(f"type {msgtype}, expected {wanted[0]}")
            message = deserialize(data, msgtype)
            if topic == scan_topic:
                decoded.scans.append(_raw_scan(message)._replace(number=n_scan_messages))
            elif topic in TF_TOPICS:
                decoded.transforms.extend(_raw_transforms(topic, message))
            else:
                decoded.odom.append(_raw_odom(message))
                robot_frame = robot_frame or bare(str(message.child_frame_id))
        except (AnyReaderError, ValueError, struct.error, IndexError, KeyError) as exc:
            decoded.failures.setdefault(topic, []).append(str(exc))
    return decoded._replace(robot_frame=robot_frame)


def _salvaged(
    path: Path,
    scan_topic: str,
    odom_topic: str | None,
    tf_topics: set[str],
    refusal: InputError,
    progress: ProgressFactory,
) -> tuple[_Messages, str]:
    """A ROS 1 bag that the reader refused, read without its index (``ros1_salvage``), and
    the warning that says so; ``refusal`` is raised when that finds nothing either."""
    topics = {scan_topic} | ({odom_topic} if odom_topic else set())
    try:
        salvage = salvage_ros1(path, topics | tf_topics)
    except (OSError, ValueError):
        raise refusal from None
    deserialize = ros1_typestore().deserialize_ros1
    with progress("decoding the salvaged messages", len(salvage.messages), "message") as shown:
        decoded = _decoded(salvage.messages, deserialize, scan_topic, shown)
    if not decoded.scans:
        raise refusal from None
    where = "" if salvage.stopped is None else f", up to where {salvage.stopped}"
    note = (
        f"{path.name}: the bag's index is missing or damaged (a recording cut short?); read "
        f"its {counted(len(salvage.messages), 'message')} on "
        f"{', '.join(sorted(topics | {topic for topic, _, _ in salvage.messages}))} record by "
        f"record{where}"
    )
    return decoded, note


# --- reading -------------------------------------------------------------------------


def read_rosbag(
    path: str | Path,
    scan_topic: str = "/scan",
    odom_topic: str | None = "/odom",
    laser_offset: tuple[float, float, float] | None = None,
    progress: ProgressFactory = silent,
    range_max_m: float | None = None,
) -> Log:
    """Read laser scans and odometry from a ROS bag (see the module docstring); the
    messages read are steps of ``progress``.

    ``odom_topic=None`` reads no odometry. ``laser_offset`` (``x_m, y_m, theta_deg``:
    the scanner's pose in the robot frame, metres and degrees) sets the mounting instead
    of the bag's transforms. ``range_max_m`` (metres, positive, else ``ValueError``) is
    every scan's range limit instead of the messages' ``range_max``. Raises ``InputError``
    naming the bag when it is missing or not a bag, when a topic is absent or of the wrong
    type, when it is damaged, when it holds no scan that can be decoded, or when its
    transforms stand the scanner nearer vertical than level. A message that cannot be
    decoded is skipped and counted in ``warnings``. The log's ``odom_times_s`` are the
    times of the scans inside the odometry's time span.
    """
    if range_max_m is not None and not range_max_m > 0:
        raise ValueError(f"range_max_m must be positive, got {range_max_m}")
    path = Path(path)
    decoded, warnings = _bag_messages(path, scan_topic, odom_topic, set(TF_TOPICS), progress)
    warnings += [
        f"{path.name}: skipped {counted(len(errors), 'message')} on {topic} that could not be "
        "decoded "
        f"(first: {errors[0]})"
        for topic, errors in decoded.failures.items()
    ]
    raw_scans = _scans_to_import(path, decoded.scans, decoded.failures, scan_topic, warnings)
    offset_settings, mirrored = _laser_offset(
        path, decoded, raw_scans[0].frame_id, laser_offset, warnings
    )
    if mirrored:
        raw_scans = [_mirrored(raw) for raw in raw_scans]
    # Integer true division rounds once: the same float read_log gives back.
    original_times_s = np.array([raw.stamp_ns / NS_PER_S for raw in raw_scans], dtype=float)
    times_s, collided = importer_times(
        original_times_s, path, "scans", "stamp and bag order", path.name
    )
    scans, scan_warnings, range_rule = _scans(
        raw_scans, times_s, laser_offset_of(offset_settings, path), range_max_m
    )
    warnings += [f"{path.name}: {text}" for text in scan_warnings]
    warnings += [collided] if collided else []
    scan_ns = np.array([s.stamp_ns for s in raw_scans], dtype=np.int64)
    odom_times_s, odom_poses = _odometry(path, decoded.odom, scan_ns, times_s, odom_topic, warnings)
    return Log(
        scans=scans,
        original_times_s=original_times_s,
        odom_times_s=odom_times_s,
        odom_poses=odom_poses,
        sensor=_sensor(path, raw_scans, scans, range_rule, scan_topic, odom_topic)
        | offset_settings,
        warnings=warnings,
        numbers=np.array([raw.number for raw in raw_scans], dtype=np.int64),
    )


def _bag_messages(
    path: Path,
    scan_topic: str,
    odom_topic: str | None,
    tf_topics: set[str],
    progress: ProgressFactory,
) -> tuple[_Messages, list[str]]:
    """The bag's decoded messages (``_Messages``) and the warning that the bag was salvaged
    (a ROS 1 bag the reader refused) or none."""
    refusal: InputError
    try:
        reader = open_bag(path)
    except InputError as refused:
        refusal = refused
    else:
        try:
            decoded = _read_messages(path, reader, scan_topic, odom_topic, tf_topics, progress)
            return decoded, []
        except InputError:
            raise
        except Exception as exc:  # the bag library meets damaged bytes in many ways
            refusal = InputError(f"the bag is damaged ({failure_text(exc)})", path=path)
        finally:
            with contextlib.suppress(Exception):
                reader.close()
    # A ROS 1 bag cut short has no index (it is written last) but whole chunks.
    if path.suffix != ".bag" or not path.is_file():
        raise refusal
    decoded, note = _salvaged(path, scan_topic, odom_topic, tf_topics, refusal, progress)
    return decoded, [note]


# --- the scanner's mounting ----------------------------------------------------------


def _laser_offset(
    path: Path,
    decoded: _Messages,
    scan_frame: str,
    given: tuple[float, float, float] | None,
    warnings: list[str],
) -> tuple[dict[str, str], bool]:
    """The laser-offset sensor settings (``segloc_cli.io.log.laser_offset_settings``) and
    whether the beams are to be mirrored (an upside-down scanner): ``given`` when it is
    there (a warning when the bag's transforms place the scanner elsewhere), else the chain
    from the robot's frame to ``scan_frame`` in the bag's transforms (a warning when there
    is none, or when a frame of it is given two poses; ``InputError`` when the transforms
    form a loop on the way)."""
    scanner = bare(scan_frame)
    links = fixed_links(decoded.transforms)
    loop = _loop(links, [scanner, decoded.robot_frame])
    if given is not None:
        if loop is None:  # a loop places the scanner nowhere to compare with
            robot = decoded.robot_frame or root_of(links, scanner)
            warnings += _overridden(path, links, robot, scanner, given)
        return laser_offset_settings(*given, "--laser-offset"), False
    if loop is not None:
        frame, frames = loop
        raise InputError(
            f"the bag's transforms form a loop ({' -> '.join(frames)}): a frame is its own "
            f"ancestor, so they place {frame} nowhere; --laser-offset X,Y,THETA_DEG "
            "gives the scanner's pose on the robot instead",
            path=path,
        )
    robot = decoded.robot_frame or root_of(links, scanner)
    mounting = None
    if robot == scanner and decoded.robot_frame:
        return laser_offset_settings(0.0, 0.0, 0.0, f"frame_id:{robot}"), False
    why: str | None
    if robot == scanner:
        why = f"no odometry frame and no transform to {scanner} (the scans' frame)"
    elif (mounting := find_mounting(links, robot, scanner)) is None:
        why = (
            f"no transform from {robot} (the robot) to {scanner} (the scans' frame) in "
            f"{TF_STATIC_TOPIC} or {TF_TOPIC}"
        )
    else:
        why = _unusable(path, mounting, scanner)
    on_chain = {*ancestors(links, robot), *ancestors(links, scanner)}
    warnings += _contradictions(path, decoded.transforms, on_chain)
    if why is not None or mounting is None:
        warnings.append(
            f"{path.name}: {why}; the scanner is taken to be at the robot's origin "
            "(--laser-offset X,Y,THETA_DEG sets it)"
        )
        return laser_offset_settings(0.0, 0.0, 0.0, NO_OFFSET), False
    if mounting.tilt_deg > MAX_TILT_DEG:
        warnings.append(
            f"{path.name}: the scanner ({scanner}) is tilted {mounting.tilt_deg:.1f}° from "
            f"the floor plane of {robot} ({mounting.source}); its scans are taken as level"
        )
    if mounting.upside_down:
        warnings.append(
            f"{path.name}: the scanner ({scanner}) is mounted upside down ({mounting.source});"
            " its beams are mirrored into an upright scan"
        )
    theta_deg = math.degrees(mounting.theta_rad)
    settings = laser_offset_settings(mounting.x_m, mounting.y_m, theta_deg, mounting.source)
    flipped = {"laser_upside_down": "yes"} if mounting.upside_down else {}
    return settings | flipped, mounting.upside_down


def _loop(links: dict, frames: list[str]) -> tuple[str, list[str]] | None:
    """The first of ``frames`` (the scanner's, the robot's; empty names skipped) whose way
    up runs into a loop, and that loop; None when none does. No pose can be read from
    transforms that contradict themselves."""
    for frame in filter(None, frames):
        loop = loop_above(links, frame)
        if loop is not None:
            return bare(frame), loop
    return None


def _contradictions(path: Path, transforms: list[Transform], frames: set[str]) -> list[str]:
    """A warning per frame of ``frames`` that the bag gives two different fixed poses."""
    return [
        f"{path.name}: the bag gives {child} two poses, {_link_text(aside)} and "
        f"{_link_text(used)}; the latter is used ({_rule(aside, used)}; --laser-offset "
        "X,Y,THETA_DEG sets the scanner's pose instead)"
        for child, (aside, used) in disagreements(transforms).items()
        if child in frames
    ]


def _rule(aside: Transform, used: Transform) -> str:
    """Why ``used`` wins over ``aside``, in tf2's words."""
    if aside.topic == used.topic:
        return f"the latest on {used.topic}, as tf2 takes it"
    return f"{TF_STATIC_TOPIC} over an unchanging {TF_TOPIC}"


def _link_text(tf: Transform) -> str:
    """A transform as ``in PARENT at (x, y, z) m, yaw θ° (TOPIC)``."""
    x, y, z = tf.translation
    rotation = transform_matrix(tf.translation, tf.rotation)
    yaw = math.degrees(math.atan2(rotation[1, 0], rotation[0, 0]))
    return f"in {bare(tf.parent)} at ({x:.4g}, {y:.4g}, {z:.4g}) m, yaw {yaw:.4g}° ({tf.topic})"


def _overridden(
    path: Path, links: dict, robot: str, scanner: str, given: tuple[float, float, float]
) -> list[str]:
    """A warning when the bag's fixed ``links`` place ``scanner`` on ``robot`` otherwise
    than ``given`` (x m, y m, θ degrees), which wins; none when they place it nowhere usable."""
    mounting = None if robot == scanner else find_mounting(links, robot, scanner)
    if mounting is None or not np.all(np.isfinite([mounting.x_m, mounting.y_m])):
        return []
    theta_deg = math.degrees(mounting.theta_rad)
    turned = abs((theta_deg - given[2] + 180.0) % 360.0 - 180.0)
    moved = math.hypot(mounting.x_m - given[0], mounting.y_m - given[1])
    if moved <= OFFSET_TOLERANCE_M and turned <= OFFSET_TOLERANCE_DEG and not mounting.upside_down:
        return []
    flipped = ", upside down" if mounting.upside_down else ""
    return [
        f"{path.name}: --laser-offset {given[0]:g},{given[1]:g},{given[2]:g} is used; the bag's "
        f"transforms place {scanner} at x {mounting.x_m:.6g} m, y {mounting.y_m:.6g} m, theta "
        f"{theta_deg:.6g}°{flipped} ({mounting.source})"
    ]


def _unusable(path: Path, mounting: Mounting, scanner: str) -> str | None:
    """Why a mounting found in the transforms is not used, or None when it is; the
    transforms of a scanner nearer vertical than level are refused (``InputError``)."""
    if not all(math.isfinite(v) for v in (mounting.x_m, mounting.y_m, mounting.theta_rad)):
        return f"the transforms to {scanner} ({mounting.source}) are not finite"
    if max(abs(mounting.x_m), abs(mounting.y_m)) > MAX_LASER_OFFSET_M:
        return (
            f"the transforms place {scanner} at ({mounting.x_m:.6g}, {mounting.y_m:.6g}) m "
            f"({mounting.source}), more than {MAX_LASER_OFFSET_M:g} m from the robot"
        )
    if mounting.tilt_deg > MAX_PLANAR_TILT_DEG:
        raise InputError(
            f"the scanner ({scanner}) is tilted {mounting.tilt_deg:.1f}° from the floor plane "
            f"({mounting.source}): it does not scan a floor plan; --laser-offset X,Y,THETA_DEG "
            "imports its scans as level",
            path=path,
        )
    return None


def _mirrored(raw: _RawScan) -> _RawScan:
    """The scan of an upside-down scanner as its upright twin would see it: beam order
    reversed, angles negated (still counter-clockwise from ``angle_min``)."""
    last_rad = _last_angle(raw)
    return raw._replace(
        angle_min=-last_rad,
        angle_max=-raw.angle_min,
        ranges=raw.ranges[::-1].copy(),
        intensities=raw.intensities[::-1].copy(),
    )


def _scans_to_import(
    path: Path,
    raw_scans: list[_RawScan],
    failures: dict[str, list[str]],
    scan_topic: str,
    warnings: list[str],
) -> list[_RawScan]:
    """The decoded scans that can be imported, sorted by stamp (among equal stamps in bag
    order); a warning per reason others are skipped, ``InputError`` when none is left."""
    if not raw_scans:
        skipped = len(failures.get(scan_topic, []))
        why = f"; {skipped} could not be decoded" if skipped else ""
        raise InputError(f"topic {scan_topic} holds no laser scans{why}", path=path)
    raw_scans, dropped = _usable(raw_scans)
    notes = [
        f"skipped {counted(len(first), 'scan')} on {scan_topic} {why}" for why, first in dropped
    ]
    warnings += [f"{path.name}: {note}" for note in notes]
    if not raw_scans:
        raise InputError(
            f"topic {scan_topic} holds no usable laser scans; {'; '.join(notes)}", path=path
        )
    raw_scans.sort(key=lambda s: s.stamp_ns)  # stable: equal stamps stay in bag order
    return raw_scans


def _odometry(
    path: Path,
    raw_odom: list[_RawOdom],
    scan_ns: np.ndarray,
    times_s: np.ndarray,
    odom_topic: str | None,
    warnings: list[str],
) -> tuple[np.ndarray, np.ndarray]:
    """Odometry (K, 3) looked up at the scans' stamps ``scan_ns`` (S,) and filed under their
    distinct times ``times_s`` (S,) seconds, for the K scans inside its time span."""
    if odom_topic is None:
        return np.zeros(0), np.zeros((0, 3))
    if not raw_odom:
        warnings.append(f"{path.name}: topic {odom_topic} holds no odometry; none imported")
        return np.zeros(0), np.zeros((0, 3))
    inside, odom_poses = _interpolate_odometry(raw_odom, scan_ns)
    if not np.all(inside):
        warnings.append(
            f"{path.name}: {np.count_nonzero(~inside)} of {counted(len(scan_ns), 'scan')} lie "
            f"outside the time span of {odom_topic} and have no odometry"
        )
    return times_s[inside], odom_poses


def _last_angle(raw: _RawScan) -> float:
    """The angle (rad) of a scan's last beam, at ``angle_increment`` steps from ``angle_min``."""
    return raw.angle_min + max(len(raw.ranges) - 1, 0) * raw.angle_increment


def _usable(raw_scans: list[_RawScan]) -> tuple[list[_RawScan], list[tuple[str, list[str]]]]:
    """The scans that can be imported, and per reason the defects of those that cannot."""
    kept = []
    dropped: dict[str, list[str]] = {}
    for raw in raw_scans:
        n = len(raw.ranges)
        last_rad = _last_angle(raw)
        if raw.stamp_ns < 0:
            dropped.setdefault("stamped before 1970 (negative header.stamp)", []).append("")
        elif n > MAX_READINGS:
            dropped.setdefault(f"with more than {MAX_READINGS:,} readings", []).append("")
        elif (defect := fan_defect(n, raw.angle_min, last_rad)) is not None:
            dropped.setdefault("with an unusable beam fan", []).append(defect)
        elif abs(_spanned_count(raw) - n) > 1:
            dropped.setdefault("whose angle_increment disagrees with their ranges", []).append(
                f"angle_min {raw.angle_min:.6g} to angle_max {raw.angle_max:.6g} rad at "
                f"{raw.angle_increment:.6g} rad spans {_spanned_count(raw)} beams, not {n}"
            )
        elif raw.range_min > raw.range_max > 0.0:
            dropped.setdefault("whose range_max is below their range_min", []).append(
                f"range_min {raw.range_min:g} m, range_max {raw.range_max:g} m"
            )
        else:
            kept.append(raw)
    return kept, [
        (why + (f" (first: {defects[0]})" if defects[0] else ""), defects)
        for why, defects in dropped.items()
    ]


def _with_usable_limits(raw: _RawScan) -> _RawScan:
    """``raw`` with range limits that can be applied: a range_max that is not a positive
    number, or not above range_min, is no maximum (inf) and such a range_min none (0), so
    that a driver's bad limits do not make every reading invalid."""
    low, high = raw.range_min, raw.range_max
    if not (math.isfinite(low) and low >= 0.0):
        low = 0.0
    if not (high > low):  # NaN, 0, negative, or not above the minimum
        low, high = 0.0, math.inf
    return raw._replace(range_min=low, range_max=high)


def _scans(
    raw_scans: list[_RawScan], times_s: np.ndarray, mount: Pose2, range_max_m: float | None
) -> tuple[list[Scan], list[str], str]:
    """Scans (invalid readings as 0.0) at ``times_s`` (S,) seconds from decoded messages,
    mounted at ``mount`` (the scanner's pose in the robot frame), with the range limit
    ``range_max_m`` when given (else ``_range_maxes``); notes on oddities, and the rule that
    gave the range limits."""
    bad_limits: list[str] = []
    usable = []
    for given in raw_scans:
        raw = _with_usable_limits(given)
        if (raw.range_min, raw.range_max) != (given.range_min, given.range_max):
            bad_limits.append(f"range_min {given.range_min!r}, range_max {given.range_max!r}")
        usable.append(raw)
    limits, limit_notes, rule = _range_maxes(usable, range_max_m)
    scans = []
    mismatched = []
    intensity_counts: list[tuple[int, int]] = []
    for raw, limit_m, time_s in zip(usable, limits, times_s, strict=True):
        if _spanned_count(raw) != len(raw.ranges):
            mismatched.append(raw)
        if len(raw.intensities) not in (0, len(raw.ranges)):
            intensity_counts.append((len(raw.intensities), len(raw.ranges)))
            raw = raw._replace(intensities=np.zeros(0))
        scans.append(_scan(raw._replace(range_max=limit_m), float(time_s), mount))
    notes = [
        *_limit_notes(bad_limits),
        *_count_notes(mismatched, len(scans)),
        *_intensity_notes(intensity_counts, len(scans)),
        *limit_notes,
    ]
    range_maxes = sorted({s.range_max_m for s in scans})
    if len(range_maxes) > 1:
        notes.append(
            f"range_max varies between scans ({range_maxes[0]!r} to {range_maxes[-1]!r} m); "
            "each scan keeps its own"
        )
    return scans, notes, rule


def _range_maxes(
    raw_scans: list[_RawScan], range_max_m: float | None
) -> tuple[list[float], list[str], str]:
    """Each scan's range limit (m): ``range_max_m`` when given, else its message's
    ``range_max`` unless the returns of the scans sharing that value lie beyond it
    (``segloc_cli.io.range_limits``); a note on each ``range_max`` not used, and the rule
    that gave the limits (the sensor setting ``range_max_from``)."""
    if range_max_m is not None:
        return [float(range_max_m)] * len(raw_scans), [], "given"
    limits = [raw.range_max for raw in raw_scans]
    sharing: dict[float, list[int]] = {}
    for i, raw in enumerate(raw_scans):
        if math.isfinite(raw.range_max):
            sharing.setdefault(raw.range_max, []).append(i)
    notes, rules = [], []
    n_overruled = 0
    for stated_m, indices in sorted(sharing.items()):
        readings = np.concatenate([raw_scans[i].ranges for i in indices])
        limit = stated_limit(readings, stated_m, "range_max", counted(len(indices), "scan"))
        if limit is None:
            continue
        for i in indices:
            limits[i] = limit.value_m
        n_overruled += len(indices)
        notes.append(limit.warning)
        rules.append(limit.rule)
    kept = ["LaserScan range_max"] if n_overruled < len(raw_scans) else []
    return limits, notes, "; ".join(kept + rules)


def _spanned_count(raw: _RawScan) -> int:
    """How many beams ``angle_min`` to ``angle_max`` at ``angle_increment`` span (-1 when
    that is no count: a step of 0, or values that are not finite)."""
    span = (raw.angle_max - raw.angle_min) / raw.angle_increment if raw.angle_increment else 0
    if not math.isfinite(span) or abs(span) > 2**31:
        return -1 if raw.angle_max != raw.angle_min else 1
    return round(span) + 1


def _scan(raw: _RawScan, time_s: float, mount: Pose2) -> Scan:
    """The scan of a message with usable range limits, at ``time_s`` seconds, mounted at
    ``mount``; readings outside the limits or not finite become 0.0."""
    n = len(raw.ranges)
    with np.errstate(invalid="ignore"):
        valid = (
            np.isfinite(raw.ranges) & (raw.ranges >= raw.range_min) & (raw.ranges < raw.range_max)
        )
    return Scan(
        time_s=time_s,
        angles_rad=raw.angle_min + np.arange(n) * raw.angle_increment,
        ranges_m=np.where(valid, raw.ranges, 0.0),
        range_max_m=raw.range_max,
        intensities=raw.intensities,
        mount=mount,
    )


def _limit_notes(bad_limits: list[str]) -> list[str]:
    """A note on the scans whose range limits cannot be applied as given (``bad_limits``:
    the limits each such scan gave), or none."""
    if not bad_limits:
        return []
    n = len(bad_limits)
    return [
        f"{counted(n, 'scan')} {plural(n, 'gives', 'give')} range limits that cannot be applied "
        f"(first: {bad_limits[0]} m); their readings count up to {MAX_RANGE_M:g} m"
    ]


def _intensity_notes(counts: list[tuple[int, int]], n_scans: int) -> list[str]:
    """A note on the scans among ``n_scans`` whose number of intensities is not their
    number of readings (``counts``: the two numbers of each), or none."""
    if not counts:
        return []
    k = len(counts)
    its = plural(k, "its", "their")
    first = f"{'first: ' if k > 1 else ''}{counted(counts[0][0], 'intensity', 'intensities')}"
    return [
        f"{k} of {counted(n_scans, 'scan')} {plural(k, 'holds', 'hold')} a number of "
        f"intensities other than {its} number of readings ({first} for "
        f"{counted(counts[0][1], 'reading')}); {its} intensities were dropped and {its} "
        "readings kept"
    ]


def _count_notes(mismatched: list[_RawScan], n_scans: int) -> list[str]:
    """Notes on the scans among ``n_scans`` whose number of readings is not the number of
    beams angle_min to angle_max at angle_increment gives (by one at most: more is skipped
    by ``_usable``): one for those with more readings, one for those with fewer."""
    notes = []
    for more, where in ((True, "past"), (False, "short of")):
        group = [raw for raw in mismatched if (len(raw.ranges) > _spanned_count(raw)) == more]
        if not group:
            continue
        k, first = len(group), group[0]
        their = plural(k, "its", "their")
        first_of = "first: " if k > 1 else ""
        found = (
            f"{counted(len(first.ranges), 'reading')}, where angle_min {first.angle_min:.6g} to "
            f"angle_max {first.angle_max:.6g} rad in steps of {first.angle_increment:.6g} rad "
            f"give {counted(_spanned_count(first), 'beam')}"
        )
        notes.append(
            f"{k} of {counted(n_scans, 'scan')} {plural(k, 'holds', 'hold')} "
            f"{'more' if more else 'fewer'} readings than {their} angles give ({first_of}"
            f"{found}); all {their} readings are kept, beam i at angle_min + i·angle_increment, "
            f"so {their} last beam lies {where} angle_max ({first_of}at "
            f"{_last_angle(first):.6g} rad)"
        )
    return notes


def _interpolate_odometry(
    raw_odom: list[_RawOdom], scan_ns: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Odometry poses at the scan times (ns, int64) inside the odometry's time span.

    Returns a mask (S,) of the scans inside the span and their poses (K, 3)
    ``x_m, y_m, theta_rad``; x and y are linear in time, the heading follows the
    shorter arc between the neighbouring messages.
    """
    table = sorted(raw_odom, key=lambda row: row[0])
    odom_ns = np.array([row[0] for row in table], dtype=np.int64)
    values = np.array([row[1:] for row in table], dtype=float)
    theta = wrap_angle(
        quaternion_to_heading(values[:, 2], values[:, 3], values[:, 4], values[:, 5])
    )
    poses = np.column_stack([values[:, 0], values[:, 1], theta])

    inside = (scan_ns >= odom_ns[0]) & (scan_ns <= odom_ns[-1])
    query = scan_ns[inside]
    if len(odom_ns) == 1:
        return inside, np.repeat(poses, len(query), axis=0)
    before = np.clip(np.searchsorted(odom_ns, query, side="right") - 1, 0, len(odom_ns) - 2)
    after = before + 1
    # Differences of integer nanoseconds are exact; float seconds near 1e9 s are not.
    span_ns = odom_ns[after] - odom_ns[before]
    w = np.divide(
        (query - odom_ns[before]).astype(float),
        span_ns.astype(float),
        out=np.zeros(len(query)),
        where=span_ns > 0,
    )
    p0, p1 = poses[before], poses[after]
    xy = p0[:, :2] + w[:, None] * (p1[:, :2] - p0[:, :2])
    heading = wrap_angle(p0[:, 2] + w * wrap_angle(p1[:, 2] - p0[:, 2]))
    return inside, np.column_stack([xy, heading])


def _largest_range_max(scans: list[Scan]) -> str:
    """The largest range limit of the scans as text, "inf" if one has none."""
    largest = max(scan.range_max_m for scan in scans)
    return repr(float(largest)) if math.isfinite(largest) else "inf"


def _sensor(
    path: Path,
    raw_scans: list[_RawScan],
    scans: list[Scan],
    range_rule: str,
    scan_topic: str,
    odom_topic: str | None,
) -> dict[str, str]:
    """Settings for the MCAP log's metadata record, from the messages and the scans made of
    them, whose range limits ``range_rule`` gave (str → str)."""
    first = raw_scans[0]
    fov_rad = abs(first.angle_increment) * max(len(first.ranges) - 1, 0)
    kind = "ROS 1 bag" if path.suffix == ".bag" else "ROS 2 bag"
    return {
        # The largest, so that no reading valid in its own scan is invalid in the log.
        "range_max_m": _largest_range_max(scans),
        "range_max_from": range_rule,
        "range_min_m": repr(min(raw.range_min for raw in raw_scans)),
        "readings": ",".join(str(n) for n in sorted({len(raw.ranges) for raw in raw_scans})),
        "fov_deg": f"{math.degrees(fov_rad):.6g}",
        "frame_id": first.frame_id,
        "source": f"{kind} {path.name}",
        "scan_topic": scan_topic,
        "odom_topic": "none" if odom_topic is None else odom_topic,
    }
