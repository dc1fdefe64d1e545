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

from segloc_cli.config import ConfidenceParams

STATUS_OK = "ok"
STATUS_AMBIGUOUS = "ambiguous"
"""A distinct pose explains the scan nearly as well as the answer."""
STATUS_LOST = "lost"
"""Too little of the scan lies on the map at the answer."""


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
