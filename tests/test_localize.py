"""The two stages together (``Localizer``) on hand-made maps."""

from __future__ import annotations

import numpy as np
import pytest

from segloc_cli.align import align
from segloc_cli.geometry import Pose2, segment_orientations, wrap_angle
from segloc_cli.localize import STATUS_OK, STATUS_TOO_FEW_SEGMENTS, Localizer


def _pieces(x1, y1, x2, y2, n):
    """A wall stored as n equal pieces, as built maps often hold it."""
    t = np.linspace(0.0, 1.0, n + 1)
    xs, ys = x1 + t * (x2 - x1), y1 + t * (y2 - y1)
    return np.column_stack([xs[:-1], ys[:-1], xs[1:], ys[1:]])


def _stroke(x, y, length, angle_deg):
    a = np.deg2rad(angle_deg)
    return [x, y, x + length * np.cos(a), y + length * np.sin(a)]


# The scan sees a 3 m wall along x and two 2 m walls along y (robot at the origin, heading
# 0). The map holds those walls in 1 m pieces, plus, 100 m away, clutter at 10° and 100°
# whose lengths (3 m and 2 m) match the scan's walls exactly.
LOCAL = np.array([[1.0, -1.0, 4.0, -1.0], [2.0, 0.0, 2.0, 2.0], [-1.0, 1.0, -1.0, 3.0]])
NEAR = np.vstack(
    [
        _pieces(1.0, -1.0, 4.0, -1.0, 3),
        _pieces(2.0, 0.0, 2.0, 2.0, 2),
        _pieces(-1.0, 1.0, -1.0, 3.0, 2),
    ]
)
FAR = np.array(
    [_stroke(100.0 + 5 * k, 0.0, 3.0, 10.0) for k in range(3)]
    + [_stroke(100.0 + 5 * k, 10.0, 2.0, 100.0) for k in range(3)]
)
MAP = np.vstack([NEAR, FAR])


def test_distant_segments_cannot_outvote_the_walls_in_reach():
    localizer = Localizer(MAP)
    guess = Pose2(0.3, -0.2, np.deg2rad(4.0))
    # With every map segment voting, the product vote is 3·3 + 2·2 + 2·2 = 17 at 10°, where
    # the clutter lines up, against 3·1 + 2·1 + 2·1 = 7 at the true 0° (walls in 1 m pieces).
    everything = align(localizer.rtable, LOCAL, prior_rad=guess.theta, window_deg=20.0)
    assert np.rad2deg(everything.best_rad) == pytest.approx(10.0, abs=1e-9)
    assert everything.peak_votes[0] == pytest.approx(17.0)
    # Only the segments the scan can reach (its 4.2 m radius plus the search's 2·√2·1.5 m)
    # take part in the localizer's vote: the walls win.
    est = localizer.localize(LOCAL, guess)
    assert est.status == STATUS_OK
    assert abs(np.rad2deg(wrap_angle(est.align_theta_rad))) <= 0.5


def test_clutter_orientations_are_what_the_example_says():
    np.testing.assert_allclose(np.rad2deg(segment_orientations(FAR)), [10] * 3 + [100] * 3)


def test_too_few_local_segments_get_a_status_not_a_pose():
    est = Localizer(MAP).localize(LOCAL[:1], Pose2(0.0, 0.0, 0.0))
    assert est.status == STATUS_TOO_FEW_SEGMENTS
    assert np.isnan(est.pose.x) and est.n_local_segments == 1
