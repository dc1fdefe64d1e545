"""Bounds on the numbers segloc reads, shared by every reader and by the options that take a
pose: beyond them a value is refused with one line rather than carried into arithmetic."""

from __future__ import annotations

MAX_COORDINATE_M = 1e7
"""Largest coordinate magnitude (m); UTM eastings and northings stay below it, and float64
still resolves nanometres there."""

MAX_ABS_ID = 2**63 - 1
"""Largest |pose_id| (and integer estimates column): ids are stored as int64."""

MAX_TILT_DEG = 3.0
"""Largest tilt (degrees) from level of a 3D pose (a scanner's mounting, a localizer's pose)
read as level without a warning. The robot's scanner tilts with it: a scan plane 3° off level
drops 5 cm per metre (from 0.3 m up it meets the floor at 5.7 m) and reads a range 0.14 %
long, about the centimetre a survey is good to at 10 m; more tilted, the floor plan seen is
not the one scanned level, nor the heading seen from above the pose's own."""

MAX_PLANAR_TILT_DEG = 45.0
"""Largest tilt (degrees) from level of a 3D pose read as a floor pose at all: nearer vertical
than level, a scanner does not scan the floor plan and a pose's heading seen from above says
nothing."""
