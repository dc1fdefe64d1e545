"""ICP baseline: the scan's points registered to points sampled along the map (small_gicp).

small_gicp works in 3D. A 2D scan and map lie in one plane, where every
point's neighbourhood is a line and neither a normal nor a plane-shaped
covariance is defined, so both clouds are stacked in a few thin layers
along z: each wall becomes a vertical strip whose normal lies in the
plane. The answer is the registration's x, y and yaw; its z, roll and
pitch stay near zero, as nothing pulls them away.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from segloc_cli.config import ICP_VARIANTS
from segloc_cli.geometry import Pose2, sample_segments
from segloc_cli.method.localize import Estimate
from segloc_cli.peers import GuidedMatcher, require

VARIANTS = dict(zip(ICP_VARIANTS, ("GICP", "PLANE_ICP"), strict=True))
"""``IcpParams.variant`` (``config.ICP_VARIANTS``) → small_gicp's registration type."""


@dataclass(frozen=True)
class IcpParams:
    """How the map is sampled and the registration run (metres)."""

    variant: str = "gicp"
    """``gicp`` (generalized ICP, plane-to-plane) or ``plane`` (point-to-plane ICP)."""
    spacing_m: float = 0.025
    """Spacing of the points sampled along map segments, and of the layers along z."""
    max_correspondence_m: float = 1.0
    """Pairs farther apart are ignored; generous, so starts a metre off still pull in."""
    max_iterations: int = 100
    neighbours: int = 10
    """Points used to estimate each point's covariance or normal."""
    layers: int = 3

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise ValueError(f"variant must be one of {sorted(VARIANTS)}, got {self.variant!r}")


class IcpLocalizer(GuidedMatcher):
    """Registers scans to one map (M, 4), world frame, from an initial guess."""

    def __init__(self, segments_world: np.ndarray, params: IcpParams | None = None):
        self._gicp = require("icp")
        self.params = params or IcpParams()
        self.segments_world = np.asarray(segments_world, dtype=float)
        map_points = sample_segments(self.segments_world, self.params.spacing_m)
        self._target, self._tree = self._preprocess(map_points)

    def _preprocess(self, points_2d: np.ndarray):
        p = self.params
        offsets = (np.arange(p.layers) - (p.layers - 1) / 2.0) * p.spacing_m
        layered = np.concatenate(
            [np.column_stack([points_2d, np.full(points_2d.shape[0], z)]) for z in offsets]
        )
        return self._gicp.preprocess_points(
            layered, downsampling_resolution=p.spacing_m / 2.0, num_neighbors=p.neighbours
        )

    def localize(
        self, segments_robot: np.ndarray, initial: Pose2, points_robot: np.ndarray
    ) -> Estimate:
        """Register ``points_robot`` (P, 2), robot frame, starting at ``initial`` (world frame).

        ``segments_robot`` is not used.
        """
        p = self.params
        if points_robot.shape[0] < p.neighbours:
            return self.judged(None, points_robot)
        source, _ = self._preprocess(points_robot)
        start = np.eye(4)
        start[:2, :2] = [
            [np.cos(initial.theta), -np.sin(initial.theta)],
            [np.sin(initial.theta), np.cos(initial.theta)],
        ]
        start[:2, 3] = initial.x, initial.y
        result = self._gicp.align(
            self._target,
            source,
            self._tree,
            init_T_target_source=start,
            registration_type=VARIANTS[p.variant],
            max_correspondence_distance=p.max_correspondence_m,
            max_iterations=p.max_iterations,
        )
        t = result.T_target_source
        pose = Pose2(float(t[0, 3]), float(t[1, 3]), float(np.arctan2(t[1, 0], t[0, 0])))
        return self.judged(pose, points_robot)
