"""The one shape every log reader returns: scans, their odometry and the sensor settings.

``read_log`` (segloc's MCAP log), ``read_carmen`` (CARMEN text logs) and
``read_rosbag`` (ROS bags) each return a ``Log``; the importers' logs are
written out as MCAP with ``write_log`` and read back as the same fields.

Frames: each scan's readings are in its scanner's frame; the scanner's pose in the
robot frame (the laser offset) is a sensor setting, ``laser_x_m``, ``laser_y_m`` and
``laser_theta_deg`` with ``laser_offset_source`` saying where it came from, and every
reader hands it to its scans as ``Scan.mount``. The odometry, the survey and every
pose segloc estimates are the robot's. A log without those settings (a CARMEN log,
whose poses are the scanner's; a recording; a log written before they existed) has its
scanner at the robot's origin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from segloc_cli.errors import InputError
from segloc_cli.geometry import Pose2, wrap_angle
from segloc_cli.scan import AT_ROBOT_ORIGIN, Scan

SENSOR_METADATA_NAME = "segloc.sensor"
"""Name of the MCAP metadata record that holds a log's sensor settings."""
LASER_OFFSET_KEYS = ("laser_x_m", "laser_y_m", "laser_theta_deg")
"""Sensor settings holding the scanner's pose in the robot frame: metres, metres, degrees."""
LASER_OFFSET_SOURCE_KEY = "laser_offset_source"
"""Sensor setting saying where the laser offset came from (``tf_static:base_link->laser``,
``--laser-offset``, ``none``)."""
SIMULATED_GUESSES_KEY = "init_errors"
"""The sensor setting ``segloc simulate`` records: its /odom holds initial guesses, not
odometry."""
MAX_LASER_OFFSET_M = 10.0
"""Largest distance (m) of a scanner from the robot's origin along either axis taken as a
mounting; more is a corrupt or mistaken setting."""


def laser_offset_settings(x_m: float, y_m: float, theta_deg: float, source: str) -> dict[str, str]:
    """The sensor settings (str → str) that record the scanner's pose in the robot frame
    (``x_m``, ``y_m`` metres, ``theta_deg`` degrees) and its ``source``; ``laser_offset_of``
    reads them back."""
    values = dict(zip(LASER_OFFSET_KEYS, (x_m, y_m, theta_deg), strict=True))
    return {key: repr(float(v)) for key, v in values.items()} | {LASER_OFFSET_SOURCE_KEY: source}


def laser_offset_of(sensor: dict[str, str], path: Path | str | None = None) -> Pose2:
    """The scanner's pose in the robot frame (metres, radians) recorded in ``sensor``; the
    robot's origin when none of ``LASER_OFFSET_KEYS`` is there.

    Raises ``InputError`` (naming ``path`` and the key) when only some of the keys are
    there, or a value is not a finite number, or a position is beyond
    ``MAX_LASER_OFFSET_M``.
    """
    given = [key for key in LASER_OFFSET_KEYS if key in sensor]
    if not given:
        return AT_ROBOT_ORIGIN
    values = []
    for key in LASER_OFFSET_KEYS:
        if key not in sensor:
            raise InputError(
                f"metadata {SENSOR_METADATA_NAME}: {key} is missing beside {given[0]}", path=path
            )
        text = sensor[key]
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        limit = MAX_LASER_OFFSET_M if key.endswith("_m") else math.inf
        if not (math.isfinite(value) and abs(value) <= limit):
            unit = f"a number of metres within ±{limit:g}" if key.endswith("_m") else "degrees"
            raise InputError(
                f"metadata {SENSOR_METADATA_NAME}: {key} is {text[:40]!r}, expected {unit}",
                path=path,
            )
        values.append(value)
    x_m, y_m, theta_deg = values
    theta_rad = math.radians(theta_deg)
    # Wrapping moves the last bit of a heading already inside: only those outside are.
    inside = -math.pi <= theta_rad < math.pi
    return Pose2(x_m, y_m, theta_rad if inside else float(wrap_angle(theta_rad)))


