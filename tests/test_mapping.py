"""Global-map building: fusion of duplicate segments, length-weighted fit, frames."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from segloc_cli.geometry import Pose2, wrap_angle
from segloc_cli.maps.fusion import (
    FuseParams,
    _nearby_pair_stretches,
    _nearby_pairs,
    build_global_map,
    fit_segments,
    fuse_segments,
    fuse_traced,
    mergeable_pairs,
    observed_map,
    overlapping_duplicates,
    polish_poses,
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


def test_three_overlapping_pieces_of_a_slanted_wall_fuse_to_it_exactly():
    # The wall (1, −2) + t·(0.8, 0.6), t ∈ [0, 10], ends at (9, 4). Pieces t ∈ [0, 4],
    # [3, 7] (reversed) and [6, 10]: neighbours overlap by 1 m, the outer two are 2 m apart.
    pieces = np.array(
        [[1.0, -2.0, 4.2, 0.4], [6.6, 2.2, 3.4, -0.2], [5.8, 1.6, 9.0, 4.0]],
    )
    fused = fuse_segments(pieces)
    assert fused.shape == (1, 4)
    assert_same_segment(fused[0], [1.0, -2.0, 9.0, 4.0], atol=1e-12)


def test_offset_duplicates_fuse_to_their_length_weighted_line():
    # Three horizontal pieces, all centred on x = 2, at y = 0 (length 4), 0.05 (length 3)
    # and 0.02 (length 2): every two are within offset_m and overlap. With the midpoints
    # on one vertical the fit is horizontal, at the length-weighted mean height
    #   y = (4·0 + 3·0.05 + 2·0.02)/9 = 0.19/9 ≈ 0.0211,
    # which every piece lies within 0.029 of; it spans x ∈ [0, 4].
    pieces = np.array([[0.0, 0.0, 4.0, 0.0], [0.5, 0.05, 3.5, 0.05], [1.0, 0.02, 3.0, 0.02]])
    fused = fuse_segments(pieces)
    assert fused.shape == (1, 4)
    assert_same_segment(fused[0], [0.0, 0.19 / 9, 4.0, 0.19 / 9], atol=1e-12)


def test_parallel_walls_farther_apart_than_offset_stay_two_segments():
    # A wall (y = 0) and a shelf along it (y = 0.1), each seen as overlapping pieces.
    # Pieces of one are 0.1 > offset_m from the other's line, so each fuses on its own.
    wall = [[0.0, 0.0, 2.5, 0.0], [4.0, 0.0, 2.0, 0.0], [1.0, 0.0, 3.0, 0.0]]
    shelf = [[0.5, 0.1, 2.0, 0.1], [1.8, 0.1, 3.5, 0.1]]
    fused = fuse_segments(np.array(wall + shelf))
    assert fused.shape == (2, 4)
    assert_same_segment(fused[0], [0.0, 0.0, 4.0, 0.0])
    assert_same_segment(fused[1], [0.5, 0.1, 3.5, 0.1])
    assert overlapping_duplicates(fused)[0].size == 0


def test_a_chain_across_parallel_lines_leaves_no_overlapping_duplicate():
    # Pieces of four lines 5 cm apart, each line seen twice with overlap: every piece
    # pairs with its own line's other piece and with the lines next to it, so they are
    # one group that no single line fits. The result must still hold no two segments
    # that overlap within tolerance of each other's lines.
    pieces = np.array([[x0, y, x0 + 2.5, y] for y in (0.0, 0.05, 0.10, 0.15) for x0 in (0.0, 1.5)])
    fused = fuse_segments(pieces)
    assert overlapping_duplicates(fused)[0].size == 0
    assert mergeable_pairs(fused, FuseParams())[0].size == 0
    # Regrown from the longest (first) piece, the lines pair up as in the full-length case.
    assert fused.shape == (2, 4)
    order = np.argsort(fused[:, 1])
    assert_same_segment(fused[order[0]], [0.0, 0.025, 4.0, 0.025])
    assert_same_segment(fused[order[1]], [0.0, 0.125, 4.0, 0.125])


def test_segments_that_match_nothing_come_out_unchanged_and_in_place():
    # Two pieces of y = 0 fuse; the two slanted segments match nothing and are returned
    # bit for bit, endpoint order kept, after the fused wall (which takes the place of
    # its first piece).
    lone = np.array([[0.3, 1.7, 2.9, 5.1], [5.0, 5.0, 4.0, 1.3]])
    segs = np.vstack([[[0.0, 0.0, 2.0, 0.0]], lone[:1], [[1.0, 0.0, 3.0, 0.0]], lone[1:]])
    fused = fuse_segments(segs)
    assert fused.shape == (3, 4)
    assert_same_segment(fused[0], [0.0, 0.0, 3.0, 0.0])
    np.testing.assert_array_equal(fused[1:], lone)


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


def test_fusion_traces_each_segment_to_the_one_it_went_into():
    # The four walls 5 cm apart are regrown into two lines (y = 0.025 from the first two,
    # y = 0.125 from the last two); the lone wall at y = 3 stays as it is; the point of
    # zero length goes nowhere.
    walls = np.array([[0.0, y, 4.0, y] for y in (0.0, 0.05, 0.10, 0.15, 3.0)])
    walls = np.vstack([walls[:2], [[1.0, 1.0, 1.0, 1.0]], walls[2:]])
    fused, into = fuse_traced(walls)
    assert fused.shape == (3, 4)
    assert into[2] == -1
    assert into[0] == into[1] and into[3] == into[4]
    assert len({into[0], into[3], into[5]}) == 3
    assert_same_segment(fused[into[0]], [0.0, 0.025, 4.0, 0.025], atol=1e-12)
    assert_same_segment(fused[into[3]], [0.0, 0.125, 4.0, 0.125], atol=1e-12)
    assert_same_segment(fused[into[5]], [0.0, 3.0, 4.0, 3.0])
    np.testing.assert_array_equal(fused, fuse_segments(walls))


def _seen_from(pose: Pose2, segments_world) -> np.ndarray:
    """World segments (K, 4) as a scanner at ``pose`` sees them: in its frame."""
    from segloc_cli.geometry import transform_segments

    inverse = Pose2(0.0, 0.0, -pose.theta).compose(Pose2(-pose.x, -pose.y, 0.0))
    return transform_segments(np.asarray(segments_world, dtype=float), inverse)


def test_observed_map_counts_the_poses_each_segment_was_seen_from():
    # The wall y = 3 is seen from all four scans, in pieces that overlap; a bench from
    # the first and third; a passer-by from the second only. The first two scans were
    # taken from one pose (one survey row): together they are one viewpoint.
    wall, bench, person = [0.0, 3.0, 6.0, 3.0], [1.0, 1.0, 1.0, 2.0], [4.0, 1.5, 4.4, 1.2]
    poses = [Pose2(2.0, 0.0, 0.3), Pose2(2.0, 0.0, 0.3), Pose2(4.0, 0.5, 1.2), Pose2(5.0, 0.0, 2.0)]
    seen = [
        [[0.0, 3.0, 4.0, 3.0], bench],
        [[1.0, 3.0, 5.0, 3.0], person],
        [[2.0, 3.0, 6.0, 3.0], bench],
        [wall],
    ]
    local_maps = [_seen_from(pose, s) for pose, s in zip(poses, seen, strict=True)]

    def count_of(segments, counts, target):
        near = [np.allclose(s, target, atol=1e-9) or np.allclose(s[[2, 3, 0, 1]], target, atol=1e-9)
                for s in segments]  # fmt: skip
        assert sum(near) == 1, f"{target} is not in the map once: {segments}"
        return int(counts[near.index(True)])

    segments, counts = observed_map(local_maps, poses)
    assert segments.shape == (3, 4)
    assert [count_of(segments, counts, t) for t in (wall, bench, person)] == [4, 2, 1]
    np.testing.assert_array_equal(segments, build_global_map(local_maps, poses))
    by_pose = observed_map(local_maps, poses, viewpoints=np.array([7, 7, 8, 9]))[1]
    assert [count_of(segments, by_pose, t) for t in (wall, bench, person)] == [3, 2, 1]
    with pytest.raises(ValueError, match="3 viewpoints for 4 local maps"):
        observed_map(local_maps, poses, viewpoints=np.array([0, 1, 2]))
    empty = observed_map([], [])
    assert empty[0].shape == (0, 4) and empty[1].shape == (0,)


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


def test_grid_candidates_hold_each_pair_once_across_orientation_bins_and_the_wrap():
    # Orientations next to the 0°/180° wrap and to the orientation-bin edges, with
    # partners turned by just under and just over angle_deg, packed into a few cells.
    rng = np.random.default_rng(11)
    params = FuseParams()
    edges = np.arange(60) * 180.0 / 59  # bin edges for angle_deg = 3
    for _ in range(20):
        base = rng.choice(np.concatenate([edges, [0.0, 179.9, 0.1]]), 30)
        angle = np.deg2rad(
            np.concatenate([base, base + rng.choice([-3.05, -2.95, 2.95, 3.05], 30)])
            + rng.normal(0.0, 0.01, 60)
        )
        start = rng.uniform(0, 3, (60, 2))
        length = rng.uniform(0.3, 3.0, 60)
        segs = np.column_stack(
            [start, start + length[:, None] * np.c_[np.cos(angle), np.sin(angle)]]
        )
        i, j = _nearby_pairs(segs, 0.15, np.deg2rad(params.angle_deg))
        pairs = list(zip(i.tolist(), j.tolist(), strict=True))
        assert len(pairs) == len(set(pairs))
        assert all(a < b for a, b in pairs)
        i, j = mergeable_pairs(segs, params)
        assert set(zip(i.tolist(), j.tolist(), strict=True)) == _brute_force_pairs(segs, params)


def test_pairs_found_a_stretch_of_columns_at_a_time_are_those_of_one_stretch():
    """However the grid's columns are cut into stretches, the candidate pairs are the same, in
    the same order, and each segment is counted done once, by its last column's stretch."""
    rng = np.random.default_rng(23)
    angle = rng.uniform(0.0, np.pi, 400)
    start = rng.uniform(0, 30, (400, 2))
    length = rng.uniform(0.1, 6.0, 400)
    segs = np.column_stack([start, start + length[:, None] * np.c_[np.cos(angle), np.sin(angle)]])
    segs = np.vstack([segs, segs + rng.normal(0, 0.02, segs.shape)])
    margin, angle_rad = 0.15, np.deg2rad(FuseParams().angle_deg)
    ((whole_i, whole_j, done),) = _nearby_pair_stretches(segs, margin, angle_rad, 10**9)
    assert done == len(segs) and whole_i.size > 500
    for entries in (1, 37, 500):
        stretches = list(_nearby_pair_stretches(segs, margin, angle_rad, entries))
        assert len(stretches) > 10
        np.testing.assert_array_equal(np.concatenate([i for i, _, _ in stretches]), whole_i)
        np.testing.assert_array_equal(np.concatenate([j for _, j, _ in stretches]), whole_j)
        assert sum(d for _, _, d in stretches) == len(segs)


