"""Stage 2 (map overlap) on hand-made geometry: Cls/Cgs, candidates, pre-filter, search; and
the kernels' shortcuts against the plain computation they must reproduce to the last bit."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from numba import njit

from segloc_cli.geometry import Pose2, transform_segments, wrap_angle
from segloc_cli.method.extract import extract_segments
from segloc_cli.method.overlap import (
    _pair_overlap,
    _within_reach,
    band_halfwidth,
    candidate_pairs,
    candidate_poses,
    coarse_to_fine,
    overlap_at_poses,
)
from segloc_cli.method.spatial import SegmentGrid
from segloc_cli.sim import SensorModel, random_free_poses, random_world, simulate_scan

SQRT2 = np.sqrt(2.0)
IDENTITY = np.array([[0.0, 0.0, 0.0]])

# The wall of the brief: x = 2 from y = −1 to 1, in front of a scanner at the origin.
WALL = np.array([[2.0, -1.0, 2.0, 1.0]])


def overlap(g, local, pose, band, pairs=None) -> float:
    return float(overlap_at_poses(g, local, np.asarray(pose, dtype=float), band, pairs)[0])


# --- band and candidates ----------------------------------------------------------------------


def test_band_halfwidth_is_half_the_grid_diagonal():
    # δ = √2·η/2: the farthest a point can be from its nearest node of a grid of spacing η.
    assert band_halfwidth(1.5) == pytest.approx(0.75 * SQRT2, abs=1e-15)
    assert band_halfwidth(0.1) == pytest.approx(0.05 * SQRT2, abs=1e-15)
    assert band_halfwidth(2.0) == pytest.approx(SQRT2, abs=1e-15)
    assert band_halfwidth(0.0) == 0.0


def test_candidate_poses_are_the_27_of_the_paper():
    centre = Pose2.from_deg(1.0, 2.0, 179.0)
    cands = candidate_poses(centre, 0.5, np.deg2rad(2.0))
    assert cands.shape == (27, 3)
    # 3×3 positions spaced 0.5 m around (1, 2), each with 177°, 179° and 181° (= −179°).
    expected = np.array(
        [
            [x, y, np.deg2rad(t)]
            for x in (0.5, 1.0, 1.5)
            for y in (1.5, 2.0, 2.5)
            for t in (177.0, 179.0, -179.0)
        ]
    )
    got = cands[np.lexsort((cands[:, 2], cands[:, 1], cands[:, 0]))]
    want = expected[np.lexsort((expected[:, 2], expected[:, 1], expected[:, 0]))]
    np.testing.assert_allclose(got, want, atol=1e-12)
    assert np.all(cands[:, 2] >= -np.pi)
    assert np.all(cands[:, 2] < np.pi)
    # Every candidate exactly once, the centre among them.
    assert np.unique(np.round(cands, 9), axis=0).shape[0] == 27
    assert np.any(np.all(np.isclose(cands, centre.as_array(), atol=1e-12), axis=1))


# --- overlap of one pair, by hand -------------------------------------------------------------


def test_overlap_sector_clipping_exact():
    # Local segment x = 1.9, y ∈ [−2, 2]; G's sector is |y| ≤ x/2 (rays through (2, ±1)),
    # so the piece inside it is y ∈ [−0.95, 0.95]. It is 0.1 from G's line, inside the band
    # 0.2: Cls = 1.9. The rays through (1.9, ±0.95) meet x = 2 at y = ±1: Cgs = 2.0.
    local = np.array([[1.9, -2.0, 1.9, 2.0]])
    assert overlap(WALL, local, IDENTITY, 0.2) == pytest.approx(1.9 + 2.0, abs=1e-12)
    # Reversing either segment changes nothing.
    assert overlap(WALL[:, [2, 3, 0, 1]], local[:, [2, 3, 0, 1]], IDENTITY, 0.2) == (
        pytest.approx(3.9, abs=1e-12)
    )
    # Half of it, y ∈ [0, 2]: clipped to [0, 0.95] → 0.95 + 1.0.
    half = np.array([[1.9, 0.0, 1.9, 2.0]])
    assert overlap(WALL, half, IDENTITY, 0.2) == pytest.approx(0.95 + 1.0, abs=1e-12)


def test_overlap_is_invariant_to_moving_the_whole_scene():
    # Same scene, robot at P: the global wall is moved into the world by P; the local map
    # (robot frame) is unchanged. The overlap at P is the overlap at the identity.
    local = np.array([[1.9, -2.0, 1.9, 2.0]])
    for pose in (Pose2.from_deg(3.0, -1.0, 40.0), Pose2.from_deg(-7.5, 2.25, -135.0)):
        wall_world = transform_segments(WALL, pose)
        assert overlap(wall_world, local, pose.as_array(), 0.2) == pytest.approx(3.9, abs=1e-12)
    # And with the robot turned 90° (facing +y), a wall at y = 2 in the world is the wall at
    # x = 2 of the robot frame: (x, y)_robot → (−y, x)_world.
    wall_world = np.array([[1.0, 2.0, -1.0, 2.0]])
    pose = Pose2.from_deg(0.0, 0.0, 90.0)
    assert overlap(wall_world, local, pose.as_array(), 0.2) == pytest.approx(3.9, abs=1e-12)


def test_overlap_position_convention():
    # Robot at (0.5, 0): the wall x = 2 is 1.5 ahead of it. A local segment at robot x = 1.5,
    # y ∈ [−2, 2], clipped to G's sector |y| ≤ 1.5·(1/1.5) = 1: Cls = 2, on G's line: Cgs = 2.
    local = np.array([[1.5, -2.0, 1.5, 2.0]])
    assert overlap(WALL, local, [0.5, 0.0, 0.0], 0.2) == pytest.approx(4.0, abs=1e-12)
    # Seen from the origin instead the segment is 0.5 from G's line: outside the band.
    assert overlap(WALL, local, IDENTITY, 0.2) == 0.0


def test_overlap_slanted_local_segment_cut_by_the_band():
    # L from (1.5, −0.5) to (2.5, 0.5) lies on y = x − 2; the band |x − 2| ≤ 0.2 keeps
    # (1.8, −0.2)–(2.2, 0.2), inside G's sector: Cls = 0.4·√2.
    # Rays through those ends meet x = 2 at y = −0.2·2/1.8 and y = 0.2·2/2.2:
    # Cgs = 0.4/1.8 + 0.4/2.2.
    local = np.array([[1.5, -0.5, 2.5, 0.5]])
    cls = 0.4 * SQRT2
    cgs = 0.2 * 2 / 1.8 + 0.2 * 2 / 2.2
    assert overlap(WALL, local, IDENTITY, 0.2) == pytest.approx(cls + cgs, abs=1e-12)
    # Band 0.3: (1.7, −0.3)–(2.3, 0.3); Cgs = 0.6/1.7 + 0.6/2.3.
    assert overlap(WALL, local, IDENTITY, 0.3) == pytest.approx(
        0.6 * SQRT2 + 0.6 / 1.7 + 0.6 / 2.3, abs=1e-12
    )


def test_overlap_band_too_narrow_gives_zero():
    local = np.array([[1.9, -2.0, 1.9, 2.0]])  # 0.1 from G's line
    assert overlap(WALL, local, IDENTITY, 0.09) == 0.0
    assert overlap(WALL, local, IDENTITY, 0.11) == pytest.approx(3.9, abs=1e-12)


def test_overlap_local_segment_outside_the_sector_gives_zero():
    # On G's own line, but above the ray through (2, 1).
    assert overlap(WALL, np.array([[2.0, 1.5, 2.0, 3.0]]), IDENTITY, 0.2) == 0.0
    # Beside the sector: at x = 1.9 the sector ends at y = 0.95.
    assert overlap(WALL, np.array([[1.9, 1.0, 1.9, 3.0]]), IDENTITY, 0.2) == 0.0
    # Behind the scanner (the sector is a wedge, not a double cone).
    assert overlap(WALL, np.array([[-2.0, -1.0, -2.0, 1.0]]), IDENTITY, 5.0) == 0.0


def test_overlap_global_segment_on_a_line_through_the_scanner_gives_zero():
    # G on the x axis subtends no sector; a local segment right beside it does not pair.
    g = np.array([[1.0, 0.0, 3.0, 0.0]])
    assert overlap(g, np.array([[1.0, 0.05, 3.0, 0.05]]), IDENTITY, 0.2) == 0.0
    assert overlap(g, np.array([[1.0, 0.0, 3.0, 0.0]]), IDENTITY, 0.2) == 0.0
    # The same on a diagonal ray.
    g = np.array([[1.0, 1.0, 2.0, 2.0]])
    assert overlap(g, np.array([[1.0, 1.01, 2.0, 2.01]]), IDENTITY, 0.2) == 0.0


def test_overlap_sums_over_pairs():
    # G1 = WALL; G2 along y = 3 from x = −1 to 1.
    # L1 = x = 1.9, y ∈ [−2, 2] pairs with G1 only: 3.9 (see above). L2 at y = 3.05,
    # x ∈ [−0.5, 0.5], inside G2's sector (|x| ≤ y/3), 0.05 from its line: Cls = 1; the rays
    # through (±0.5, 3.05) meet y = 3 at x = ±0.5·3/3.05: Cgs = 3/3.05.
    # L1 lies outside G2's sector (its directions are within ±46.5°, G2's from 71.6° to
    # 108.4°) and L2 outside G1's (within ±26.6°).
    g = np.vstack([WALL, [[-1.0, 3.0, 1.0, 3.0]]])
    local = np.array([[1.9, -2.0, 1.9, 2.0], [-0.5, 3.05, 0.5, 3.05]])
    expected = 3.9 + 1.0 + 3.0 / 3.05
    assert overlap(g, local, IDENTITY, 0.2) == pytest.approx(expected, abs=1e-12)
    # Restricted to chosen (global, local) pairs.
    only_first = (np.array([0]), np.array([0]))
    assert overlap(g, local, IDENTITY, 0.2, only_first) == pytest.approx(3.9, abs=1e-12)
    crossed = (np.array([0, 1]), np.array([1, 0]))
    assert overlap(g, local, IDENTITY, 0.2, crossed) == 0.0
    empty = (np.zeros(0, dtype=int), np.zeros(0, dtype=int))
    np.testing.assert_array_equal(overlap_at_poses(g, local, np.zeros((5, 3)), 0.2, empty), 0.0)
    # Many poses at once give the per-pose values.
    poses = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.0, np.pi]])
    got = overlap_at_poses(g, local, poses, 0.2)
    assert got[0] == pytest.approx(expected, abs=1e-12)
    assert got[1] == pytest.approx(overlap(g, local, poses[1], 0.2), abs=1e-12)
    assert got[2] == 0.0  # turned round: both local segments face away from both walls


# --- pair pre-filter --------------------------------------------------------------------------


def _random_case(rng: np.random.Generator, grid: float, scale: float):
    """A global map, a local map partly seen from near ``centre``, a centre and a Δα."""
    m = int(rng.integers(1, 9))
    g = rng.uniform(-scale, scale, (m, 4))
    centre = Pose2(*rng.uniform(-scale / 2, scale / 2, 2), rng.uniform(-np.pi, np.pi))
    n = int(rng.integers(1, 9))
    seen = transform_segments(g, centre.inverse())[rng.integers(0, m, n)]
    seen = seen + rng.normal(0.0, grid, seen.shape)
    other = rng.uniform(-scale, scale, (n, 4))
    local = np.where(rng.random((n, 1)) < 0.6, seen, other)
    return g, local, centre, np.deg2rad(rng.uniform(0.1, 10.0))


@pytest.mark.parametrize("grid", [1.5, 0.4, 0.05])
def test_candidate_pairs_filter_is_exact(grid):
    rng = np.random.default_rng(int(grid * 1000))
    band = band_halfwidth(grid)
    dropped = positive = 0
    for i in range(360):
        scale = (0.5, 2.0, 6.0)[i % 3]  # scanner inside, beside and far from the segments
        g, local, centre, dtheta = _random_case(rng, grid, scale)
        cands = candidate_poses(centre, grid, dtheta)
        pairs = candidate_pairs(g, local, centre, SQRT2 * grid, dtheta, band)
        full = overlap_at_poses(g, local, cands, band)
        filtered = overlap_at_poses(g, local, cands, band, pairs)
        np.testing.assert_allclose(
            filtered, full, rtol=0, atol=1e-9, err_msg=f"case {i}: a dropped pair contributed"
        )
        dropped += g.shape[0] * local.shape[0] - pairs[0].size
        positive += bool(full.max() > 0)
    # Not vacuous: the filter drops pairs, and most cases overlap somewhere.
    assert dropped > 100
    assert positive > 180


# --- coarse-to-fine search --------------------------------------------------------------------

# The paper's schedule (K = 6 halvings, no re-centring) from a 1.5 m grid and 4° heading step.
PAPER_SCHEDULE = {"grid_m": 1.5, "dtheta_deg": 4.0, "iterations": 6, "ratio": 0.9, "recentres": 0}


def tuning(**changes) -> dict:
    """The keywords of ``coarse_to_fine``: the paper's schedule with ``changes``."""
    return PAPER_SCHEDULE | changes


