"""How far to trust an estimate: ``ok``, ``ambiguous`` or ``lost``.

Three numbers decide. The share of the scan's points that lie on the map at
the answer (its inlier ratio) says whether the scan was explained at all; a
wrong pose can still explain much of a scan, so the margin over the best
distinct alternative says whether anything else explains it about as well
(a 180° view down a featureless corridor fits many places along it); and
since a search may not reach the alternatives, how firmly the points on the
map fix the position along their weakest direction says whether the scan
could tell such places apart at all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

MIN_HOLD_POINTS = 3.0
"""Fewest points' worth that must pin the position along its weakest direction: fewer, and
the position along a corridor or a lone wall rests on one or two readings, or on none."""

STATUS_OK = "ok"
STATUS_AMBIGUOUS = "ambiguous"
"""A distinct pose explains the scan nearly as well as the answer."""
STATUS_LOST = "lost"
"""Too little of the scan lies on the map at the answer."""


@dataclass(frozen=True)
class ConfidenceParams:
    """Thresholds on inlier ratios (shares of the scan's points, 0–1)."""

    min_inlier_ratio: float = 0.5
    """Below this share of points on the map the answer is ``lost``."""
    min_margin: float = 0.1
    """The answer's share must beat the best distinct alternative's by this, else ``ambiguous``."""
    min_hold_points: float = MIN_HOLD_POINTS
    """The points on the map must fix the position in every direction by this many points'
    worth (``refine.support``), else ``ambiguous``."""


def judge(
    inlier_ratio: float,
    runner_up_ratio: float,
    params: ConfidenceParams,
    hold_points: float = math.inf,
) -> str:
    """Status of an answer from its inlier share, its best distinct alternative's (0 if none)
    and how firmly its points fix the position along their weakest direction."""
    if not inlier_ratio >= params.min_inlier_ratio:
        return STATUS_LOST
    if inlier_ratio - runner_up_ratio < params.min_margin or hold_points < params.min_hold_points:
        return STATUS_AMBIGUOUS
    return STATUS_OK
