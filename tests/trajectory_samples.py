"""Trajectories of another localizer written in every format segloc reads, with the formats'
own writers: ROS 1 and ROS 2 bags (rosbags), MCAP files of ``foxglove.PoseInFrame``
(foxglove-sdk for protobuf, the ``mcap`` writer for JSON), TUM text.

AMCL's ROS 2 bags come from ``examples/amcl_bags.py`` (``write_amcl_bag``), the script of
the CI quick start; tests import it from there (``examples/`` is on pytest's path).

Poses are (N, 3) arrays ``x_m, y_m, theta_rad``; covariances (N, 3, 3) over (x m, y m,
yaw rad); stamps integer nanoseconds.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import pandas as pd
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Ros2Writer
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from segloc_cli.estimates import ESTIMATE_COLUMNS
from segloc_cli.geometry import heading_to_quaternion
from segloc_cli.io.rosbag import ros1_typestore

ROS1_STORE = ros1_typestore()
ROS2_STORE = get_typestore(Stores.LATEST)
PWCS = "geometry_msgs/msg/PoseWithCovarianceStamped"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
TF = "tf2_msgs/msg/TFMessage"
SCAN = "sensor_msgs/msg/LaserScan"
NS = 1_000_000_000
# Where each (x, y, yaw) entry goes in ROS's 6×6 covariance over x y z roll pitch yaw.
_SLOTS = (0, 1, 5)


def stamps_ns(times_s: Iterable[float]) -> list[int]:
    """Times (s) as whole nanoseconds."""
    return [round(float(t) * NS) for t in times_s]


def covariance36(cov3: np.ndarray | None) -> np.ndarray:
    """A (3, 3) covariance over (x, y, yaw) in ROS's 6×6 row-major layout (36,)."""
    full = np.zeros((6, 6))
    if cov3 is not None:
        full[np.ix_(_SLOTS, _SLOTS)] = np.asarray(cov3, dtype=float)
    return full.reshape(36)


def _header(store: Typestore, stamp_ns: int, frame_id: str):
    sec, nanosec = divmod(int(stamp_ns), NS)
    stamp = store.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
    fields = {"seq": 0} if store is ROS1_STORE else {}
    return store.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id, **fields)


def _pose(store: Typestore, pose, z: float = 0.0, quaternion=None):
    t = store.types
    qx, qy, qz, qw = heading_to_quaternion(pose[2]).tolist() if quaternion is None else quaternion
    return t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=float(pose[0]), y=float(pose[1]), z=z),
        orientation=t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
    )


def pose_with_covariance(store: Typestore, stamp_ns: int, frame: str, pose, cov3=None, **kw):
    """A ``PoseWithCovarianceStamped`` (what AMCL publishes) at ``pose`` (x, y, θ rad)."""
    t = store.types
    return t[PWCS](
        header=_header(store, stamp_ns, frame),
        pose=t["geometry_msgs/msg/PoseWithCovariance"](
            pose=_pose(store, pose, **kw), covariance=covariance36(cov3)
        ),
    )


def pose_stamped(store: Typestore, stamp_ns: int, frame: str, pose, cov3=None, **kw):
    return store.types[POSE_STAMPED](
        header=_header(store, stamp_ns, frame), pose=_pose(store, pose, **kw)
    )


def odometry(store: Typestore, stamp_ns: int, frame: str, pose, cov3=None, **kw):
    t = store.types
    vector = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    return t[ODOMETRY](
        header=_header(store, stamp_ns, frame),
        child_frame_id="base_link",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](
            pose=_pose(store, pose, **kw), covariance=covariance36(cov3)
        ),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](linear=vector, angular=vector),
            covariance=np.zeros(36),
        ),
    )


def tf_message(store: Typestore, links: list[tuple[int, str, str, tuple]]):
    """A ``TFMessage`` of (stamp ns, parent, child, (x, y, θ rad)) links."""
    t = store.types
    transforms = []
    for stamp_ns, parent, child, pose in links:
        qx, qy, qz, qw = heading_to_quaternion(pose[2]).tolist()
        transforms.append(
            t["geometry_msgs/msg/TransformStamped"](
                header=_header(store, stamp_ns, parent),
                child_frame_id=child,
                transform=t["geometry_msgs/msg/Transform"](
                    translation=t["geometry_msgs/msg/Vector3"](
                        x=float(pose[0]), y=float(pose[1]), z=0.0
                    ),
                    rotation=t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
                ),
            )
        )
    return t[TF](transforms=transforms)


def empty_scan(store: Typestore, stamp_ns: int):
    """A LaserScan without readings: a topic that is not a pose."""
    return store.types[SCAN](
        header=_header(store, stamp_ns, "laser"),
        angle_min=0.0,
        angle_max=0.0,
        angle_increment=0.0,
        time_increment=0.0,
        scan_time=0.0,
        range_min=0.0,
        range_max=1.0,
        ranges=np.zeros(0, dtype=np.float32),
        intensities=np.zeros(0, dtype=np.float32),
    )