def test_coarse_to_fine_has_no_default_tuning():
    # Its defaults live in LocalizeParams only: a call that leaves one out is an error.
    start = Pose2(0.0, 0.0, 0.0)
    for name in PAPER_SCHEDULE:
        partial = {k: v for k, v in PAPER_SCHEDULE.items() if k != name}
        with pytest.raises(TypeError, match=name):
            coarse_to_fine(WALL, WALL, start, **partial)
    with pytest.raises(TypeError):
        coarse_to_fine(WALL, WALL, start, 1.5, 4.0, 6, 0.9, 0)  # keyword-only


# An L-shaped room (10 × 4 plus 4 × 4) with two boxes.
L_ROOM = np.array(
    [
        [0, 0, 10, 0],
        [10, 0, 10, 4],
        [10, 4, 4, 4],
        [4, 4, 4, 8],
        [4, 8, 0, 8],
        [0, 8, 0, 0],
        [6, 1, 7, 1],
        [7, 1, 7, 1.8],
        [7, 1.8, 6, 1.8],
        [6, 1.8, 6, 1],
        [1, 5, 1.6, 5],
        [1.6, 5, 1.6, 6.2],
        [1.6, 6.2, 1, 6.2],
        [1, 6.2, 1, 5],
    ],
    dtype=float,
)


