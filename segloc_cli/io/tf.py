"""ROS transform trees: where a bag's scanner sits on its robot, from ``/tf_static`` and ``/tf``.

A bag's transforms (``geometry_msgs/TransformStamped``: a child frame's pose in its
parent frame, translation in metres, rotation as a quaternion ``x y z w``) form a tree:
each child frame has one parent. Which of them describe the robot's build:

- every transform on ``/tf_static``; a child given again takes the latest;
- a transform on ``/tf`` whose every message gives the same translation and rotation
  (a mounting published at a rate, as ROS 1's ``static_transform_publisher`` does),
  unless ``/tf_static`` gives that child; one that changes (``odom → base_link``) is
  motion and is left out.

Frame names are compared without a leading "/" (ROS 1's tf wrote "/base_link").

Transforms that contradict each other: a child that ``/tf_static`` gives twice with
different poses (or parents) takes the latest, as tf2 does, and one that ``/tf_static`` and
an unchanging ``/tf`` give differently takes ``/tf_static``'s (``disagreements`` lists
them, for a warning). Transforms that form a loop (a frame its own ancestor) place nothing:
``loop_above`` finds one, which the importer refuses.

``find_mounting`` composes the transforms along the tree from the robot's frame to the
scanner's (through their nearest common ancestor, so neither need be above the other)
and projects the result onto the robot's floor plane: the scanner's position x, y and
the heading of its x axis, with how far its scan plane is tilted from level and whether
it faces down (upside down, which mirrors its beams).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from segloc_cli.geometry import wrap_angle

TF_STATIC_TOPIC = "/tf_static"
TF_TOPIC = "/tf"
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
"""Message types of the transform topics (ROS 1 before tf2 wrote ``tf/tfMessage``)."""
SAME_LINK_TOLERANCE = 1e-6
"""Largest difference (metres; quaternion components) of two transforms taken as the same."""


class Transform(NamedTuple):
    """One transform of a bag: ``child``'s pose in ``parent`` as read from ``topic``;
    ``translation`` (3,) metres, ``rotation`` (4,) a non-zero quaternion ``x y z w``."""

    topic: str
    parent: str
    child: str
    translation: tuple[float, float, float]
    rotation: tuple[float, float, float, float]


@dataclass(frozen=True)
class Mounting:
    """A scanner's pose in the robot frame, projected onto the robot's floor plane.

    ``x_m``, ``y_m`` metres; ``theta_rad`` the heading of the scanner's x axis in
    [-π, π); ``tilt_deg`` the angle between the scan plane and the floor plane (0 for a
    level scanner, upright or upside down); ``upside_down`` whether the scanner's z axis
    points down; ``source`` where the chain came from, ``tf_static:ROBOT->SCANNER`` (or
    ``tf:…`` when a link of it came from ``/tf``).
    """

    x_m: float
    y_m: float
    theta_rad: float
    tilt_deg: float
    upside_down: bool
    source: str


def bare(frame: str) -> str:
    """A frame name as compared here: without a leading "/"."""
    return frame.lstrip("/")


def transform_matrix(translation: Iterable[float], rotation: Iterable[float]) -> np.ndarray:
    """The homogeneous matrix (4, 4) of a translation (3,) in metres and a quaternion (4,)
    ``x y z w`` (normalised here); ``ValueError`` when either is not finite or the
    quaternion is zero."""
    t = np.asarray(list(translation), dtype=float)
    q = np.asarray(list(rotation), dtype=float)
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(q))):
        raise ValueError("the transform is not finite")
    largest = float(np.max(np.abs(q)))
    if largest == 0.0:
        raise ValueError("the transform's rotation quaternion is all zeros")
    q = q / largest  # so that neither 1e-200 nor 1e200 under- or overflows in the norm
    x, y, z, w = q / float(np.linalg.norm(q))
    matrix = np.eye(4)
    matrix[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    matrix[:3, 3] = t
    return matrix


def fixed_links(transforms: Iterable[Transform]) -> dict[str, tuple[str, np.ndarray, str]]:
    """The tree of the robot's build: per child frame, its parent, its pose there (4, 4)
    and the topic that gave it, from transforms in bag order (see the module docstring)."""
    static: dict[str, Transform] = {}
    moving: dict[str, Transform | None] = {}  # None: it changed
    for tf in transforms:
        child = bare(tf.child)
        if tf.topic == TF_STATIC_TOPIC:
            static[child] = tf
        elif child not in moving:
            moving[child] = tf
        elif (seen := moving[child]) is not None and seen[1:] != tf[1:]:
            moving[child] = None
    chosen = {child: tf for child, tf in moving.items() if tf is not None} | static
    return {
        child: (bare(tf.parent), transform_matrix(tf.translation, tf.rotation), tf.topic)
        for child, tf in chosen.items()
    }


def disagreements(transforms: Iterable[Transform]) -> dict[str, tuple[Transform, Transform]]:
    """Per child frame given two fixed poses that differ (beyond ``SAME_LINK_TOLERANCE``):
    (the one set aside, the one ``fixed_links`` uses), from transforms in bag order."""
    static: dict[str, Transform] = {}
    unchanging: dict[str, Transform | None] = {}
    found: dict[str, tuple[Transform, Transform]] = {}
    for tf in transforms:
        child = bare(tf.child)
        if tf.topic == TF_STATIC_TOPIC:
            if child in static and not same_link(static[child], tf):
                found[child] = (static[child], tf)
            static[child] = tf
        elif child not in unchanging:
            unchanging[child] = tf
        elif (seen := unchanging[child]) is not None and seen[1:] != tf[1:]:
            unchanging[child] = None  # motion, not a mounting
    for child, kept in unchanging.items():
        if kept is not None and child in static and not same_link(kept, static[child]):
            found.setdefault(child, (kept, static[child]))
    return found


def same_link(a: Transform, b: Transform) -> bool:
    """Whether two transforms give their child the same pose in the same parent."""
    if bare(a.parent) != bare(b.parent):
        return False
    q_a, q_b = np.asarray(a.rotation, float), np.asarray(b.rotation, float)
    q_a, q_b = q_a / np.linalg.norm(q_a), q_b / np.linalg.norm(q_b)
    turned = min(np.abs(q_a - q_b).max(), np.abs(q_a + q_b).max())  # q and −q: one rotation
    moved = np.abs(np.subtract(a.translation, b.translation)).max()
    return bool(moved <= SAME_LINK_TOLERANCE and turned <= SAME_LINK_TOLERANCE)


def loop_above(links: dict[str, tuple[str, np.ndarray, str]], frame: str) -> list[str] | None:
    """The frames of a loop met going up from ``frame`` through ``links`` (each the parent
    of the one before, ending with the first again), or None when the way up ends at a
    root."""
    path = [bare(frame)]
    while path[-1] in links:
        parent = links[path[-1]][0]
        if parent in path:
            return [*path[path.index(parent) :], parent]
        path.append(parent)
    return None


def ancestors(links: dict[str, tuple[str, np.ndarray, str]], frame: str) -> list[str]:
    """``frame`` and the frames above it through ``links``, nearest first."""
    return [ancestor for ancestor, _, _ in _up(links, bare(frame))]


def _up(links: dict[str, tuple[str, np.ndarray, str]], frame: str):
    """From ``frame`` up to the root of its tree: (ancestor, ``frame``'s pose in it (4, 4),
    the topics of the links between), ``frame`` itself first. Stops at a loop."""
    pose = np.eye(4)
    topics: frozenset[str] = frozenset()
    seen: set[str] = set()
    while True:
        yield frame, pose, topics
        seen.add(frame)
        if frame not in links or links[frame][0] in seen:
            return
        parent, link, topic = links[frame]
        frame, pose, topics = parent, link @ pose, topics | {topic}


def root_of(links: dict[str, tuple[str, np.ndarray, str]], frame: str) -> str:
    """The top frame of ``frame``'s tree (``frame`` itself when it has no parent)."""
    return ancestors(links, frame)[-1]


