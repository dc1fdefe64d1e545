"""Global-map building: fusion of duplicate segments, length-weighted fit, frames."""

from __future__ import annotations

import numpy as np
import pytest

from segloc_cli.geometry import Pose2
from segloc_cli.mapping import (
    FuseParams,
    build_global_map,
    fit_segments,
    fuse_segments,
    mergeable_pairs,
)


def assert_same_segment(got, want, atol=1e-12):
    """Equal as undirected segments: the endpoints may come in either order."""
    got = np.asarray(got, dtype=float).reshape(4)
    want = np.asarray(want, dtype=float).reshape(4)
    flipped = want[[2, 3, 0, 1]]
    assert np.allclose(got, want, atol=atol) or np.allclose(got, flipped, atol=atol), (
        f"{got} is not the segment {want}"
    )


def seg(theta_deg: float, half_length: float) -> list[float]:
    """A segment centred on the origin along ``theta_deg``."""
    c, s = np.cos(np.deg2rad(theta_deg)), np.sin(np.deg2rad(theta_deg))
    return [-half_length * c, -half_length * s, half_length * c, half_length * s]


# --- fuse_segments ----------------------------------------------------------------------------


def test_overlapping_collinear_pieces_become_one():
    fused = fuse_segments(np.array([[0.0, 0.0, 2.0, 0.0], [1.0, 0.0, 3.0, 0.0]]))
    assert fused.shape == (1, 4)
    assert_same_segment(fused[0], [0.0, 0.0, 3.0, 0.0])
    # Reversed directions make no difference.
    fused = fuse_segments(np.array([[2.0, 0.0, 0.0, 0.0], [1.0, 0.0, 3.0, 0.0]]))
    assert_same_segment(fused[0], [0.0, 0.0, 3.0, 0.0])


def test_gap_below_threshold_merges_above_does_not():
    # Gap 0.1 ≤ gap_m = 0.15: one segment spanning both.
    fused = fuse_segments(np.array([[0.0, 0.0, 1.0, 0.0], [1.1, 0.0, 2.0, 0.0]]))
    assert fused.shape == (1, 4)
    assert_same_segment(fused[0], [0.0, 0.0, 2.0, 0.0])
    # Gap 0.2 > 0.15: unchanged.
    pieces = np.array([[0.0, 0.0, 1.0, 0.0], [1.2, 0.0, 2.0, 0.0]])
    np.testing.assert_array_equal(fuse_segments(pieces), pieces)
    # The threshold is the parameter: gap_m = 0.25 merges them.
    fused = fuse_segments(pieces, FuseParams(gap_m=0.25))
    assert fused.shape == (1, 4)
    assert_same_segment(fused[0], [0.0, 0.0, 2.0, 0.0])


def test_parallel_offset_beyond_threshold_does_not_merge():
    # 0.1 apart > offset_m = 0.06.
    pieces = np.array([[0.0, 0.0, 2.0, 0.0], [1.0, 0.1, 3.0, 0.1]])
    np.testing.assert_array_equal(fuse_segments(pieces), pieces)
    # 0.04 apart (and overlapping from x = 1 to 2) merges.
    assert fuse_segments(np.array([[0.0, 0.0, 2.0, 0.0], [1.0, 0.04, 3.0, 0.04]])).shape == (1, 4)


def test_angle_beyond_threshold_does_not_merge():
    # Two 1 m segments crossing at their midpoints. At 4° their ends are 0.5·sin 4° = 3.5 cm
    # from each other's line (< offset_m), but 4° > angle_deg = 3°: no merge.
    pieces = np.array([seg(0.0, 0.5), seg(4.0, 0.5)])
    np.testing.assert_array_equal(fuse_segments(pieces), pieces)
    # At 2° they merge. Both are centred on the origin with equal length, so the fit is
    # the bisector at 1°; every endpoint projects to ±0.5·cos 1° on it.
    fused = fuse_segments(np.array([seg(0.0, 0.5), seg(2.0, 0.5)]))
    assert fused.shape == (1, 4)
    assert_same_segment(fused[0], seg(1.0, 0.5 * np.cos(np.deg2rad(1.0))))


def test_chain_of_neighbouring_overlaps_becomes_one():
    # A overlaps B, B overlaps C, A and C are 1 m apart.
    chain = np.array([[0.0, 0.0, 2.0, 0.0], [1.5, 0.0, 3.5, 0.0], [3.0, 0.0, 5.0, 0.0]])
    pairs = mergeable_pairs(chain, FuseParams())
    assert set(zip(*(a.tolist() for a in pairs), strict=True)) == {(0, 1), (1, 2)}
    fused = fuse_segments(chain)
    assert fused.shape == (1, 4)
    assert_same_segment(fused[0], [0.0, 0.0, 5.0, 0.0])