def test_fusion_counts_each_segment_of_its_first_round_once():
    from segloc_cli.progress import Progress

    class Counted(Progress):
        def __init__(self, what, total, unit):
            super().__init__(what, total, unit, terminal=False)
            made.append(self)

    made: list[Counted] = []
    pieces = np.array([[0.1 * k, 0.0, 0.1 * k + 0.5, 0.0] for k in range(40)])
    fused = fuse_segments(pieces, progress=Counted)
    assert fused.shape == (1, 4)
    (shown,) = made
    assert (shown.what, shown.total, shown.unit, shown.done) == (
        "fusing segments",
        40,
        "segment",
        40,
    )


def test_pieces_either_side_of_the_orientation_wrap_merge():
    # At +0.5° and −0.5° (that is, 179.5°) two overlapping pieces are 1° apart.
    fused = fuse_segments(np.array([seg(0.5, 1.0), seg(-0.5, 1.0)]))
    assert fused.shape == (1, 4)
    assert_same_segment(fused[0], seg(0.0, np.cos(np.deg2rad(0.5))), atol=1e-12)


# --- overlapping_duplicates -------------------------------------------------------------------


def _rotated_touching_pieces() -> np.ndarray:
    """Two pieces of one line at 17° that share an endpoint and nothing more.

    Computed, their overlap along the line comes out as −1e-16 m rather than 0.
    """
    a = np.array([20.0, 20.0])
    u = np.array([np.cos(np.deg2rad(17.0)), np.sin(np.deg2rad(17.0))])
    return np.array([[*a, *(a + u)], [*(a + 3.0 * u), *(a + u)]])


