"""Bounds on the numbers segloc reads, shared by every reader and by the options that take a
pose: beyond them a value is refused with one line rather than carried into arithmetic."""

from __future__ import annotations

MAX_COORDINATE_M = 1e7
"""Largest coordinate magnitude (m); UTM eastings and northings stay below it, and float64
still resolves nanometres there."""

MAX_ABS_ID = 2**63 - 1
"""Largest |pose_id| (and integer estimates column): ids are stored as int64."""