def test_a_chain_across_parallel_lines_is_not_averaged_into_one():
    # Four full-length walls 5 cm apart: each pairs with its neighbours, so all
    # four form one group, but one line through them (y = 0.075) would leave the
    # outer two 7.5 cm off. Regrown from the first, the group gives two lines.
    walls = np.array([[0.0, y, 4.0, y] for y in (0.0, 0.05, 0.10, 0.15)])
    pairs = mergeable_pairs(walls, FuseParams())
    assert set(zip(*(a.tolist() for a in pairs), strict=True)) == {(0, 1), (1, 2), (2, 3)}
    fused = fuse_segments(walls)
    assert fused.shape == (2, 4)
    order = np.argsort(fused[:, 1])
    assert_same_segment(fused[order[0]], [0.0, 0.025, 4.0, 0.025])
    assert_same_segment(fused[order[1]], [0.0, 0.125, 4.0, 0.125])


def test_fusion_repeats_until_nothing_merges():
    # A (y = 0, 4 m) and B (y = 0.05, 2 m, over A's middle) merge into a line at
    # y = (4·0 + 2·0.05)/6 = 1/60. C (y = 0.07, from x = 4.05) is 0.07 from A's line and
    # 1.05 past B's end, so it pairs with neither in the first round; it is 0.053 from the
    # fused line and 0.05 past its end, so it joins in the second.
    segs = np.array([[0.0, 0.0, 4.0, 0.0], [1.0, 0.05, 3.0, 0.05], [4.05, 0.07, 6.0, 0.07]])
    pairs = mergeable_pairs(segs, FuseParams())
    assert set(zip(*(a.tolist() for a in pairs), strict=True)) == {(0, 1)}
    first = fit_segments(segs[:2])
    assert_same_segment(first, [0.0, 1 / 60, 4.0, 1 / 60])
    i, j = mergeable_pairs(np.vstack([first, segs[2]]), FuseParams())
    assert (i.tolist(), j.tolist()) == ([0], [1])
    fused = fuse_segments(segs)
    assert fused.shape == (1, 4)
    xs = np.sort(fused[0, [0, 2]])
    assert xs == pytest.approx([0.0, 6.0], abs=0.01)


def test_unrelated_segments_and_degenerate_input():
    walls = np.array([[0.0, 0.0, 4.0, 0.0], [4.0, 0.0, 4.0, 3.0], [0.0, 1.0, 4.0, 1.0]])
    np.testing.assert_array_equal(fuse_segments(walls), walls)
    # A zero-length segment is dropped.
    np.testing.assert_array_equal(fuse_segments(np.vstack([walls, [[1.0, 1.0, 1.0, 1.0]]])), walls)
    assert fuse_segments(np.zeros((0, 4))).shape == (0, 4)


# --- fit_segments -----------------------------------------------------------------------------


def test_fit_is_length_weighted():
    # Long piece y = 0, x ∈ [0, 4] (length 4); short piece y = 0.04, x ∈ [1.5, 2.5]
    # (length 1); both centred on x = 2. Length-weighted centroid:
    #   y = (4·0 + 1·0.04)/5 = 0.008,
    # and with both midpoints at x = 2 the scatter has no xy term: the line is y = 0.008,
    # 0.008 from the long piece and 0.032 from the short one (1 : 4, inverse to length).
    # It spans the projections of all endpoints: x ∈ [0, 4].
    long_short = np.array([[0.0, 0.0, 4.0, 0.0], [1.5, 0.04, 2.5, 0.04]])
    assert_same_segment(fit_segments(long_short), [0.0, 0.008, 4.0, 0.008])
    fused = fuse_segments(long_short)
    assert fused.shape == (1, 4)
    assert_same_segment(fused[0], [0.0, 0.008, 4.0, 0.008])
    # Swapping which piece is long moves the line to the other side: y = 0.032.
    swapped = np.array([[1.5, 0.0, 2.5, 0.0], [0.0, 0.04, 4.0, 0.04]])
    assert_same_segment(fit_segments(swapped), [0.0, 0.032, 4.0, 0.032])


def test_fit_of_one_segment_is_itself():
    s = np.array([[1.0, 2.0, 4.0, 6.0]])
    assert_same_segment(fit_segments(s), s[0])


