"""Poses and transforms out of decoded messages of the types another localizer publishes.

A decoded message is what ``rosbags`` deserializes (attribute access, ROS 1 and ROS 2
alike), what ``mcap-protobuf-support`` decodes (a protobuf message) or a JSON object (a
dict). Each reader below takes one and gives plain numbers:

- ``Pose``: the stamp (integer nanoseconds), the frame the pose is in, the position
  (x, y, z metres), the orientation quaternion (x, y, z, w) and, where the message carries
  one, the (x, y, yaw) block of its 6×6 covariance;
- ``Link``: one transform of a transform message, the child frame's pose in the parent's.

Frame names are given without a leading "/" (ROS 1's tf wrote "/map").
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

from segloc_cli.estimates import COVARIANCE_CELLS
from segloc_cli.io.rosbag import header_stamp_ns
from segloc_cli.io.tf import TF_TYPES, bare
from segloc_cli.io.times import NS_PER_S

POSE_WITH_COVARIANCE_TYPE = "geometry_msgs/msg/PoseWithCovarianceStamped"
POSE_STAMPED_TYPE = "geometry_msgs/msg/PoseStamped"
ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
FOXGLOVE_POSE_TYPE = "foxglove.PoseInFrame"
FOXGLOVE_TF_TYPE = "foxglove.FrameTransforms"
LINK_TYPES = (*TF_TYPES, FOXGLOVE_TF_TYPE)
"""Message types that carry transforms between named frames (read with ``frames``)."""
POSE_TYPES = (POSE_WITH_COVARIANCE_TYPE, POSE_STAMPED_TYPE, ODOMETRY_TYPE, FOXGLOVE_POSE_TYPE)
"""Message types that carry one pose each."""
SUPPORTED_TYPES = (*POSE_TYPES, *LINK_TYPES)
_PLANAR_AXES = (0, 1, 5)
"""x, y and yaw among the axes of a ROS pose covariance (x, y, z, roll, pitch, yaw)."""
COVARIANCE_INDICES = tuple(6 * _PLANAR_AXES[r] + _PLANAR_AXES[c] for r, c in COVARIANCE_CELLS)
"""Where the entries of ``estimates.COVARIANCE_COLUMNS`` lie in a ROS 6×6 row-major pose
covariance: var x, cov xy, var y, cov x-yaw, cov y-yaw, var yaw (0, 1, 7, 5, 11, 35)."""


class Pose(NamedTuple):
    """One pose of a message: ``stamp_ns`` (None when the message carries no time),
    ``frame_id`` (bare), ``values`` x y z (m) qx qy qz qw, ``covariance`` the six values of
    ``COVARIANCE_COLUMNS`` (m², m·rad, rad²) or None."""

    stamp_ns: int | None
    frame_id: str
    values: tuple[float, ...]
    covariance: tuple[float, ...] | None


class Link(NamedTuple):
    """One transform: ``child``'s pose in ``parent`` at ``stamp_ns``; ``values`` tx ty tz (m)
    qx qy qz qw; ``static`` whether it came from the static transform topic."""

    stamp_ns: int
    parent: str
    child: str
    values: tuple[float, ...]
    static: bool


def _xyz_q(pose: Any) -> tuple[float, ...]:
    p, q = pose.position, pose.orientation
    return tuple(float(v) for v in (p.x, p.y, p.z, q.x, q.y, q.z, q.w))


def _covariance(covariance: Any) -> tuple[float, ...]:
    values = [float(v) for v in covariance]
    if len(values) != 36:
        raise ValueError(f"the covariance holds {len(values)} values, not 36")
    return tuple(values[i] for i in COVARIANCE_INDICES)


def _ros_pose(message: Any, covariance: bool, nested: bool) -> Pose:
    pose = message.pose.pose if nested else message.pose
    return Pose(
        stamp_ns=header_stamp_ns(message),
        frame_id=bare(str(message.header.frame_id)),
        values=_xyz_q(pose),
        covariance=_covariance(message.pose.covariance) if covariance else None,
    )


def _foxglove_stamp(stamp: Any) -> int | None:
    """A Foxglove timestamp (protobuf ``seconds, nanos``; JSON ``sec, nsec``) in ns."""
    if stamp is None:
        return None
    if isinstance(stamp, dict):
        return int(stamp["sec"]) * NS_PER_S + int(stamp["nsec"])
    return int(stamp.seconds) * NS_PER_S + int(stamp.nanos)


def _field(message: Any, name: str) -> Any:
    """A field of a protobuf message or JSON object; None when it is not set."""
    if isinstance(message, dict):
        return message.get(name)
    return getattr(message, name) if message.HasField(name) else None


def _numbers(part: Any, names: str) -> tuple[float, ...]:
    if isinstance(part, dict):
        return tuple(float(part[name]) for name in names)
    return tuple(float(getattr(part, name)) for name in names)


def _foxglove_pose(message: Any) -> Pose:
    pose = message["pose"] if isinstance(message, dict) else message.pose
    position = pose["position"] if isinstance(pose, dict) else pose.position
    orientation = pose["orientation"] if isinstance(pose, dict) else pose.orientation
    frame = message["frame_id"] if isinstance(message, dict) else message.frame_id
    return Pose(
        stamp_ns=_foxglove_stamp(_field(message, "timestamp")),
        frame_id=bare(str(frame)),
        values=_numbers(position, "xyz") + _numbers(orientation, "xyzw"),
        covariance=None,
    )


POSE_READERS: dict[str, Callable[[Any], Pose]] = {
    POSE_WITH_COVARIANCE_TYPE: lambda m: _ros_pose(m, covariance=True, nested=True),
    POSE_STAMPED_TYPE: lambda m: _ros_pose(m, covariance=False, nested=False),
    ODOMETRY_TYPE: lambda m: _ros_pose(m, covariance=True, nested=True),
    FOXGLOVE_POSE_TYPE: _foxglove_pose,
}
"""Per pose message type, the function that reads its ``Pose``."""


def ros_links(message: Any, static: bool) -> list[Link]:
    """The transforms of a ``tf2_msgs/TFMessage`` (or ROS 1 ``tf/tfMessage``)."""
    return [
        Link(
            stamp_ns=header_stamp_ns(stamped),
            parent=bare(str(stamped.header.frame_id)),
            child=bare(str(stamped.child_frame_id)),
            values=_numbers(stamped.transform.translation, "xyz")
            + _numbers(stamped.transform.rotation, "xyzw"),
            static=static,
        )
        for stamped in message.transforms
    ]


def foxglove_links(message: Any, static: bool, log_time_ns: int) -> list[Link]:
    """The transforms of a ``foxglove.FrameTransforms`` (protobuf or JSON); a transform
    without a timestamp is taken at the message's log time."""
    transforms = message["transforms"] if isinstance(message, dict) else message.transforms
    links = []
    for transform in transforms:
        stamp = _foxglove_stamp(_field(transform, "timestamp"))
        get = transform.get if isinstance(transform, dict) else transform.__getattribute__
        links.append(
            Link(
                stamp_ns=log_time_ns if stamp is None else stamp,
                parent=bare(str(get("parent_frame_id"))),
                child=bare(str(get("child_frame_id"))),
                values=_numbers(get("translation"), "xyz") + _numbers(get("rotation"), "xyzw"),
                static=static,
            )
        )
    return links


def message_links(msgtype: str, message: Any, static: bool, log_time_ns: int) -> list[Link]:
    """The transforms of a message of one of ``LINK_TYPES``."""
    if msgtype == FOXGLOVE_TF_TYPE:
        return foxglove_links(message, static, log_time_ns)
    return ros_links(message, static)