def find_mounting(
    links: dict[str, tuple[str, np.ndarray, str]], robot_frame: str, scanner_frame: str
) -> Mounting | None:
    """The pose of ``scanner_frame`` in ``robot_frame`` through ``links`` (``fixed_links``),
    projected onto the robot's floor plane; None when the two are not in one tree."""
    robot, scanner = bare(robot_frame), bare(scanner_frame)
    above_scanner = {frame: (pose, topics) for frame, pose, topics in _up(links, scanner)}
    for frame, robot_pose, robot_topics in _up(links, robot):
        if frame in above_scanner:
            scanner_pose, scanner_topics = above_scanner[frame]
            matrix = np.linalg.inv(robot_pose) @ scanner_pose
            topics = robot_topics | scanner_topics
            kind = "tf_static" if topics <= {TF_STATIC_TOPIC} else "tf"
            return _projected(matrix, f"{kind}:{robot}->{scanner}")
    return None


def _projected(matrix: np.ndarray, source: str) -> Mounting:
    """A pose (4, 4) projected onto the floor plane (z = 0 of the frame it is in)."""
    rotation = matrix[:3, :3]
    # The heading of the scanner's x axis; for a scanner turned over about that axis, its
    # beams, mirrored, run counter-clockwise from the same heading.
    theta = math.atan2(rotation[1, 0], rotation[0, 0])
    up = float(np.clip(rotation[2, 2], -1.0, 1.0))
    return Mounting(
        x_m=float(matrix[0, 3]),
        y_m=float(matrix[1, 3]),
        theta_rad=float(wrap_angle(theta)),
        tilt_deg=math.degrees(math.acos(abs(up))),
        upside_down=up < 0.0,
        source=source,
    )
