"""One laser scan: readings in the scanner's own frame (x forward, angles counter-clockwise)
and the scanner's mounting on the robot, which takes them into the robot frame.

Also the bounds every reader of scans applies, whatever the file format: a
reading beyond ``MAX_RANGE_M`` is no return, a scan with more than
``MAX_READINGS`` readings or a degenerate fan (``fan_defect``) is not a scan.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from segloc_cli.geometry import Pose2, transform_points

MAX_RANGE_M = 1000.0
"""Largest range (m) taken as a return; no planar laser measures a kilometre, so a larger
reading is corrupt data and counts as no return, whatever the sensor's ``range_max_m``."""

MAX_READINGS = 100_000
"""Most readings in one scan; readers skip larger scans (a 0.01° fan over 360° has 36,000)."""

FAN_TOLERANCE_RAD = 1e-3
"""Slack (rad) on the widest fan, 2π, for rounding in files that store a full turn."""

MAX_ABS_ANGLE_RAD = 4.0 * math.pi
"""Largest beam angle magnitude (rad): a fan starting within one turn of 0 and spanning at
most a turn stays inside ±4π, so larger angles are corrupt or not in radians."""

AT_ROBOT_ORIGIN = Pose2(0.0, 0.0, 0.0)
"""The mounting of a scanner whose frame is the robot's (the default)."""


@dataclass(frozen=True)
class Scan:
    """A range scan.

    ``angles_rad`` (N,) are beam angles in radians in the scanner's frame, all
    finite (``ValueError`` otherwise); ``ranges_m`` (N,) the measured ranges in
    metres; a reading is invalid when it is <= 0, non-finite, or at/above
    ``range_max_m`` or ``MAX_RANGE_M`` (no return). ``time_s`` is the
    acquisition time in seconds (log time base).

    ``mount``: the scanner's pose in the robot frame (metres, radians; the log's
    laser offset, ``Log.laser_offset``). ``to_robot`` applies it, and it is the one
    place where readings become robot-frame geometry: ``points`` and
    ``extract.extract_segments`` give robot-frame coordinates, so every pose placed
    under them is the robot's. The default is a scanner at the robot's origin.
    """

    time_s: float
    angles_rad: np.ndarray
    ranges_m: np.ndarray
    range_max_m: float = float("inf")
    intensities: np.ndarray = field(default_factory=lambda: np.zeros(0))
    mount: Pose2 = AT_ROBOT_ORIGIN

    def __post_init__(self) -> None:
        if np.shape(self.angles_rad) != np.shape(self.ranges_m):
            raise ValueError(
                f"scan at t={self.time_s}: {np.size(self.angles_rad)} angles "
                f"but {np.size(self.ranges_m)} ranges"
            )
        if not np.all(np.isfinite(np.asarray(self.angles_rad, dtype=float))):
            raise ValueError(f"scan at t={self.time_s}: beam angles must be finite")

    def __len__(self) -> int:
        return int(np.size(self.ranges_m))

    @property
    def valid(self) -> np.ndarray:
        """Boolean mask (N,) of valid readings."""
        r = np.asarray(self.ranges_m, dtype=float)
        with np.errstate(invalid="ignore"):
            return np.isfinite(r) & (r > 0.0) & (r < min(self.range_max_m, MAX_RANGE_M))

    def points(self) -> np.ndarray:
        """Valid readings as (K, 2) points in metres, robot frame, in beam order."""
        ok = self.valid
        r = np.asarray(self.ranges_m, dtype=float)[ok]
        a = np.asarray(self.angles_rad, dtype=float)[ok]
        return self.to_robot(np.column_stack([r * np.cos(a), r * np.sin(a)]))

    def to_robot(self, coords_scanner: np.ndarray) -> np.ndarray:
        """Coordinates in the scanner's frame → the robot frame, by ``mount``.

        ``coords_scanner``: metres, x y pairs along the last axis, such as points (K, 2)
        or segments (M, 4) ``x1 y1 x2 y2``; the result has the same shape. A scanner at
        the robot's origin returns its coordinates unchanged.
        """
        coords = np.asarray(coords_scanner, dtype=float)
        if self.mount == AT_ROBOT_ORIGIN:
            return coords
        return transform_points(coords.reshape(-1, 2), self.mount).reshape(coords.shape)


def evenly_spaced_angles(n: int, start_rad: float, end_rad: float) -> np.ndarray:
    """``n`` angles from ``start_rad`` to ``end_rad`` inclusive (as foxglove.LaserScan)."""
    if n == 1:
        return np.array([start_rad], dtype=float)
    return np.linspace(start_rad, end_rad, n)


def fan_defect(n: int, start_rad: float, end_rad: float) -> str | None:
    """Why ``n`` beams evenly spaced from ``start_rad`` to ``end_rad`` (inclusive) are not a
    usable scan, or ``None`` when they are.

    Refused: non-finite angles, angles beyond ±``MAX_ABS_ANGLE_RAD``, a fan whose angles
    decrease (``end_rad < start_rad``: segloc's beams turn counter-clockwise, and a fan
    given the other way round puts every wall on the wrong side), a degenerate fan (more
    than one beam and ``start_rad == end_rad``: every beam on one ray), and a fan wider
    than a full turn (2π + ``FAN_TOLERANCE_RAD``), whose beams would overlap.
    """
    if not (math.isfinite(start_rad) and math.isfinite(end_rad)):
        return f"non-finite fan angles ({start_rad!r} to {end_rad!r} rad)"
    if max(abs(start_rad), abs(end_rad)) > MAX_ABS_ANGLE_RAD:
        return (
            f"fan angles {start_rad:.6g} to {end_rad:.6g} rad lie beyond ±4π "
            "(corrupt, or not radians)"
        )
    if end_rad < start_rad:
        return f"fan angles decrease, from {start_rad:.6g} to {end_rad:.6g} rad"
    if n > 1 and start_rad == end_rad:
        return f"degenerate fan: all {n} beams at {start_rad:.6g} rad"
    if end_rad - start_rad > 2.0 * math.pi + FAN_TOLERANCE_RAD:
        return f"fan spans {end_rad - start_rad:.6g} rad, more than a full turn"
    return None
