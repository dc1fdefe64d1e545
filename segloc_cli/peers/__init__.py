"""Other localizers behind the two-stage method's interface, for comparison.

``icp`` registers the scan's points to points sampled along the map's
segments with small_gicp (GICP or point-to-plane ICP); ``correlative``
matches the scan against virtual scans of the map with the Karto scan
matcher, the correlative search that slam_toolbox and OpenKarto use. Both
packages are optional: ``pip install 'segloc[peers]'``.

Each peer is a ``ScanMatcher`` like ``Localizer`` and returns the same
``Estimate``; it uses the scan's points only (``uses_segments`` is False, so
no segments are extracted for it) and needs an initial guess for every scan
(``supports_global`` is False).
"""

from __future__ import annotations

import importlib

import numpy as np

from segloc_cli.config import METHODS
from segloc_cli.errors import SeglocError
from segloc_cli.estimates import STATUS_NO_OVERLAP
from segloc_cli.geometry import Pose2
from segloc_cli.method.confidence import ConfidenceParams, points_status
from segloc_cli.method.localize import NAN_POSE, Estimate
from segloc_cli.method.refine import RefineParams, support
from segloc_cli.method.spatial import NEAR_CELL_M, SegmentGrid

__all__ = ["METHODS", "GuidedMatcher", "judged_estimate", "peer_localizer", "require"]

_PACKAGES = {
    "icp": ("small_gicp", "small-gicp"),
    "correlative": ("karto_scanmatcher", "karto-scanmatcher"),
}


def require(method: str):
    """The module a peer method runs on; a ``SeglocError`` saying how to install it if missing."""
    module, distribution = _PACKAGES[method]
    try:
        return importlib.import_module(module)
    except ImportError:
        raise SeglocError(
            f"--method {method} needs the {distribution} package: pip install 'segloc[peers]'"
        ) from None


def peer_localizer(method: str, segments_world: np.ndarray, **options):
    """The peer localizer for ``method`` ("icp" or "correlative") on a map (M, 4), world frame.

    ``options`` go to the peer's parameters (``IcpParams``, ``CorrelativeParams``).
    """
    if method == "icp":
        from segloc_cli.peers.icp import IcpLocalizer, IcpParams

        return IcpLocalizer(segments_world, IcpParams(**options))
    if method == "correlative":
        from segloc_cli.peers.correlative import CorrelativeLocalizer, CorrelativeParams

        return CorrelativeLocalizer(segments_world, CorrelativeParams(**options))
    raise ValueError(f"unknown peer method {method!r}; expected icp or correlative")


class GuidedMatcher:
    """What the peers share as ``ScanMatcher``s: points only, from an initial guess."""

    segments_world: np.ndarray
    """The map (M, 4), world frame, as each peer's constructor keeps it."""

    uses_segments = False
    supports_global = False
    supports_window = False
    """The correlative matcher bins points by their beam from one origin, ICP weighs them as
    one sensor's: both take each scan alone."""

    def localize_global(self, segments_robot: np.ndarray, points_robot: np.ndarray) -> Estimate:
        """Refused: a peer searches around an initial guess, never the whole map."""
        raise ValueError(f"{type(self).__name__} needs an initial guess for every scan")

    def judged(self, pose: Pose2 | None, points_robot: np.ndarray) -> Estimate:
        """``judged_estimate`` on this matcher's map, through its grid of the map."""
        if getattr(self, "_near_index", None) is None:
            self._near_index = SegmentGrid(self.segments_world, cell_m=NEAR_CELL_M)
        return judged_estimate(pose, points_robot, self.segments_world, self._near_index)


def judged_estimate(
    pose: Pose2 | None,
    points_robot: np.ndarray,
    segments_world: np.ndarray,
    index: SegmentGrid | None = None,
) -> Estimate:
    """A peer's answer as an ``Estimate``, with the inlier share and verdict the two stages get.

    ``pose`` None (the matcher gave up) yields a ``no_overlap`` row. Peers
    report no rival, so the verdict is ``lost`` by the inlier share, else
    ``ambiguous`` where the points cannot fix the position (a corridor), else
    ``ok``. ``index``, a fine grid of the map (``GuidedMatcher.near_index``),
    finds the segments near each point without testing them all.
    """
    if pose is None or not np.isfinite([pose.x, pose.y, pose.theta]).all():
        return Estimate(pose=NAN_POSE, status=STATUS_NO_OVERLAP, n_local_segments=0)
    band = RefineParams().final_gate_m
    ratio, hold = support(points_robot, segments_world, pose, band, index=index)
    status = points_status(ratio, hold, ConfidenceParams())
    return Estimate(pose=pose, status=status, n_local_segments=0, inlier_ratio=ratio)