@pytest.mark.parametrize(
    "true", [Pose2.from_deg(3.0, 2.0, 20.0), Pose2.from_deg(2.0, 5.0, -179.0)], ids=str
)
def test_coarse_to_fine_converges_on_noise_free_geometry(true):
    local = transform_segments(L_ROOM, true.inverse())
    for direction_deg in range(0, 360, 45):
        for dtheta_deg in (-3.0, 3.0):
            d = np.deg2rad(direction_deg)
            start = Pose2(
                true.x + 0.5 * np.cos(d),
                true.y + 0.5 * np.sin(d),
                float(wrap_angle(true.theta + np.deg2rad(dtheta_deg))),
            )
            result = coarse_to_fine(L_ROOM, local, start, **tuning(iterations=10, recentres=40))
            err_m = np.hypot(result.pose.x - true.x, result.pose.y - true.y)
            err_deg = abs(np.rad2deg(wrap_angle(result.pose.theta - true.theta)))
            assert err_m < 0.01, f"start {start}: {err_m:.4f} m off"
            assert err_deg < 0.1, f"start {start}: {err_deg:.3f}° off"


def test_coarse_to_fine_paper_schedule_track():
    true = Pose2.from_deg(3.0, 2.0, 20.0)
    local = transform_segments(L_ROOM, true.inverse())
    start = Pose2.from_deg(3.3, 2.4, 23.0)
    k, grid, dtheta_deg = 6, 1.5, 4.0
    result = coarse_to_fine(
        L_ROOM, local, start, **tuning(grid_m=grid, dtheta_deg=dtheta_deg, iterations=k)
    )
    # The estimate before the first and after each of the K iterations, one overlap each.
    assert result.track.shape == (k + 1, 3)
    assert result.best_overlaps_m.shape == (k,)
    np.testing.assert_array_equal(result.track[0], start.as_array())
    np.testing.assert_array_equal(result.track[-1], result.pose.as_array())
    # Iteration i averages candidates at most η_i = η0/2^i and Δα_i = Δα0/2^i from the
    # current estimate, so it moves at most that far along each axis.
    steps = np.diff(result.track, axis=0)
    eta = grid / 2.0 ** np.arange(k)
    dalpha = np.deg2rad(dtheta_deg) / 2.0 ** np.arange(k)
    assert np.all(np.abs(steps[:, 0]) <= eta + 1e-12)
    assert np.all(np.abs(steps[:, 1]) <= eta + 1e-12)
    assert np.all(np.abs(wrap_angle(steps[:, 2])) <= dalpha + 1e-12)
    # The reported overlap is the overlap at the final pose with the last iteration's band.
    last_band = band_halfwidth(grid / 2.0 ** (k - 1))
    assert result.overlap_m == pytest.approx(
        overlap(L_ROOM, local, result.pose.as_array(), last_band), abs=1e-9
    )
    # From 50 cm off it gets well inside the first grid cell.
    assert np.hypot(result.pose.x - true.x, result.pose.y - true.y) < 0.15