def test_fit_of_collinear_pieces_spans_their_union():
    # Pieces of the line y = x − 1 in any order and direction.
    pieces = np.array([[3.0, 2.0, 2.0, 1.0], [1.0, 0.0, 1.5, 0.5], [5.0, 4.0, 4.5, 3.5]])
    assert_same_segment(fit_segments(pieces), [1.0, 0.0, 5.0, 4.0])


# --- build_global_map -------------------------------------------------------------------------


def test_build_global_map_moves_local_maps_to_the_world():
    # (1, 0)–(2, 0) seen from (1, 1, 90°): R(90°)(x, y) = (−y, x), so (1, 2)–(1, 3).
    # (0, 1)–(1, 1) seen from (−1, 0, 180°): (x, y) → (−1 − x, −y), so (−1, −1)–(−2, −1).
    local_maps = [np.array([[1.0, 0.0, 2.0, 0.0]]), np.array([[0.0, 1.0, 1.0, 1.0]])]
    poses = [Pose2.from_deg(1.0, 1.0, 90.0), Pose2.from_deg(-1.0, 0.0, 180.0)]
    np.testing.assert_allclose(
        build_global_map(local_maps, poses),
        [[1.0, 2.0, 1.0, 3.0], [-1.0, -1.0, -2.0, -1.0]],
        atol=1e-12,
    )


def test_build_global_map_fuses_one_wall_seen_twice():
    # The wall y = 2, x ∈ [0, 4]: from (0, 0, 0°) the robot sees x ∈ [0, 2.5]; from
    # (2, 0, 90°) it sees x ∈ [1.5, 4], which in its frame (x, y)_world − (2, 0) rotated by
    # −90° is (2, 0.5)–(2, −2).
    local_maps = [np.array([[0.0, 2.0, 2.5, 2.0]]), np.array([[2.0, 0.5, 2.0, -2.0]])]
    poses = [Pose2(0.0, 0.0, 0.0), Pose2.from_deg(2.0, 0.0, 90.0)]
    world = build_global_map(local_maps, poses)
    assert world.shape == (1, 4)
    assert_same_segment(world[0], [0.0, 2.0, 4.0, 2.0], atol=1e-12)


def test_build_global_map_checks_its_inputs():
    with pytest.raises(ValueError, match="1 local maps but 2 poses"):
        build_global_map([np.zeros((0, 4))], [Pose2(0, 0, 0), Pose2(1, 0, 0)])
    assert build_global_map([], []).shape == (0, 4)


def _brute_force_pairs(segs: np.ndarray, params: FuseParams) -> set[tuple[int, int]]:
    """Every pair tested directly, from the definitions (no spatial grid)."""
    found = set()
    for a in range(len(segs)):
        for b in range(a + 1, len(segs)):
            pa, qa, pb, qb = segs[a, :2], segs[a, 2:], segs[b, :2], segs[b, 2:]
            ua = (qa - pa) / np.linalg.norm(qa - pa)
            ub = (qb - pb) / np.linalg.norm(qb - pb)
            if abs(ua @ ub) < np.cos(np.deg2rad(params.angle_deg)):
                continue

            def off(p, u, r):
                return abs((r - p) @ np.array([-u[1], u[0]]))

            offset = max(off(pa, ua, pb), off(pa, ua, qb), off(pb, ub, pa), off(pb, ub, qa))

            def gap(p, u, length, r, s):
                t = sorted([(r - p) @ u, (s - p) @ u])
                return max(t[0] - length, -t[1])

            la, lb = np.linalg.norm(qa - pa), np.linalg.norm(qb - pb)
            if (
                offset <= params.offset_m
                and gap(pa, ua, la, pb, qb) <= params.gap_m
                and gap(pb, ub, lb, pa, qa) <= params.gap_m
            ):
                found.add((a, b))
    return found


def test_grid_candidates_find_exactly_the_brute_force_pairs():
    rng = np.random.default_rng(5)
    params = FuseParams()
    for _ in range(20):
        start = rng.uniform(0, 12, (40, 2))
        angle = rng.choice([0.0, np.pi / 2, rng.uniform(0, np.pi)], 40)
        length = rng.uniform(0.2, 7.0, 40)  # long ones span several grid cells
        segs = np.column_stack(
            [start, start + length[:, None] * np.c_[np.cos(angle), np.sin(angle)]]
        )
        segs = np.vstack([segs, segs + rng.normal(0, 0.02, segs.shape)])
        i, j = mergeable_pairs(segs, params)
        assert set(zip(i.tolist(), j.tolist(), strict=True)) == _brute_force_pairs(segs, params)