def test_overlapping_duplicates_are_exactly_the_overlapping_mergeable_pairs():
    segs = np.vstack(
        [
            [0.0, 0.0, 4.0, 0.0],  # 0: a wall
            [3.0, 0.03, 6.0, 0.03],  # 1: 3 cm off it, overlapping x ∈ [3, 4] → duplicate of 0
            [6.0, 0.03, 8.0, 0.03],  # 2: continues 1 end to end: touching only
            [0.0, 0.1, 4.0, 0.1],  # 3: parallel to 0 at 10 cm > offset_m: a different line
            [8.1, 0.03, 9.0, 0.03],  # 4: 0.1 past 2: mergeable across the gap, no overlap
            seg(4.0, 0.5) + np.array([2.0, 0.0, 2.0, 0.0]),  # 5: crosses 0 at 4° > angle_deg
            # 6: a short piece on 0 at 2°: its ends are within 1.8 cm of 0's line, but 0's
            # far end is 3·sin 2° ≈ 10 cm from its line, so they are not one line.
            seg(2.0, 0.5) + np.array([1.0, 0.0, 1.0, 0.0]),
            _rotated_touching_pieces(),  # 7, 8: share an endpoint, nothing more
            [0.0, 10.0, 3.0, 10.0],  # 9, 10, 11: three overlapping copies of y ≈ 10
            [4.0, 10.02, 1.0, 10.02],
            [2.0, 9.99, 5.0, 9.99],
        ]
    )
    i, j = overlapping_duplicates(segs)
    assert sorted(zip(i.tolist(), j.tolist(), strict=True)) == [
        (0, 1),
        (9, 10),
        (9, 11),
        (10, 11),
    ]
    # The touching and gapped pieces do match, as pieces of one wall.
    merge = set(zip(*(a.tolist() for a in mergeable_pairs(segs, FuseParams())), strict=True))
    assert {(1, 2), (2, 4), (7, 8)} <= merge
    assert overlapping_duplicates(fuse_segments(segs))[0].size == 0