def test_coarse_to_fine_recentres_add_iterations_only_while_moving():
    true = Pose2.from_deg(3.0, 2.0, 20.0)
    local = transform_segments(L_ROOM, true.inverse())
    start = Pose2.from_deg(3.3, 2.4, 23.0)
    result = coarse_to_fine(L_ROOM, local, start, **tuning(iterations=6, recentres=5))
    # At most 5 extra iterations on top of the 6 halvings.
    assert 7 <= result.track.shape[0] <= 12
    assert result.best_overlaps_m.shape == (result.track.shape[0] - 1,)


def test_coarse_to_fine_weighted_mean_step_by_hand():
    # G = WALL (x = 2, y ∈ [−1, 1]); the local map sees its top half-metre, robot frame
    # x = 2, y ∈ [0.5, 1]. Start at the true pose (the origin); η = 0.1, Δα = 0 so all
    # three headings of a position coincide; δ = 0.0707.
    # Columns x = ±0.1 put L 0.1 from G's line: outside the band, overlap 0.
    # Column x = 0: at y = −0.1, G is (2, −0.9)–(2, 1.1) in the robot frame and L lies
    # inside its sector: 0.5 + 0.5 = 1.0. At y = 0: 1.0. At y = +0.1, G is (2, −1.1)–(2, 0.9)
    # and L is clipped to [0.5, 0.9]: 0.4 + 0.4 = 0.8.
    local = np.array([[2.0, 0.5, 2.0, 1.0]])
    start = Pose2(0.0, 0.0, 0.0)
    args = dict(grid_m=0.1, dtheta_deg=0.0, iterations=1, recentres=0)
    # Ratio 0.9 keeps 1.0 and 1.0 (0.8 < 0.9): mean y = (−0.1 + 0)/2 = −0.05.
    r = coarse_to_fine(WALL, local, start, ratio=0.9, **args)
    assert r.best_overlaps_m[0] == pytest.approx(1.0, abs=1e-12)
    assert (r.pose.x, r.pose.y, r.pose.theta) == pytest.approx((0.0, -0.05, 0.0), abs=1e-12)
    # Ratio 0.75 keeps all three, weighted: (−0.1·1 + 0·1 + 0.1·0.8)/2.8 = −0.02/2.8.
    r = coarse_to_fine(WALL, local, start, ratio=0.75, **args)
    assert (r.pose.x, r.pose.y, r.pose.theta) == pytest.approx((0.0, -0.02 / 2.8, 0.0), abs=1e-12)
    # The final overlap uses the band of the last grid (η = 0.1): at y = −1/140, G spans
    # (2, −1 + 1/140)–(2, 1 + 1/140), L is inside: 1.0.
    assert r.overlap_m == pytest.approx(1.0, abs=1e-12)


