"""The one shape every log reader returns: scans, their odometry and the sensor settings.

``read_log`` (segloc's MCAP log), ``read_carmen`` (CARMEN text logs) and
``read_rosbag`` (ROS bags) each return a ``Log``; the importers' logs are
written out as MCAP with ``write_log`` and read back as the same fields.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from segloc_cli.scan import Scan


@dataclass(frozen=True)
class Log:
    """Everything a reader took from a log file.

    ``scans`` (S) in the reader's order (file order for MCAP and CARMEN, stamp
    order for ROS bags), each in its scanner's frame (x forward, angles
    counter-clockwise, radians; ranges in metres) with ``time_s`` in seconds
    since the epoch of the source's clock. Times that collided in an imported
    source have been made distinct (``segloc_cli.io.times``).

    ``original_times_s`` (S,) seconds: each scan's time as written in its source
    (a CARMEN record's ipc timestamp, a ROS message's ``header.stamp``, the
    publish time an MCAP record kept), equal to ``scan_times_s`` wherever no
    time had to be moved.

    ``odom_times_s`` (K,) seconds and ``odom_poses`` (K, 3) ``x_m, y_m,
    theta_rad`` with headings in [-π, π): the odometry. In an MCAP log, the
    ``/odom`` messages in the world frame; from CARMEN, the odometry fields of
    each laser record (K = S, at the scans' times) in the odometry frame, moved
    to the scanner by the laser offset; from a ROS bag, the odometry frame
    interpolated to the scans inside the odometry's time span, at their times.

    ``sensor``: the sensor settings as str → str (``range_max_m`` in metres,
    ``readings``, ``fov_deg``, …), as stored in the MCAP log's ``segloc.sensor``
    metadata record; empty when an MCAP log has none.

    ``laser_poses`` (S, 3) ``x_m, y_m, theta_rad``: the pose each CARMEN laser
    record carries, in the log's world frame (in a SLAM-corrected log, the
    corrected trajectory), headings in [-π, π); None for other sources.

    ``finished``: whether the file is whole; False only for an MCAP log without
    its footer or cut short by a damaged record.

    ``message_counts``: messages read per MCAP channel topic, including topics
    segloc does not use and skipped messages; empty for imported sources.

    ``warnings``: human-readable notes on what was skipped, damaged or
    adjusted, one line each.
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

    @property
    def scan_times_s(self) -> np.ndarray:
        """Acquisition times (S,) of the scans, seconds."""
        return np.array([scan.time_s for scan in self.scans], dtype=float)
