"""Planar geometry shared by every module.

Conventions, used everywhere:

- A pose is ``Pose2(x, y, theta)``: metres and radians, the robot frame
  expressed in the world frame (a scanner's mounting, ``Scan.mount``, is its
  frame expressed in the robot frame). Arrays of poses are (N, 3).
- A segment map is an (M, 4) float64 array of endpoints ``x1 y1 x2 y2`` in
  metres. Which frame it is in is said by the name holding it
  (``segments_robot``, ``segments_world``).
- Angles are radians in code; degrees only at the edges, named ``*_deg``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TWO_PI = 2.0 * np.pi


def wrap_angle(angle_rad):
    """Wrap angles (radians, scalar or array) into [-pi, pi).

    Up to rounding: the one float just below -pi comes out as pi. Compiled code
    uses the twin ``kernels.wrap``.
    """
    return (np.asarray(angle_rad) + np.pi) % TWO_PI - np.pi


def circular_mean(angles_rad: np.ndarray, weights: np.ndarray | None = None) -> float:
    """Weighted mean of angles on the circle (radians in, radians in [-pi, pi) out)."""
    angles_rad = np.asarray(angles_rad, dtype=float)
    w = np.ones_like(angles_rad) if weights is None else np.asarray(weights, dtype=float)
    mean = np.arctan2(np.sum(w * np.sin(angles_rad)), np.sum(w * np.cos(angles_rad)))
    return float(wrap_angle(mean))  # atan2 may return +π


def heading_to_quaternion(theta_rad) -> np.ndarray:
    """Headings (N,) radians → unit quaternions (N, 4) ``qx qy qz qw`` about +z."""
    half = 0.5 * np.asarray(theta_rad, dtype=float)
    zeros = np.zeros_like(half)
    return np.stack([zeros, zeros, np.sin(half), np.cos(half)], axis=-1)


def quaternion_to_heading(qx, qy, qz, qw) -> np.ndarray:
    """Yaw (radians, [-pi, pi]) of quaternions given by components (any shape).

    Uses the form that does not need the quaternion to be normalised.
    """
    qx, qy, qz, qw = (np.asarray(q, dtype=float) for q in (qx, qy, qz, qw))
    return np.arctan2(2.0 * (qw * qz + qx * qy), qw * qw + qx * qx - qy * qy - qz * qz)


@dataclass(frozen=True)
class Pose2:
    """An SE(2) pose: position in metres, heading in radians, world frame."""

    x: float
    y: float
    theta: float

    @classmethod
    def from_deg(cls, x: float, y: float, theta_deg: float) -> Pose2:
        return cls(float(x), float(y), float(np.deg2rad(theta_deg)))

    @property
    def theta_deg(self) -> float:
        return float(np.rad2deg(self.theta))

    def as_array(self) -> np.ndarray:
        return np.array([self.x, self.y, self.theta])

    def compose(self, other: Pose2) -> Pose2:
        """``self ⊕ other``: ``other`` is expressed in the frame of ``self``."""
        c, s = np.cos(self.theta), np.sin(self.theta)
        return Pose2(
            self.x + c * other.x - s * other.y,
            self.y + s * other.x + c * other.y,
            float(wrap_angle(self.theta + other.theta)),
        )

    def inverse(self) -> Pose2:
        c, s = np.cos(self.theta), np.sin(self.theta)
        return Pose2(
            -c * self.x - s * self.y, s * self.x - c * self.y, float(wrap_angle(-self.theta))
        )


def relative_motion(from_poses: np.ndarray, to_poses: np.ndarray) -> np.ndarray:
    """``from⁻¹ ⊕ to`` row by row: poses (K, 3) ``x_m, y_m, theta_rad`` in one frame →
    (K, 3) motions ``dx_m, dy_m, dtheta_rad`` expressed in the frame of ``from``,
    dtheta wrapped to [-pi, pi)."""
    from_poses = np.asarray(from_poses, dtype=float).reshape(-1, 3)
    to_poses = np.asarray(to_poses, dtype=float).reshape(-1, 3)
    c, s = np.cos(from_poses[:, 2]), np.sin(from_poses[:, 2])
    dx = to_poses[:, 0] - from_poses[:, 0]
    dy = to_poses[:, 1] - from_poses[:, 1]
    return np.column_stack(
        [c * dx + s * dy, -s * dx + c * dy, wrap_angle(to_poses[:, 2] - from_poses[:, 2])]
    )


def chained_motions(start: np.ndarray, motions: np.ndarray) -> np.ndarray:
    """The poses (K + 1, 3) ``x_m, y_m, theta_rad`` from ``start`` (3,) on, each reached
    from the one before by the next of ``motions`` (K, 3: ``dx_m, dy_m, dtheta_rad`` in the
    frame of the pose before, as ``relative_motion`` gives them), headings wrapped to
    [-pi, pi)."""
    start = np.asarray(start, dtype=float).reshape(3)
    motions = np.asarray(motions, dtype=float).reshape(-1, 3)
    headings = start[2] + np.concatenate([[0.0], np.cumsum(motions[:, 2])])
    c, s = np.cos(headings[:-1]), np.sin(headings[:-1])
    steps = np.column_stack(
        [c * motions[:, 0] - s * motions[:, 1], s * motions[:, 0] + c * motions[:, 1]]
    )
    xy = start[:2] + np.vstack([[0.0, 0.0], np.cumsum(steps, axis=0)])
    return np.column_stack([xy, wrap_angle(headings)])


def rotation(theta_rad: float) -> np.ndarray:
    """2×2 rotation matrix."""
    c, s = np.cos(theta_rad), np.sin(theta_rad)
    return np.array([[c, -s], [s, c]])


def transform_points(points: np.ndarray, pose: Pose2) -> np.ndarray:
    """Points (N, 2) in the frame of ``pose`` → the frame ``pose`` is expressed in."""
    return np.asarray(points, dtype=float) @ rotation(pose.theta).T + np.array([pose.x, pose.y])


def transform_segments(segments: np.ndarray, pose: Pose2) -> np.ndarray:
    """Segments (M, 4) in the frame of ``pose`` → the frame ``pose`` is expressed in."""
    segments = np.asarray(segments, dtype=float).reshape(-1, 4)
    ends = transform_points(segments.reshape(-1, 2), pose)
    return ends.reshape(-1, 4)


def segment_lengths(segments: np.ndarray) -> np.ndarray:
    """Lengths (M,) in metres of segments (M, 4)."""
    segments = np.asarray(segments, dtype=float).reshape(-1, 4)
    return np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1])


def segment_orientations(segments: np.ndarray) -> np.ndarray:
    """Undirected orientations (M,) of segments (M, 4), radians in [0, pi)."""
    segments = np.asarray(segments, dtype=float).reshape(-1, 4)
    return np.arctan2(segments[:, 3] - segments[:, 1], segments[:, 2] - segments[:, 0]) % np.pi


def as_segments(array_like, what: str = "segments") -> np.ndarray:
    """Validate and convert to an (M, 4) float64 array of finite endpoints."""
    segments = np.asarray(array_like, dtype=float)
    if segments.size == 0:
        return np.zeros((0, 4))
    if segments.ndim != 2 or segments.shape[1] != 4:
        raise ValueError(
            f"{what} must be an (M, 4) array of x1 y1 x2 y2, got shape {segments.shape}"
        )
    if not np.all(np.isfinite(segments)):
        raise ValueError(f"{what} contain non-finite coordinates")
    return segments


def point_segment_distances(points: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Distances (P, M) in metres from points (P, 2) to segments (M, 4).

    Compiled code measures one pair with ``kernels.point_segment_distance``.
    """
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    segments = as_segments(segments)
    a = segments[None, :, 0:2]
    e = (segments[:, 2:4] - segments[:, 0:2])[None, :, :]
    w = points[:, None, :] - a
    length2 = np.sum(e * e, axis=2)
    u = np.clip(np.sum(w * e, axis=2) / np.where(length2 > 0.0, length2, 1.0), 0.0, 1.0)
    return np.hypot(*np.moveaxis(w - u[:, :, None] * e, 2, 0))


def sample_segments(segments: np.ndarray, spacing_m: float) -> np.ndarray:
    """Points (P, 2) along segments (M, 4), both ends included, at most ``spacing_m`` apart.

    Each segment gets ``ceil(length / spacing) + 1`` evenly spaced points, so
    short segments keep their two ends and no gap exceeds the spacing.
    """
    if not spacing_m > 0.0:
        raise ValueError(f"spacing_m must be > 0, got {spacing_m}")
    segments = as_segments(segments)
    counts = np.ceil(segment_lengths(segments) / spacing_m).astype(np.int64) + 1
    owner = np.repeat(np.arange(segments.shape[0]), counts)
    first = np.cumsum(counts) - counts
    t = (np.arange(owner.size) - first[owner]) / np.maximum(counts[owner] - 1, 1)
    starts, ends = segments[owner, 0:2], segments[owner, 2:4]
    return starts + t[:, None] * (ends - starts)
