"""Correlative baseline: the Karto scan matcher against virtual scans of the map.

Karto matches a scan to other scans: it rasterises their points into a
smeared occupancy grid and searches a window of poses around the guess,
coarse then fine, for the one that puts most of the scan's points on
occupied cells. Here the other scans are rendered from the segment map, a
full circle of beams from the guessed position and from four positions a
set distance from it (so walls hidden from the guess, but seen from the
true pose, are in the grid too). The scan itself is re-binned onto a
regular fan of beams, which is the form Karto takes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from segloc_cli.geometry import Pose2, point_segment_distances
from segloc_cli.method.localize import Estimate
from segloc_cli.peers import GuidedMatcher, require
from segloc_cli.sim import cast_rays

NO_RETURN_M = 1000.0
"""Range written for beams that hit nothing; beyond ``range_max_m``, so Karto drops it."""


@dataclass(frozen=True)
class CorrelativeParams:
    """The search window and raster (metres, degrees)."""

    search_m: float = 4.2
    """Side of the square of positions searched around the guess (±2.1 m)."""
    resolution_m: float = 0.02
    """Grid cell and position step of the fine search."""
    smear_m: float = 0.04
    """Spread of each map point over the grid (Karto's smear deviation)."""
    window_deg: float = 20.0
    """Headings searched: ± this around the guess..."""
    coarse_step_deg: float = 2.0
    """...every this many degrees, then refined..."""
    fine_step_deg: float = 0.2
    """...at this step around the coarse best."""
    beam_step_deg: float = 0.5
    """Angular spacing of the virtual scans and of the re-binned scan."""
    view_offset_m: float = 1.0
    """Distance from the guess of the four extra virtual-scan positions."""
    range_max_m: float = 30.0
    """Longest virtual beam."""

    def __post_init__(self) -> None:
        cells = self.search_m / self.resolution_m
        if not np.isclose(cells, round(cells)):
            # Karto indexes its search window out of bounds otherwise.
            raise ValueError(
                f"search_m ({self.search_m}) must be a whole number of resolution_m "
                f"({self.resolution_m})"
            )


class CorrelativeLocalizer(GuidedMatcher):
    """Correlative search for scans on one map (M, 4), world frame, around an initial guess."""

    def __init__(self, segments_world: np.ndarray, params: CorrelativeParams | None = None):
        self._karto = require("correlative")
        self.params = params or CorrelativeParams()
        self.segments_world = np.asarray(segments_world, dtype=float)
        p = self.params
        config = self._karto.ScanMatcherConfig()
        config.search_size = p.search_m
        config.resolution = p.resolution_m
        config.smear_deviation = p.smear_m
        config.coarse_search_angle_offset = np.deg2rad(p.window_deg)
        config.coarse_angle_resolution = np.deg2rad(p.coarse_step_deg)
        config.fine_search_angle_resolution = np.deg2rad(p.fine_step_deg)
        config.range_threshold = p.range_max_m
        self._config = config
        step = np.deg2rad(p.beam_step_deg)
        self._beams = round(2.0 * np.pi / step)
        self._step = 2.0 * np.pi / self._beams
        self._fan = self._karto.LaserScanConfig(
            -np.pi, np.pi - self._step, self._step, 0.0, p.range_max_m, p.range_max_m, "segloc"
        )

    def _scan(self, ranges_m: np.ndarray, pose: Pose2, number: int):
        at = self._karto.Pose2(pose.x, pose.y, pose.theta)
        return self._karto.LocalizedRangeScan(self._fan, ranges_m.tolist(), at, at, number, 0.0)

    def _virtual_scans(self, guess: Pose2) -> list:
        """Full-circle renderings of the map from the guess and four positions around it."""
        p = self.params
        d = p.view_offset_m
        origins = np.array([[0.0, 0.0], [d, 0.0], [-d, 0.0], [0.0, d], [0.0, -d]])
        origins += [guess.x, guess.y]
        reach = point_segment_distances(origins, self.segments_world).min(axis=0)
        nearby = self.segments_world[reach <= p.range_max_m]
        angles = -np.pi + self._step * np.arange(self._beams)
        views = []
        for k, (x, y) in enumerate(origins):
            ranges = cast_rays(nearby, (x, y), angles)
            ranges = np.where(ranges <= p.range_max_m, ranges, NO_RETURN_M)
            views.append(self._scan(ranges, Pose2(float(x), float(y), 0.0), k))
        return views

    def _binned(self, points_robot: np.ndarray) -> np.ndarray:
        """The points as ranges on the regular fan (nearest point per beam), robot frame."""
        angles = np.arctan2(points_robot[:, 1], points_robot[:, 0])
        beam = np.round((angles + np.pi) / self._step).astype(np.int64) % self._beams
        ranges = np.full(self._beams, NO_RETURN_M)
        np.minimum.at(ranges, beam, np.hypot(points_robot[:, 0], points_robot[:, 1]))
        return ranges

    def localize(
        self, segments_robot: np.ndarray, initial: Pose2, points_robot: np.ndarray
    ) -> Estimate:
        """Search around ``initial`` (world frame) for the pose of ``points_robot`` (P, 2).

        ``segments_robot`` is not used.
        """
        if points_robot.shape[0] == 0:
            return self.judged(None, points_robot)
        matcher = self._karto.Wrapper(self._config)
        views = self._virtual_scans(initial)
        query = self._scan(self._binned(points_robot), initial, len(views))
        try:
            result = matcher.match_scan(query, views, False, True)
        except RuntimeError:
            return self.judged(None, points_robot)
        best = result.best_pose
        pose = Pose2(float(best.x), float(best.y), float(best.yaw))
        return self.judged(pose, points_robot)