def test_overlapping_duplicates_follow_the_parameters():
    # 5 cm apart and overlapping: a duplicate at offset_m = 0.06, not at 0.04.
    pair = np.array([[0.0, 0.0, 2.0, 0.0], [1.0, 0.05, 3.0, 0.05]])
    assert overlapping_duplicates(pair)[0].tolist() == [0]
    assert overlapping_duplicates(pair, FuseParams(offset_m=0.04))[0].size == 0
    assert overlapping_duplicates(np.zeros((0, 4)))[0].size == 0


# --- properties -------------------------------------------------------------------------------


def _pieces(
    rng: np.random.Generator, spacing, overlap, repeats: int, noise_m: float
) -> tuple[np.ndarray, float]:
    """Overlapping pieces (K, 4) of the wall y = 0, x ∈ [0, L], and L.

    Piece k starts at the k-th cut and runs ``overlap[k]`` past the next one (the
    last stops at L); each is seen ``repeats`` times, every endpoint moved by up to
    ``noise_m`` along and across the wall, in a random direction.
    """
    cuts = np.concatenate([[0.0], np.cumsum(spacing)])
    wall_length = float(cuts[-1])
    ends = np.minimum(cuts[1:] + np.asarray(overlap[: len(spacing)]), wall_length)
    x = np.repeat(np.column_stack([cuts[:-1], ends]), repeats, axis=0)
    pieces = np.column_stack([x[:, 0], np.zeros(len(x)), x[:, 1], np.zeros(len(x))])
    pieces += rng.uniform(-noise_m, noise_m, pieces.shape)
    flip = rng.random(len(pieces)) < 0.5
    pieces[flip] = pieces[flip][:, [2, 3, 0, 1]]
    return pieces, wall_length


def _place(segments: np.ndarray, x: float, y: float, theta: float) -> np.ndarray:
    """Segments (K, 4) moved by the pose (x, y, theta)."""
    c, s = np.cos(theta), np.sin(theta)
    r = np.array([[c, -s], [s, c]])
    return np.hstack([segments[:, :2] @ r.T + [x, y], segments[:, 2:] @ r.T + [x, y]])


wall_cuts = st.lists(st.floats(0.5, 1.2), min_size=1, max_size=6)
pose = st.tuples(st.floats(-20, 20), st.floats(-20, 20), st.floats(-np.pi, np.pi))


@settings(max_examples=100, deadline=None)
@given(
    spacing=wall_cuts,
    overlap=st.lists(st.floats(0.02, 0.3), min_size=6, max_size=6),
    repeats=st.integers(1, 3),
    where=pose,
    seed=st.integers(0, 2**32 - 1),
)
def test_a_wall_cut_into_noisy_overlapping_pieces_fuses_into_one(
    spacing, overlap, repeats, where, seed
):
    noise = 0.005
    pieces, length = _pieces(np.random.default_rng(seed), spacing, overlap, repeats, noise)
    pieces = _place(pieces, *where)
    fused = fuse_segments(pieces)
    assert fused.shape == (1, 4)
    # One round: every piece is in one group, which their length-weighted fit spans.
    assert_same_segment(fused[0], fit_segments(pieces), atol=1e-9)
    wall = _place(np.array([[0.0, 0.0, length, 0.0]]), *where)[0]
    assert_same_segment(fused[0], wall, atol=0.02)


@settings(max_examples=100, deadline=None)
@given(
    spacing=st.tuples(wall_cuts, wall_cuts),
    overlap=st.lists(st.floats(0.02, 0.3), min_size=6, max_size=6),
    apart=st.floats(0.09, 0.5),
    shift=st.floats(-1.0, 1.0),
    where=pose,
    seed=st.integers(0, 2**32 - 1),
)
def test_parallel_walls_beyond_offset_never_merge_whatever_the_pieces(
    spacing, overlap, apart, shift, where, seed
):
    # Two parallel walls 9–50 cm apart, each in noisy overlapping pieces: with
    # 2 mm of noise no piece of one comes within offset_m of the other's line.
    rng = np.random.default_rng(seed)
    near, _ = _pieces(rng, spacing[0], overlap, 2, 0.002)
    far, _ = _pieces(rng, spacing[1], overlap, 2, 0.002)
    far += [shift, apart, shift, apart]
    near, far = _place(near, *where), _place(far, *where)
    fused = fuse_segments(np.vstack([near, far]))
    assert fused.shape == (2, 4)
    assert_same_segment(fused[0], fit_segments(near), atol=1e-9)
    assert_same_segment(fused[1], fit_segments(far), atol=1e-9)