def test_coarse_to_fine_averages_headings_on_the_circle():
    # Scene symmetric about the robot's x axis, robot facing −x (heading 180°): a wall at
    # world x = −2 is the wall x = 2 of the robot frame. The overlap is the same at
    # (x, y, 180° − a) and (x, −y, 180° + a), so the weighted mean is y = 0, heading 180°.
    # An arithmetic mean of 176°, 180°, −176° would land near 60° instead.
    g = np.array([[-2.0, 1.0, -2.0, -1.0]])
    local = np.array([[2.0, -0.8, 2.0, 0.8]])
    start = Pose2.from_deg(0.0, 0.0, 180.0)
    r = coarse_to_fine(g, local, start, **tuning(grid_m=0.1, iterations=1, ratio=0.0))
    cands = candidate_poses(start, 0.1, np.deg2rad(4.0))
    turned = np.abs(wrap_angle(cands[:, 2] - np.pi)) > 0.01
    # The turned candidates do overlap, so they take part in the mean.
    assert overlap_at_poses(g, local, cands, band_halfwidth(0.1))[turned].max() > 0.5
    assert r.pose.y == pytest.approx(0.0, abs=1e-12)
    assert abs(wrap_angle(r.pose.theta - np.pi)) < 1e-12


def test_coarse_to_fine_no_overlap_stays_put():
    # A local map that pairs with nothing at any candidate: the estimate does not move.
    local = np.array([[-5.0, -1.0, -5.0, 1.0]])
    start = Pose2(0.2, -0.1, 0.3)
    r = coarse_to_fine(WALL, local, start, **tuning(grid_m=0.5, iterations=3))
    np.testing.assert_array_equal(r.track, np.tile(start.as_array(), (4, 1)))
    np.testing.assert_array_equal(r.best_overlaps_m, [0.0, 0.0, 0.0])
    assert r.overlap_m == 0.0