@dataclass(frozen=True)
class Log:
    """Everything a reader took from a log file.

    ``scans`` (S) in the reader's order (file order for MCAP and CARMEN, stamp
    order for ROS bags), each in its scanner's frame (x forward, angles
    counter-clockwise, radians; ranges in metres) with the scanner's mounting
    (``laser_offset``) as ``Scan.mount`` and ``time_s`` in seconds since the
    epoch of the source's clock. Times that collided in an imported source have
    been made distinct (``segloc_cli.io.times``).

    ``original_times_s`` (S,) seconds: each scan's time as written in its source
    (a CARMEN record's ipc timestamp, a ROS message's ``header.stamp``, the
    publish time an MCAP record kept), equal to ``scan_times_s`` wherever no
    time had to be moved.

    ``odom_times_s`` (K,) seconds and ``odom_poses`` (K, 3) ``x_m, y_m,
    theta_rad`` with headings in [-π, π): the odometry. In an MCAP log, the
    ``/odom`` messages, the robot's poses in the world frame; from CARMEN, the
    odometry fields of each laser record (K = S, at the scans' times) in the
    odometry frame, moved to the scanner by the laser offset (CARMEN's poses are
    the scanner's: its scans are mounted at the robot's origin); from a ROS bag,
    the robot's pose (the odometry's child frame) in the odometry frame
    interpolated to the scans inside the odometry's time span, at their times.

    ``sensor``: the sensor settings as str → str (``range_max_m`` in metres,
    ``readings``, ``fov_deg``, the laser offset, …), as stored in the MCAP log's
    ``segloc.sensor`` metadata record; empty when an MCAP log has none.

    ``laser_poses`` (S, 3) ``x_m, y_m, theta_rad``: the pose each CARMEN laser
    record carries, in the log's world frame (in a SLAM-corrected log, the
    corrected trajectory), headings in [-π, π); None for other sources.

    ``finished``: whether the file is whole; False only for an MCAP log without
    its footer or cut short by a damaged record.

    ``message_counts``: messages read per MCAP channel topic, including topics
    segloc does not use and skipped messages; empty for imported sources.

    ``warnings``: human-readable notes on what was skipped, damaged or
    adjusted, one line each.

    ``numbers`` (S,) int: each scan's own number in its source, from 1 (its place among
    the source's scans, those that could not be read included, or the sequence number
    the source gave it), so that a scan keeps its number when one before it is skipped;
    None: the scans are numbered 1 to S in order (``scan_numbers``).
    """

    scans: list[Scan]
    original_times_s: np.ndarray
    odom_times_s: np.ndarray
    odom_poses: np.ndarray
    sensor: dict[str, str]
    laser_poses: np.ndarray | None = None
    finished: bool = True
    message_counts: dict[str, int] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    numbers: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.numbers is not None and np.shape(self.numbers) != (len(self.scans),):
            raise ValueError(f"{np.size(self.numbers)} scan numbers for {len(self.scans)} scans")

    @property
    def scan_numbers(self) -> np.ndarray:
        """Each scan's number (S,) int64 in its source, from 1: the pose id of its row."""
        if self.numbers is None:
            return np.arange(1, len(self.scans) + 1, dtype=np.int64)
        return np.asarray(self.numbers, dtype=np.int64)

    @property
    def scan_times_s(self) -> np.ndarray:
        """Acquisition times (S,) of the scans, seconds."""
        return np.array([scan.time_s for scan in self.scans], dtype=float)

    @property
    def has_odometry(self) -> bool:
        """Whether ``/odom`` is odometry, the robot's motion from scan to scan: the log has
        some, and it is not what ``segloc simulate`` writes there without ``--odometry``, an
        initial guess per scan drawn apart from the others (its sensor settings record
        ``init_errors``)."""
        return self.odom_times_s.size > 0 and SIMULATED_GUESSES_KEY not in self.sensor

    @property
    def laser_offset(self) -> Pose2:
        """The scanner's pose in the robot frame (metres, radians) from ``sensor``; the
        robot's origin when the log records none (``laser_offset_of``)."""
        return laser_offset_of(self.sensor)

    @property
    def laser_offset_source(self) -> str:
        """Where the laser offset came from, as recorded; ``none`` when not recorded."""
        return self.sensor.get(LASER_OFFSET_SOURCE_KEY, "none")