@settings(max_examples=150, deadline=None)
@given(n=st.integers(2, 30), where=pose, seed=st.integers(0, 2**32 - 1))
def test_fused_maps_hold_no_overlapping_duplicates(n, where, seed):
    # Pieces within 15 cm of one line, tilted by up to 4°: chains of matches across
    # nearby lines, groups that no one line fits, and regrowth.
    rng = np.random.default_rng(seed)
    x0, length = rng.uniform(0.0, 4.0, n), rng.uniform(0.2, 3.0, n)
    y0, tilt = rng.uniform(-0.15, 0.15, n), np.deg2rad(rng.uniform(-4.0, 4.0, n))
    segs = np.column_stack([x0, y0, x0 + length * np.cos(tilt), y0 + length * np.sin(tilt)])
    fused = fuse_segments(_place(segs, *where))
    assert fused.shape[0] <= n
    assert overlapping_duplicates(fused)[0].size == 0
    assert mergeable_pairs(fused, FuseParams())[0].size == 0
    np.testing.assert_array_equal(fuse_segments(fused), fused)


def test_a_map_built_from_an_off_centre_scanner_lies_on_the_walls():
    """``map build`` places each scan's segments at the robot's surveyed pose through the
    scanner's mounting: the map lies on the hall's walls, where the same scans taken as
    mounted at the robot's origin would put it a mounting away."""
    from dataclasses import replace
    from pathlib import Path

    from segloc_cli.config import Config
    from segloc_cli.geometry import point_segment_distances, sample_segments
    from segloc_cli.io.log import Log
    from segloc_cli.io.maps import read_world
    from segloc_cli.io.tables import read_pose_table
    from segloc_cli.runs.pipeline import build_map
    from segloc_cli.sim import NOISE_FREE, simulate_scan

    hall = Path(__file__).resolve().parents[1] / "datasets" / "hall"
    world = read_world(hall / "world.json")
    survey = read_pose_table(hall / "survey.csv")
    mount = Pose2(0.22, 0.05, np.deg2rad(10.0))
    rng = np.random.default_rng(3)
    scans = [
        replace(simulate_scan(world, Pose2(*p).compose(mount), NOISE_FREE, rng, t), mount=mount)
        for t, p in zip(survey.time_s, survey.poses, strict=True)
    ]

    def built_off_the_walls(scans) -> np.ndarray:
        log = Log(scans, survey.time_s, np.zeros(0), np.zeros((0, 3)), {})
        segments = build_map(log, hall / "log.mcap", survey, hall, Config()).segments
        return point_segment_distances(sample_segments(segments, 0.1), world.segments).min(1)

    mounted = built_off_the_walls(scans)
    assert np.percentile(mounted, 99) < 0.01, np.percentile(mounted, [50, 99])
    unmounted = built_off_the_walls([replace(s, mount=Pose2(0.0, 0.0, 0.0)) for s in scans])
    assert np.median(unmounted) > 0.1


ROOM = np.array([[0, 0, 6, 0], [6, 0, 6, 4], [6, 4, 0, 4], [0, 4, 0, 0]], dtype=float)
"""A 6 m × 4 m room's walls, world frame."""
WALKER = np.array([2.5, 2.6, 3.0, 2.6])
"""A person walking by, seen by one scan only."""
STANDER = np.array([4.3, 2.9, 4.7, 3.2])
"""A person standing while the robot takes three scans from two poses."""


def _room_with_people():
    """Noise-free scans of ``ROOM`` with people in it, and their survey: (log, survey).

    Three surveyed poses; the second holds two scans 20 ms apart (both pair with its row).
    ``WALKER`` is in the first scan only, ``STANDER`` in the last three: the walls are seen
    from three poses, the stander from two, the walker from one.
    """
    from segloc_cli.estimates import PoseTable
    from segloc_cli.io.log import Log
    from segloc_cli.sim import NOISE_FREE, simulate_scan
    from segloc_cli.world import World

    poses = np.array([[1.5, 1.5, 0.0], [3.0, 1.2, 0.5], [4.5, 1.5, -0.3]])
    shots = [(0.0, 0, WALKER), (1.0, 1, STANDER), (1.02, 1, STANDER), (2.0, 2, STANDER)]
    rng = np.random.default_rng(0)
    scans = [simulate_scan(World(np.vstack([ROOM, person])), Pose2(*poses[k]), NOISE_FREE, rng, t)
             for t, k, person in shots]  # fmt: skip
    log = Log(scans, np.array([t for t, _, _ in shots]), np.zeros(0), np.zeros((0, 3)), {})
    return log, PoseTable(np.arange(1, 4), np.array([0.0, 1.0, 2.0]), poses)


def _on(segments: np.ndarray, world: np.ndarray) -> np.ndarray:
    """Index (M,) of the world segment each segment lies on (within 3 cm at both ends)."""
    from segloc_cli.geometry import point_segment_distances

    ends = np.vstack([segments[:, :2], segments[:, 2:]])
    d = point_segment_distances(ends, world).reshape(2, len(segments), len(world)).max(axis=0)
    assert np.all(d.min(axis=1) < 0.03), d
    return d.argmin(axis=1)


