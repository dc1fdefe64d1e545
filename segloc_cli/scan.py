"""One laser scan in the scanner's own frame (x forward, angles counter-clockwise)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Scan:
    """A range scan.

    ``angles_rad`` (N,) are beam angles in the robot frame, ``ranges_m`` (N,)
    the measured ranges in metres; a reading is invalid when it is <= 0,
    non-finite, or at/above ``range_max_m`` (no return). ``time_s`` is the
    acquisition time in seconds (log time base).
    """

    time_s: float
    angles_rad: np.ndarray
    ranges_m: np.ndarray
    range_max_m: float = float("inf")
    intensities: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        if np.shape(self.angles_rad) != np.shape(self.ranges_m):
            raise ValueError(
                f"scan at t={self.time_s}: {np.size(self.angles_rad)} angles "
                f"but {np.size(self.ranges_m)} ranges"
            )

    def __len__(self) -> int:
        return int(np.size(self.ranges_m))

    @property
    def valid(self) -> np.ndarray:
        """Boolean mask (N,) of valid readings."""
        r = np.asarray(self.ranges_m, dtype=float)
        with np.errstate(invalid="ignore"):
            return np.isfinite(r) & (r > 0.0) & (r < self.range_max_m)

    def points(self) -> np.ndarray:
        """Valid readings as (K, 2) points in metres, robot frame, in beam order."""
        ok = self.valid
        r = np.asarray(self.ranges_m, dtype=float)[ok]
        a = np.asarray(self.angles_rad, dtype=float)[ok]
        return np.column_stack([r * np.cos(a), r * np.sin(a)])


def evenly_spaced_angles(n: int, start_rad: float, end_rad: float) -> np.ndarray:
    """``n`` angles from ``start_rad`` to ``end_rad`` inclusive (as foxglove.LaserScan)."""
    if n == 1:
        return np.array([start_rad], dtype=float)
    return np.linspace(start_rad, end_rad, n)