def test_an_empty_local_map_overlaps_nothing_and_leaves_the_start():
    world = np.array([[0.0, 0.0, 4.0, 0.0], [0.0, 0.0, 0.0, 3.0]])
    start = Pose2(1.0, 1.0, 0.2)
    result = coarse_to_fine(world, np.zeros((0, 4)), start, **PAPER_SCHEDULE)
    assert result.overlap_m == 0.0
    assert (result.pose.x, result.pose.y, result.pose.theta) == (1.0, 1.0, 0.2)
    pairs = candidate_pairs(world, np.zeros((0, 4)), start, 1.0, 0.1, 0.1)
    assert pairs[0].size == 0 and pairs[1].size == 0


# --- the kernels' shortcuts change no result --------------------------------------------------


@njit
def _plain_pair_overlap(gax, gay, gbx, gby, lax, lay, lbx, lby, band_m, sin2_min) -> float:
    """|Cls| + |Cgs| of one pair (robot frame) computed plainly, every step in turn: what
    the kernels' shortcuts (tests that tell a zero without dividing) must reproduce."""
    turn = gax * gby - gay * gbx
    if abs(turn) <= 1e-12:
        return 0.0
    if turn < 0.0:
        gax, gay, gbx, gby = gbx, gby, gax, gay
    ex, ey = gbx - gax, gby - gay
    g_len = np.sqrt(ex * ex + ey * ey)
    nx, ny = -ey / g_len, ex / g_len
    off = nx * gax + ny * gay
    dx, dy = lbx - lax, lby - lay
    lo, hi = 0.0, 1.0
    for k in range(2):
        if k == 0:
            a, b = gax * lay - gay * lax, gax * dy - gay * dx
        else:
            a, b = lax * gby - lay * gbx, dx * gby - dy * gbx
        if b > 0.0:
            lo = max(lo, -a / b)
        elif b < 0.0:
            hi = min(hi, -a / b)
        elif a < 0.0:
            return 0.0
    s0 = nx * lax + ny * lay - off
    sd = nx * dx + ny * dy
    if sd == 0.0:
        if abs(s0) > band_m:
            return 0.0
    else:
        t1, t2 = (-band_m - s0) / sd, (band_m - s0) / sd
        lo = max(lo, min(t1, t2))
        hi = min(hi, max(t1, t2))
    if hi <= lo:
        return 0.0
    q0x, q0y = lax + lo * dx, lay + lo * dy
    q1x, q1y = lax + hi * dx, lay + hi * dy
    n_q0 = nx * q0x + ny * q0y
    n_q1 = nx * q1x + ny * q1y
    if n_q0 * n_q0 < sin2_min * (q0x * q0x + q0y * q0y) or n_q0 == 0.0:
        return 0.0
    if n_q1 * n_q1 < sin2_min * (q1x * q1x + q1y * q1y) or n_q1 == 0.0:
        return 0.0
    k0, k1 = off / n_q0, off / n_q1
    cx, cy = k1 * q1x - k0 * q0x, k1 * q1y - k0 * q0y
    return (hi - lo) * np.sqrt(dx * dx + dy * dy) + np.sqrt(cx * cx + cy * cy)