def write_bag(kind: str, path: Path, topics: dict[str, str], messages: list[tuple]) -> Path:
    """Write ``messages`` (topic, record ns, message object) on ``topics`` (topic → type) as
    ``kind``: "ros1" (``path`` a ``.bag`` file), "sqlite3" or "mcap" (``path`` a ROS 2 bag
    folder). Returns ``path``."""
    if kind == "ros1":
        with Ros1Writer(path) as writer:
            connections = {
                topic: writer.add_connection(topic, msgtype, typestore=ROS1_STORE)
                for topic, msgtype in topics.items()
            }
            for topic, record_ns, message in messages:
                data = ROS1_STORE.serialize_ros1(message, topics[topic])
                writer.write(connections[topic], record_ns, bytes(data))
        return path
    plugin = StoragePlugin.SQLITE3 if kind == "sqlite3" else StoragePlugin.MCAP
    with Ros2Writer(path, version=9, storage_plugin=plugin) as writer:
        connections = {
            topic: writer.add_connection(topic, msgtype, typestore=ROS2_STORE)
            for topic, msgtype in topics.items()
        }
        for topic, record_ns, message in messages:
            data = ROS2_STORE.serialize_cdr(message, topics[topic])
            writer.write(connections[topic], record_ns, bytes(data))
    return path


def amcl_messages(
    store: Typestore,
    stamps: list[int],
    poses: np.ndarray,
    covariances: np.ndarray,
    frame: str = "map",
) -> list[tuple]:
    """``/amcl_pose`` records (topic, record ns, message) for ``write_bag``: one
    ``PoseWithCovarianceStamped`` per pose (x m, y m, θ rad) with its (3, 3) covariance,
    stamped at ``stamps`` (ns) and recorded 5 ms later, as AMCL publishes its estimates."""
    return [
        ("/amcl_pose", stamp + 5_000_000, pose_with_covariance(store, stamp, frame, p, c))
        for stamp, p, c in zip(stamps, np.asarray(poses), np.asarray(covariances), strict=True)
    ]


def write_foxglove_mcap(path: Path, stamps: list[int], poses: np.ndarray, frame: str = "map"):
    """An MCAP file written by foxglove-sdk: ``/pose``, ``foxglove.PoseInFrame`` (protobuf)."""
    import foxglove
    from foxglove import channels
    from foxglove.messages import Pose, PoseInFrame, Quaternion, Timestamp, Vector3

    context = foxglove.Context()
    writer = foxglove.open_mcap(path, allow_overwrite=True, context=context)
    channel = channels.PoseInFrameChannel("/pose", context=context)
    for stamp, (x, y, theta) in zip(stamps, poses, strict=True):
        qx, qy, qz, qw = heading_to_quaternion(theta).tolist()
        channel.log(
            PoseInFrame(
                timestamp=Timestamp(sec=stamp // NS, nsec=stamp % NS),
                frame_id=frame,
                pose=Pose(
                    position=Vector3(x=float(x), y=float(y), z=0.0),
                    orientation=Quaternion(x=qx, y=qy, z=qz, w=qw),
                ),
            ),
            log_time=stamp + 1_000_000,
        )
    writer.close()
    return path


def write_json_pose_mcap(
    path: Path, stamps: list[int], poses: np.ndarray, frame: str = "map", untimed=()
):
    """An MCAP file of ``/pose``, ``foxglove.PoseInFrame`` in JSON encoding (mcap writer); the
    messages numbered in ``untimed`` (from 0) without a timestamp, logged at their stamp."""
    from mcap.writer import Writer

    with path.open("wb") as stream:
        writer = Writer(stream)
        writer.start()
        schema = writer.register_schema(
            name="foxglove.PoseInFrame", encoding="jsonschema", data=b'{"type": "object"}'
        )
        channel = writer.register_channel("/pose", message_encoding="json", schema_id=schema)
        for k, (stamp, (x, y, theta)) in enumerate(zip(stamps, poses, strict=True)):
            qx, qy, qz, qw = heading_to_quaternion(theta).tolist()
            message = {
                "timestamp": {"sec": stamp // NS, "nsec": stamp % NS},
                "frame_id": frame,
                "pose": {
                    "position": {"x": float(x), "y": float(y), "z": 0.0},
                    "orientation": {"x": qx, "y": qy, "z": qz, "w": qw},
                },
            }
            if k in untimed:
                del message["timestamp"]
            data = json.dumps(message).encode()
            writer.add_message(channel, log_time=stamp, data=data, publish_time=stamp)
        writer.finish()
    return path


def write_tum(path: Path, stamps: list[int], poses: np.ndarray) -> Path:
    """A TUM trajectory, times the float nearest each stamp, numbers as exact text."""
    lines = ["# t x y z qx qy qz qw"]
    for stamp, (x, y, theta) in zip(stamps, poses, strict=True):
        q = heading_to_quaternion(theta).tolist()
        lines.append(" ".join(repr(float(v)) for v in (stamp / NS, x, y, 0.0, *q)))
    path.write_text("\n".join(lines) + "\n")
    return path


def estimates_frame(times_s: np.ndarray, poses: np.ndarray) -> pd.DataFrame:
    """An estimates frame of ``poses`` at ``times_s`` as segloc writes one (no stage data)."""
    frame = pd.DataFrame({c: np.full(len(poses), np.nan) for c in ESTIMATE_COLUMNS})
    frame["pose_id"] = np.arange(1, len(poses) + 1)
    frame["time_s"] = times_s
    frame["x_m"], frame["y_m"] = poses[:, 0], poses[:, 1]
    frame["theta_deg"] = np.degrees(poses[:, 2])
    frame["n_local_segments"] = 0
    frame["window_scans"] = 0
    frame["status"] = "ok"
    return frame