@pytest.mark.parametrize(
    ("min_observations", "kept", "dropped"),
    [(1, [0, 1, 2, 3, 4, 5], []), (2, [0, 1, 2, 3, 5], [4]), (3, [0, 1, 2, 3], [4, 5])],
)
def test_map_build_keeps_the_walls_and_drops_what_few_poses_saw(min_observations, kept, dropped):
    """Walls seen from three poses stay; a passer-by seen from one pose goes at 2, a person
    standing through three scans from two poses at 3 (two scans from one pose are one
    view)."""
    from dataclasses import replace
    from pathlib import Path

    from segloc_cli.config import Config
    from segloc_cli.runs.pipeline import build_map

    log, survey = _room_with_people()
    config = replace(Config(), fuse=FuseParams(min_observations=min_observations))
    built = build_map(log, Path("log.mcap"), survey, Path("survey.csv"), config)
    world = np.vstack([ROOM, WALKER, STANDER])
    assert sorted(_on(built.segments, world).tolist()) == kept
    assert sorted(_on(built.dropped, world).tolist()) == dropped


def test_map_build_refuses_to_drop_every_segment():
    from dataclasses import replace
    from pathlib import Path

    from segloc_cli.config import Config
    from segloc_cli.errors import InputError
    from segloc_cli.runs.pipeline import build_map

    log, survey = _room_with_people()
    config = replace(Config(), fuse=FuseParams(min_observations=4))
    with pytest.raises(InputError, match="no segment was seen from 4 surveyed poses"):
        build_map(log, Path("log.mcap"), survey, Path("survey.csv"), config)


def _map_builder(tmp_path, capsys, log, survey, range_max_m: float):
    """``log`` and ``survey`` written into ``tmp_path``, and a function that runs ``segloc map
    build`` of them with extra options and returns (its stderr, the map file read back)."""
    import json

    from segloc_cli.cli import main
    from segloc_cli.io.mcap_log import LogWriter
    from segloc_cli.io.tables import write_pose_table

    log_path, survey_path = tmp_path / "log.mcap", tmp_path / "survey.csv"
    with LogWriter(log_path, {"range_max_m": f"{range_max_m:g}"}) as writer:
        for scan in log.scans:
            writer.add_scan(scan)
    write_pose_table(survey_path, survey)

    def build(*options) -> tuple[str, dict]:
        out = tmp_path / "map.json"
        main(["map", "build", str(log_path), "--survey", str(survey_path), "--out", str(out),
              "--force", *options])  # fmt: skip
        return capsys.readouterr().err, json.loads(out.read_text())

    return build


def test_map_build_says_what_it_dropped(tmp_path, capsys):
    """``--min-observations`` drops what too few poses saw; the summary line and the map
    file's source say how many segments; without it every segment is kept."""
    build = _map_builder(tmp_path, capsys, *_room_with_people(), range_max_m=30.0)
    err, built = build("--min-observations", "3")
    assert "2 segments (1.0 m) seen from fewer than 3 surveyed poses dropped" in err, err
    assert len(built["segments"]) == 4
    assert built["source"]["dropped_segments"] == 2
    assert built["source"]["fuse"]["min_observations"] == 3
    err, built = build()
    assert "dropped" not in err and len(built["segments"]) == 6, err
    assert built["source"]["dropped_segments"] == 0
    with pytest.raises(SystemExit) as exc:
        build("--min-observations", "0")
    assert exc.value.code == 2
    assert "--min-observations" in capsys.readouterr().err


HALLWAY = np.array([[0, 0, 14, 0], [14, 0, 14, 4], [14, 4, 0, 4], [0, 4, 0, 0]], dtype=float)
"""A 14 m × 4 m hallway's walls, world frame."""
PASSER_BY = np.array([8.0, 0.4, 8.0, 1.0])
"""A person by the south wall, in the first scan only."""
HALLWAY_POSES = np.array([[12.5, 2.0, 0.0], [5.0, 3.0, 0.0], [4.0, 3.5, 0.0]])
"""Where the scans are taken: the first near the east end, the later ones 7–9 m west of it,
beyond the scanner's 8 m reach of the east wall but within reach of the wall behind the
person."""