@njit
def _both_ways(args):
    """(kernel, plain) overlap (P,) of each row (10,) of ``args``."""
    got, want = np.empty(args.shape[0]), np.empty(args.shape[0])
    for i in range(args.shape[0]):
        a = args[i]
        got[i] = _pair_overlap(a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7], a[8], a[9])
        want[i] = _plain_pair_overlap(a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7], a[8], a[9])
    return got, want


ODD_VALUES = np.array(
    [0.0, -0.0, 1.0, -1.0, 2.0, 1e-300, -1e-300, 5e-324, 1e300, -1e300, np.inf, -np.inf, np.nan]
)


def _pair_cases(rng: np.random.Generator, count: int, odd_share: float) -> np.ndarray:
    """Rows (count, 10) of G's ends, L's ends (robot frame), band and sin² of the incidence,
    some coordinates on a 0.5 m lattice (so that ends meet and lines run through the
    scanner exactly), some odd values."""
    rows = rng.uniform(-4.0, 4.0, (count, 10))
    lattice = rng.random(count) < 0.3
    rows[lattice, :8] = np.round(rows[lattice, :8] * 2.0) / 2.0
    odd = rng.random((count, 8)) < odd_share
    rows[:, :8][odd] = rng.choice(ODD_VALUES, odd.sum())
    rows[:, 8] = rng.choice([0.0, 0.05, 0.3, 2.0], count)
    rows[:, 9] = rng.choice([0.0, np.sin(np.deg2rad(5.0)) ** 2, 0.5], count)
    return rows


@pytest.mark.parametrize("odd_share", [0.0, 0.03, 0.3])
def test_pair_overlap_equals_the_plain_computation(odd_share):
    rows = _pair_cases(np.random.default_rng(int(odd_share * 100)), 40_000, odd_share)
    got, want = _both_ways(rows)
    # The same value to the last bit; a NaN stays a NaN (its sign bit may differ).
    np.testing.assert_array_equal(got, want)
    finite = ~np.isnan(want)
    assert got[finite].tobytes() == want[finite].tobytes()
    assert (want > 0.0).sum() > 1000  # not vacuous


def test_pair_overlap_raises_where_the_plain_computation_did():
    # G subtends a sector (turn = 1e-5) while its length squared underflows to 0: the
    # plain computation divides by zero before looking at L, even for an L outside.
    args = (1e160, 0.0, 1e160, 1e-165, -5.0, -1.0, -5.0, 1.0, 0.1, 0.0)
    for overlap_of in (_plain_pair_overlap, _pair_overlap):
        with pytest.raises(ZeroDivisionError):
            overlap_of(*args)