def _hallway_with_a_passer_by(later_rows: list[int]):
    """Noise-free scans of ``HALLWAY`` by a scanner reaching 8 m, and their survey: (log,
    survey). The first scan, from ``HALLWAY_POSES[0]``, sees ``PASSER_BY``; one later scan
    per entry of ``later_rows`` is taken after they left, from ``HALLWAY_POSES[row]``, and
    pairs with that survey row (a row listed twice holds two scans)."""
    from dataclasses import replace

    from segloc_cli.estimates import PoseTable
    from segloc_cli.io.log import Log
    from segloc_cli.sim import NOISE_FREE, simulate_scan
    from segloc_cli.world import World

    sensor = replace(NOISE_FREE, range_max_m=8.0)
    rows = sorted(set(later_rows))
    times = [0.0, *(float(row) + 0.02 * later_rows[:k].count(row) for k, row in
                    enumerate(later_rows))]  # fmt: skip
    rng = np.random.default_rng(0)
    worlds = [World(np.vstack([HALLWAY, PASSER_BY])), *[World(HALLWAY)] * len(later_rows)]
    scans = [simulate_scan(world, Pose2(*HALLWAY_POSES[row]), sensor, rng, t)
             for world, row, t in zip(worlds, [0, *later_rows], times, strict=True)]  # fmt: skip
    log = Log(scans, np.array(times), np.zeros(0), np.zeros((0, 3)), {})
    survey_rows = [0, *rows]
    survey = PoseTable(
        np.arange(1, len(survey_rows) + 1),
        np.array([float(r) for r in survey_rows]),
        HALLWAY_POSES[survey_rows],
    )
    return log, survey


@pytest.mark.parametrize(
    ("later_rows", "passer_by_dropped"),
    [([1, 2], True), ([1], False), ([1, 1], False)],
    ids=["seen-through-by-two-poses", "by-one-pose", "by-two-scans-from-one-pose"],
)
def test_map_build_drops_what_more_poses_see_through_than_saw(later_rows, passer_by_dropped):
    """The passer-by, seen from the first pose, goes when two later poses see the wall behind
    where they stood, and stays when one pose does (one view against one), however many
    scans it took there. The walls stay, seen through by none: the south wall seen from
    every pose, and the east wall seen from the first pose only (the later ones are out of
    reach of it)."""
    from dataclasses import replace
    from pathlib import Path

    from segloc_cli.config import Config
    from segloc_cli.runs.pipeline import build_map

    log, survey = _hallway_with_a_passer_by(later_rows)
    config = replace(Config(), fuse=FuseParams(seen_through="drop"))
    built = build_map(log, Path("log.mcap"), survey, Path("survey.csv"), config)
    world = np.vstack([HALLWAY, PASSER_BY])
    if passer_by_dropped:
        assert sorted(_on(built.segments, world).tolist()) == [0, 1, 2, 3]
        assert _on(built.dropped, world).tolist() == [4]
        assert built.dropped_seen_through.tolist() == [True]
    else:
        assert sorted(_on(built.segments, world).tolist()) == [0, 1, 2, 3, 4]
        assert built.dropped.shape == (0, 4)
    kept = build_map(log, Path("log.mcap"), survey, Path("survey.csv"), Config())
    assert sorted(_on(kept.segments, world).tolist()) == [0, 1, 2, 3, 4]


def test_a_segment_goes_when_free_space_over_most_of_its_interior():
    """The free metres are weighed against the interior, the segment less 6 cm at either end,
    where a fused end that overshoots a corner would be seen past."""
    from segloc_cli.maps.carving import free_length, mostly_free

    walls = np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 1.0, 0.3, 1.0], [0.0, 2.0, 0.1, 2.0]])
    free_m = np.array([0.45, 0.10, 0.0])  # interiors 0.88, 0.18 and none
    assert mostly_free(walls, free_m, 0.06).tolist() == [True, True, False]
    assert mostly_free(walls, np.array([0.44, 0.09, 0.0]), 0.06).tolist() == [False] * 3
    with pytest.raises(ValueError, match="1 viewpoints for 2 scans"):
        free_length(walls, np.ones(3), [np.zeros((0, 2))] * 2, [Pose2(0, 0, 0)] * 2,
                    np.array([0]), 0.06, 0.3)  # fmt: skip


def test_map_build_refuses_to_drop_every_segment_as_seen_through():
    """A scan that saw only the passer-by, and two later ones whose beams run on through
    where they stood, to points 1 m and 2 m behind by turns (too ragged for a segment of
    their own): nothing would be left."""
    from dataclasses import replace
    from pathlib import Path

    from segloc_cli.config import Config
    from segloc_cli.errors import InputError
    from segloc_cli.estimates import PoseTable
    from segloc_cli.io.log import Log
    from segloc_cli.runs.pipeline import build_map
    from segloc_cli.scan import Scan
    from segloc_cli.sim import NOISE_FREE, simulate_scan
    from segloc_cli.world import World

    poses = HALLWAY_POSES
    first = simulate_scan(World(PASSER_BY[None]), Pose2(*poses[0]), NOISE_FREE,
                          np.random.default_rng(0), 0.0)  # fmt: skip
    later = []
    for k in (1, 2):
        through = np.column_stack([np.full(9, 8.0), np.linspace(0.45, 0.95, 9)]) - poses[k, :2]
        reach = (np.tile([1.0, 2.0], 5)[:9] + 8.0 - poses[k, 0]) / through[:, 0]
        angles, ranges = np.arctan2(through[:, 1], through[:, 0]), reach * np.hypot(*through.T)
        later.append(Scan(float(k), angles, ranges, 30.0))
    log = Log([first, *later], np.array([0.0, 1.0, 2.0]), np.zeros(0), np.zeros((0, 3)), {})
    survey = PoseTable(np.arange(1, 4), np.array([0.0, 1.0, 2.0]), poses)
    config = replace(Config(), fuse=FuseParams(seen_through="drop"))
    with pytest.raises(InputError, match="every segment is seen through"):
        build_map(log, Path("log.mcap"), survey, Path("survey.csv"), config)


def test_map_build_says_what_it_dropped_as_seen_through(tmp_path, capsys):
    """The summary line says how many segments went, how long, and why, for each reason;
    the map file's source counts them; a choice --seen-through does not take is refused."""
    build = _map_builder(tmp_path, capsys, *_hallway_with_a_passer_by([1, 2]), range_max_m=8.0)
    err, built = build("--seen-through", "drop")
    note = "; 1 segment (0.6 m) seen through from more surveyed poses than saw them dropped"
    assert err.rstrip().endswith(note), err
    assert len(built["segments"]) == 4
    assert built["source"]["dropped_segments"] == built["source"]["dropped_seen_through"] == 1
    assert built["source"]["fuse"]["seen_through"] == "drop"
    # The passer-by and the east wall were seen from one pose: both go for that first.
    err, built = build("--seen-through", "drop", "--min-observations", "2")
    assert err.rstrip().endswith(
        "; 2 segments (4.6 m) seen from fewer than 2 surveyed poses dropped; 0 segments "
        "(0.0 m) seen through from more surveyed poses than saw them dropped"
    ), err
    assert built["source"]["dropped_seen_through"] == 0
    err, built = build()
    assert "dropped" not in err and len(built["segments"]) == 5, err
    with pytest.raises(SystemExit) as exc:
        build("--seen-through", "maybe")
    assert exc.value.code == 2
    assert "--seen-through" in capsys.readouterr().err


def _surveyed_room(seed: int, n: int = 24, error_m: float = 0.04, error_deg: float = 0.8):
    """Noise-free scans of a random room at ``n`` poses, their local maps, and surveyed poses
    off the truth by up to ``error_m`` per axis and ``error_deg``, as a SLAM solution is."""
    from segloc_cli.method.extract import extract_segments
    from segloc_cli.sim import NOISE_FREE, random_free_poses, random_world, simulate_scan

    rng = np.random.default_rng(seed)
    world = random_world(rng)
    truths = [Pose2(*p) for p in random_free_poses(world, n, rng)]
    scans = [simulate_scan(world, t, NOISE_FREE, rng, float(k)) for k, t in enumerate(truths)]
    errors = rng.uniform(-1, 1, (n, 3)) * [error_m, error_m, np.deg2rad(error_deg)]
    offsets = zip(truths, errors, strict=True)
    surveyed = [Pose2(t.x + e[0], t.y + e[1], t.theta + e[2]) for t, e in offsets]
    local_maps = [extract_segments(s) for s in scans]
    return truths, surveyed, local_maps, [s.points() for s in scans]


def _relative_errors(poses, truths) -> np.ndarray:
    """Mean position (m) and heading (rad) error of ``poses`` after the mean error of all of
    them is taken out: how far they disagree with each other, which is what blurs a map (a
    common offset only moves the map's frame)."""
    d = np.array([(p.x - t.x, p.y - t.y, wrap_angle(p.theta - t.theta))
                  for p, t in zip(poses, truths, strict=True)])  # fmt: skip
    d -= d.mean(axis=0)
    return np.array([np.hypot(d[:, 0], d[:, 1]).mean(), np.abs(d[:, 2]).mean()])


def test_polishing_brings_surveyed_poses_into_agreement():
    """Over eight rooms the poses' disagreement shrinks, on average, to under 0.8 of what was
    surveyed in position and 0.6 in heading (each room's own share varies: a room whose
    halves both err alike can even gain a little)."""
    shares = []
    for seed in range(100, 108):
        truths, surveyed, local_maps, points = _surveyed_room(seed)
        polished = polish_poses(local_maps, points, surveyed, FuseParams(polish_rounds=2))
        shares.append(_relative_errors(polished, truths) / _relative_errors(surveyed, truths))
    position, heading = np.mean(shares, axis=0)
    assert position < 0.8 and heading < 0.6


def test_polishing_keeps_poses_it_cannot_trust_and_zero_rounds_changes_nothing():
    _, surveyed, local_maps, points = _surveyed_room(63)
    assert polish_poses(local_maps, points, surveyed, FuseParams()) == surveyed
    far = list(surveyed)
    far[0] = Pose2(surveyed[0].x + 1.0, surveyed[0].y, surveyed[0].theta)  # a survey blunder
    polished = polish_poses(local_maps, points, far, FuseParams(polish_rounds=1))
    assert polished[0] == far[0]  # the fit would move it 1 m: over polish_max_shift_m
    with pytest.raises(ValueError, match="local maps"):
        polish_poses(local_maps[:-1], points, surveyed, FuseParams(polish_rounds=1))