@functools.cache
def _schedule_cases():
    """(map, local map, start) on a generated room: scans from free poses, starts off by up
    to 1.5 m and 20°, and a random local map that matches nothing."""
    rng = np.random.default_rng(17)
    world = random_world(rng)
    cases = []
    for truth in random_free_poses(world, 6, rng):
        truth = Pose2(*truth)
        local = extract_segments(simulate_scan(world, truth, SensorModel(), rng, 0.0))
        dx, dy, dtheta = rng.uniform(-1.0, 1.0, 3) * [1.5, 1.5, np.deg2rad(20.0)]
        cases.append(
            (world.segments, local, Pose2(truth.x + dx, truth.y + dy, truth.theta + dtheta))
        )
    cases.append((world.segments, rng.uniform(-5.0, 5.0, (8, 4)), cases[0][2]))
    return cases


@pytest.mark.parametrize("case", range(7))
def test_each_iteration_scores_as_overlap_at_poses_over_candidate_pairs(case):
    # The search's own loop (pairs grouped by global segment, the map segments out of
    # reach dropped as the grid shrinks) against the public functions, pair by pair.
    g, local, start = _schedule_cases()[case]
    grid, dtheta, k = 1.5, np.deg2rad(4.0), 6
    result = coarse_to_fine(g, local, start, **tuning(grid_m=grid, iterations=k))
    for i in range(k):
        centre = Pose2(*result.track[i])
        eta, step = grid / 2.0**i, dtheta / 2.0**i
        band = band_halfwidth(eta)
        pairs = candidate_pairs(g, local, centre, SQRT2 * eta, step, band)
        scores = overlap_at_poses(g, local, candidate_poses(centre, eta, step), band, pairs)
        assert scores.max() == result.best_overlaps_m[i], f"iteration {i}"
    final_band = SQRT2 * grid / 2.0**k
    pairs = candidate_pairs(g, local, result.pose, 0.0, 0.0, final_band)
    final = overlap_at_poses(g, local, result.pose.as_array(), final_band, pairs)[0]
    assert final == result.overlap_m
    if case < 6:  # not vacuous: the scans do overlap the map
        assert result.overlap_m > 1.0


@pytest.mark.parametrize("case", range(7))
def test_recentred_search_ends_on_the_overlap_of_its_final_pose(case):
    g, local, start = _schedule_cases()[case]
    result = coarse_to_fine(g, local, start, **tuning(iterations=8, recentres=8))
    final_band = SQRT2 * 1.5 / 2.0**8
    pairs = candidate_pairs(g, local, result.pose, 0.0, 0.0, final_band)
    assert overlap_at_poses(g, local, result.pose.as_array(), final_band, pairs)[0] == (
        result.overlap_m
    )
    # The map's grid spares segments out of reach, and changes nothing either.
    index = SegmentGrid(g, cell_m=2.0)
    indexed = coarse_to_fine(g, local, start, **tuning(iterations=8, recentres=8), index=index)
    np.testing.assert_array_equal(indexed.track, result.track)
    np.testing.assert_array_equal(indexed.best_overlaps_m, result.best_overlaps_m)
    assert indexed.overlap_m == result.overlap_m


def test_within_reach_takes_the_segments_the_grid_lists():
    rng = np.random.default_rng(8)
    segments = random_world(rng).segments
    for cell_m in (2.0, 40.0):  # many cells, and one cell that holds the whole map
        grid = SegmentGrid(segments, cell_m=cell_m)
        queries = [((x, y), r) for x, y, r in rng.uniform([-5, -5, 0], [25, 20, 30], (200, 3))]
        queries += [((np.nan, 0.0), 1.0), ((0.0, 0.0), np.inf), ((1e30, 1e30), 5.0)]
        for (x, y), radius in queries:
            got = _within_reach(grid, segments, x, y, radius)
            np.testing.assert_array_equal(got, segments[grid.candidates([x, y], radius)])
