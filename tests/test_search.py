"""Score rasters, the hypothesis search and global localization."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from segloc_cli.config import SearchParams
from segloc_cli.estimates import STATUS_AMBIGUOUS, STATUS_OK, STATUS_TOO_FEW_SEGMENTS
from segloc_cli.geometry import Pose2, point_segment_distances, rotation, wrap_angle
from segloc_cli.method.extract import extract_segments
from segloc_cli.method.localize import LocalizeParams, Localizer
from segloc_cli.method.score_raster import (
    BOUND_LEVELS,
    cell_indices,
    level_shift,
    max_pyramid,
    phase_split,
    pyramid_cells,
    pyramid_depth,
    score_raster,
)
from segloc_cli.method.search import (
    MIN_TOP_LEVEL,
    HypothesisSearch,
    Pruning,
    SearchGrid,
    _batches,
    _best_first,
    _climbed,
    _collect,
    _collect_parallel,
    _count_bounds,
    _exact_sum,
    _merge_heading,
    _merged_room,
    _point_cells,
    _Poses,
    _quarter_bounds,
    _segment_samples,
    _shadowed,
    _top_bounds,
    _within_disk,
    distinct,
)
from segloc_cli.sim import NOISE_FREE, random_free_poses, random_world, simulate_scan
from segloc_cli.world import World


def _errors(pose: Pose2, truth: Pose2) -> tuple[float, float]:
    """Position (m) and heading (°) error."""
    return (
        float(np.hypot(pose.x - truth.x, pose.y - truth.y)),
        abs(float(np.rad2deg(wrap_angle(pose.theta - truth.theta)))),
    )


def test_score_raster_values_by_hand():
    raster = score_raster(np.array([[0.0, 0.0, 1.0, 0.0]]), cell_m=0.05, radius_m=0.1, margin_m=0.2)
    np.testing.assert_allclose(raster.origin, [-0.2, -0.2])
    points = np.array([[0.5, 0.0], [0.5, 0.05], [0.5, -0.1], [1.05, 0.0], [0.5, 0.3], [9.0, 9.0]])
    # On the wall 1; 5 cm away 1 − 0.25; at the radius and beyond 0; 5 cm past its end 0.75;
    # outside the raster 0.
    np.testing.assert_allclose(raster.lookup(points), [1.0, 0.75, 0.0, 0.75, 0.0, 0.0], atol=1e-6)


@settings(max_examples=40, deadline=None)
@given(
    st.integers(min_value=1, max_value=4),
    st.integers(min_value=1, max_value=30),
    st.integers(min_value=1, max_value=30),
    st.integers(min_value=0, max_value=2**31),
)
def test_pyramid_bounds_every_shift_within_its_square(depth, nx, ny, seed):
    fine = np.random.default_rng(seed).random((nx, ny)).astype(np.float32)
    pyramid = max_pyramid(fine, depth)
    pad = 2**depth - 1
    assert pyramid.pad == pad and pyramid.depth == depth
    assert pyramid.values.size == pyramid_cells((nx, ny), depth)

    def best_over(b, c, side_x, side_y):
        square = fine[max(b, 0) : max(b + side_x, 0), max(c, 0) : max(c + side_y, 0)]
        return float(square.max()) if square.size else 0.0

    for level in range(1, depth + 1):
        side, stride = 2**level, 2 ** level_shift(level)
        for b in range(-pad, nx):
            for c in range(-pad, ny):
                bound = pyramid.bound(level, b, c)
                # An upper bound on the square from (b, c), and no looser than one 255th over
                # the widened square of the level cell holding it.
                q, r = (b + pad) // stride * stride - pad, (c + pad) // stride * stride - pad
                widened = best_over(q, r, side + stride - 1, side + stride - 1)
                assert best_over(b, c, side, side) <= bound <= widened + 1.0 / BOUND_LEVELS + 1e-6


def test_pyramid_levels_above_the_lag_keep_one_bound_per_stride():
    assert [level_shift(level) for level in range(1, 8)] == [0, 0, 1, 2, 3, 4, 5]
    pyramid = max_pyramid(np.zeros((100, 60), dtype=np.float32), 4)
    # Padded by 15 cells: 115 × 75 at strides 1, 1, 2 and 4.
    assert pyramid.shapes.tolist() == [[115, 75], [115, 75], [58, 38], [29, 19]]


def _exhaustive(search: HypothesisSearch, points, headings, centre, half_width_m):
    """Every (sum, heading index, x, y) of the search's grid, by brute force."""
    cell = search.fine.cell_m
    half = int(np.ceil(half_width_m / cell))
    start = np.asarray(centre) - half * cell
    n = 2 * half + 1
    rows = []
    for h, theta in enumerate(headings):
        world = points @ np.array([[np.cos(theta), np.sin(theta)], [-np.sin(theta), np.cos(theta)]])
        base = cell_indices((world + start - search.fine.origin) / cell)
        for x in range(n):
            for y in range(n):
                total = _exact_sum(search.fine.score, base[:, 0], base[:, 1], x, y)
                rows.append((total, h, x, y))
    return rows, start


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize(("max_depth", "half_width_m"), [(2, 0.4), (3, 0.4), (5, 0.35)])
def test_branch_and_bound_finds_what_brute_force_finds(seed, max_depth, half_width_m):
    """On small maps and windows, the best pose is the exhaustive maximum (same sum), and the
    runner-ups are exact sums, distinct, and no worse than keep_fraction of the best. The
    window of 17 shifts spans 5 × 5 top squares of level 2 or 3 × 3 of level 3 (points
    merged per level cell after sorting); of 15 shifts, 2 × 2 (only consecutive points
    merged)."""
    rng = np.random.default_rng(8100 + seed)
    world = random_world(rng)
    true = Pose2(*random_free_poses(world, 1, rng)[0])
    points = simulate_scan(world, true, NOISE_FREE, rng, 0.0).points()[::8]
    search = HypothesisSearch(world.segments, SearchParams(max_depth=max_depth))
    guess = np.array([true.x + rng.uniform(-0.3, 0.3), true.y + rng.uniform(-0.3, 0.3)])
    headings = true.theta + np.deg2rad(np.arange(-3.0, 3.5, 1.0))
    found = search.search(points, headings, guess, half_width_m)
    rows, start = _exhaustive(search, points, headings, guess, half_width_m)
    best = max(row[0] for row in rows)
    assert found[0].score * points.shape[0] == pytest.approx(best, rel=1e-12)
    sums = {(h, x, y): total for total, h, x, y in rows}
    for i, hyp in enumerate(found):
        h = int(np.argmin(np.abs(wrap_angle(headings - hyp.pose.theta))))
        x, y = np.rint((np.array([hyp.pose.x, hyp.pose.y]) - start) / search.fine.cell_m)
        assert hyp.score * points.shape[0] == pytest.approx(sums[(h, int(x), int(y))], rel=1e-12)
        assert hyp.score >= search.params.keep_fraction * found[0].score
        assert distinct([f.pose for f in found[:i]], hyp.pose, 0.3, 3.0)


@pytest.mark.parametrize("seed", range(4))
def test_global_search_finds_what_brute_force_finds(seed):
    """A search with a reach (as ``--global`` makes) starts from every square of level
    ``MIN_TOP_LEVEL`` at every heading, bounded in one pass: its best is the exhaustive
    maximum, and taking the squares one at a time or all at once finds the same poses."""
    rng = np.random.default_rng(8400 + seed)
    world = random_world(rng)
    true = Pose2(*random_free_poses(world, 1, rng)[0])
    points = simulate_scan(world, true, NOISE_FREE, rng, 0.0).points()[::8]
    search = HypothesisSearch(world.segments)
    centre = np.array([true.x + rng.uniform(-0.3, 0.3), true.y + rng.uniform(-0.3, 0.3)])
    headings = true.theta + np.deg2rad(np.arange(-4.0, 4.5, 1.0))
    half = 0.6  # 25 × 25 positions: 4 × 4 squares of 8 at level 3
    assert search._top_depth(25, headings.size) == MIN_TOP_LEVEL
    found = search.search(points, headings, centre, half, reach_m=100.0)
    rows, _ = _exhaustive(search, points, headings, centre, half)
    assert found[0].score * points.shape[0] == pytest.approx(max(r[0] for r in rows), rel=1e-12)
    one_by_one = search.search(points, headings, centre, half, reach_m=100.0, first_batch=1)
    assert [h.score for h in one_by_one] == [h.score for h in found]


@settings(max_examples=60, deadline=None)
@given(
    st.integers(min_value=1, max_value=40),
    st.integers(min_value=1, max_value=40),
    st.sampled_from([2, 4]),
    st.integers(min_value=1, max_value=9),
    st.integers(min_value=0, max_value=2**31),
)
def test_top_bounds_read_the_level_at_every_square(nx, ny, step, n_top, seed):
    """The one-pass bounds of every top square are the level's values summed over the
    merged points, read square by square (cells outside the level count 0)."""
    rng = np.random.default_rng(seed)
    level = rng.integers(0, BOUND_LEVELS + 1, (nx, ny)).astype(np.uint8)
    count = int(rng.integers(0, 12))
    cells = rng.integers(-3 * step * n_top, max(nx, ny) + 4, (count + 2, 2))
    weights = rng.integers(1, 50, count + 2).astype(np.int32)
    out = np.full((n_top, n_top), -7, dtype=np.int32)
    # Rows and columns from a random first to a random stop: 0 outside, as if left out.
    box = np.concatenate([np.sort(rng.integers(0, n_top + 1, 2)) for _ in range(2)])
    _top_bounds(phase_split(level, step), cells, weights, count, out, box)
    expected = np.zeros((n_top, n_top), dtype=np.int64)
    for a in range(n_top):
        for b in range(n_top):
            for (ci, cj), w in zip(cells[:count], weights[:count], strict=True):
                i, j = ci + a * step, cj + b * step
                inside = box[0] <= a < box[1] and box[2] <= b < box[3]
                if 0 <= i < nx and 0 <= j < ny and inside:
                    expected[a, b] += w * int(level[i, j])
    np.testing.assert_array_equal(out, expected)


@settings(max_examples=60, deadline=None)
@given(
    st.integers(min_value=1, max_value=25),
    st.integers(min_value=1, max_value=25),
    st.floats(min_value=0.0, max_value=9.0),
    st.integers(min_value=0, max_value=2**31),
)
def test_within_disk_is_a_distance_check(na, nb, radius, seed):
    occupied = np.random.default_rng(seed).random((na, nb)) < 0.05
    near = _within_disk(occupied, radius, 0)
    # With a rim, the same answer for the cells inside it.
    rim = min(na, nb) // 3
    np.testing.assert_array_equal(
        _within_disk(occupied, radius, rim), near[rim : na - rim, rim : nb - rim]
    )
    grid = np.stack(np.meshgrid(np.arange(na), np.arange(nb), indexing="ij"), -1).reshape(-1, 2)
    marked = grid[occupied.ravel()]
    if marked.size == 0:
        assert not near.any()
        return
    gap = np.hypot(*(grid[:, None, :] - marked[None, :, :]).transpose(2, 0, 1)).min(axis=1)
    # Exactly the cells within the radius, but for round-off right at it.
    assert np.all(near.ravel()[gap <= radius - 1e-9])
    assert not np.any(near.ravel()[gap > radius + 1e-9])


def test_batches_take_the_best_bins_first_and_grow():
    tally = np.array([5, 0, 3, 9, 1, 2, 4])
    # From the best bin down: 4 ≥ 3 held; then 2 + 1 + 9 ≥ 12; the rest at the last bin.
    assert _batches(tally, 3).tolist() == [[6, 6], [3, 5], [0, 2]]
    assert _batches(tally, 100).tolist() == [[0, 6]]


@pytest.mark.parametrize("whole", [True, False])
def test_batches_list_the_best_bound_first_and_equal_bounds_in_order(whole):
    top = np.array([5, 7, 5, 7, 3, 7, 5], dtype=np.int32 if whole else np.float64)
    members = np.arange(top.size)
    assert _best_first(top, members).tolist() == [1, 3, 5, 0, 2, 6, 4]
    assert _best_first(top, members[[0, 2, 4]]).tolist() == [0, 2, 4]
    # Squares of clutter: many equal bounds, which keep their order.
    saturated = np.full(50_000, 9, dtype=top.dtype)
    saturated[::7] = 8
    order = _best_first(saturated, np.arange(saturated.size))
    expected = np.concatenate([np.flatnonzero(saturated == 9), np.flatnonzero(saturated == 8)])
    np.testing.assert_array_equal(order, expected)


@pytest.mark.parametrize("seed", range(3))
def test_batches_collect_exactly_the_squares_of_their_bins_in_order(seed):
    rng = np.random.default_rng(8700 + seed)
    unit, n_h, n_top = BOUND_LEVELS, 7, 9
    top = rng.integers(-1, 6 * unit, size=(n_h, n_top * n_top)).astype(np.int32)
    counts = np.zeros((n_h, 8), dtype=np.int32)
    for h in range(n_h):
        _count_bounds(top[h].reshape(n_top, n_top), unit, counts[h])
    flat = top.reshape(-1)
    assert counts.sum() == np.count_nonzero(flat >= 0)
    for low, high in [(5, 5), (2, 4), (0, 7)]:
        expected = np.flatnonzero((flat >= low * unit) & (flat < (high + 1) * unit))
        assert _collect(top, counts, low, high, unit).tolist() == expected.tolist()
        assert _collect_parallel(top, counts, low, high, unit).tolist() == expected.tolist()


def _global_grid(seed: int):
    """A search of a random room at a few headings around a scan's true one, as a global
    search makes it (``SearchGrid`` at level ``MIN_TOP_LEVEL``), its points merged."""
    rng = np.random.default_rng(8800 + seed)
    world = random_world(rng)
    true = Pose2(*random_free_poses(world, 1, rng)[0])
    points = simulate_scan(world, true, NOISE_FREE, rng, 0.0).points()[::4]
    search = HypothesisSearch(world.segments)
    headings = true.theta + np.deg2rad(np.arange(-6.0, 6.5, 1.0))
    start = np.array([true.x, true.y]) - 1.6
    cos_sin = np.column_stack([np.cos(headings), np.sin(headings)])
    ix, iy = _point_cells(points, cos_sin, start, search.fine.origin, search.fine.cell_m)
    grid = SearchGrid(headings, ix, iy, 65, MIN_TOP_LEVEL, search.fine.cell_m)
    pyramid = search.pyramid.arrays(search.fine.score, search._phased(MIN_TOP_LEVEL))
    merged, shapes = _merged_room(pyramid, grid)
    for h in range(headings.size):
        _merge_heading(pyramid, grid, True, shapes, merged, h)
    return points, pyramid, grid, merged


@pytest.mark.parametrize("seed", range(3))
def test_quarters_checked_part_way_are_dropped_only_when_none_can_beat_the_threshold(seed):
    points, pyramid, grid, merged = _global_grid(seed)
    full, part = np.zeros(4), np.zeros(4)
    step, checked, dropped = 2**MIN_TOP_LEVEL, 0, 0
    for h in range(grid.headings.size):
        for x in range(0, grid.n_cells, step):
            for y in range(0, grid.n_cells, step):
                level = MIN_TOP_LEVEL
                assert _quarter_bounds(pyramid, grid, merged, h, level, x, y, full, -np.inf)
                for share in (0.3, 0.6, 0.9):
                    threshold = share * points.shape[0]
                    if _quarter_bounds(pyramid, grid, merged, h, level, x, y, part, threshold):
                        assert part.tolist() == full.tolist()
                    else:
                        dropped += 1
                        assert full.max() <= threshold
                        assert part.max() <= threshold
                    checked += 1
    assert 0 < dropped < checked


NO_PYRAMID = pytest.mark.xdist_group("no-pyramid")
"""The tests of a search without a pyramid, on one worker: its kernels take float64 bounds,
which only ``warmup --all`` (``make kernels``) compiles ahead; where that cache does not hold
them (an edited module), the first such test compiles them for the others."""


@NO_PYRAMID
@pytest.mark.parametrize("max_depth", [0, 1, 2])
def test_a_search_on_threads_of_few_levels_finds_what_it_finds_on_one(max_depth):
    """With no pyramid, or one whose top squares' quarters are single shifts or squares of
    the first level, threads find the same poses as one thread."""
    rng = np.random.default_rng(9000 + max_depth)
    world = random_world(rng)
    true = Pose2(*random_free_poses(world, 1, rng)[0])
    points = simulate_scan(world, true, NOISE_FREE, rng, 0.0).points()[::8]
    search = HypothesisSearch(world.segments, SearchParams(max_depth=max_depth))
    headings = true.theta + np.deg2rad(np.arange(-3.0, 3.5, 1.0))
    centre = np.array([true.x, true.y])
    runs = [
        search.search(points, headings, centre, 0.3, 30.0, first_batch=1, threads=threads)
        for threads in (False, True)
    ]
    assert runs[0] == runs[1]
    assert runs[0][0].score > 0.9


@pytest.mark.parametrize("seed", range(3))
def test_global_search_on_threads_finds_what_it_finds_on_one(seed):
    """Threads bound the headings, collect the batches and drop the top squares none of
    whose quarters beat the threshold: the same poses as one thread taking them one by one,
    with a batch of one square first so that almost all come after it."""
    rng = np.random.default_rng(8900 + seed)
    world = random_world(rng)
    true = Pose2(*random_free_poses(world, 1, rng)[0])
    points = simulate_scan(world, true, NOISE_FREE, rng, 0.0).points()[::4]
    search = HypothesisSearch(world.segments)
    headings = np.deg2rad(np.arange(0.0, 360.0, 2.0))
    centre, half = search.extent()
    one = search.search(points, headings, centre, half, 30.0, first_batch=1, threads=False)
    many = search.search(points, headings, centre, half, 30.0, first_batch=1, threads=True)
    assert many == one
    assert len(one) >= 1


@pytest.mark.parametrize("seed", range(4))
def test_global_search_keeps_every_square_within_reach_of_the_map(seed):
    rng = np.random.default_rng(8300 + seed)
    world = random_world(rng)
    search = HypothesisSearch(world.segments)
    centre, half = search.extent()
    reach = float(rng.uniform(0.5, 6.0))
    depth = int(rng.integers(2, 6))
    cell = search.fine.cell_m
    n_cells = 2 * int(np.ceil((half + 8.0) / cell)) + 1  # beyond the map on every side
    start = centre - (half + 8.0)
    mask = search._reachable(start, n_cells, depth, reach)
    side = 2**depth * cell
    n_top = mask.shape[0]
    corners = start + side * np.stack(
        np.meshgrid(np.arange(n_top), np.arange(n_top), indexing="ij"), axis=-1
    ).reshape(-1, 2)
    nearest = point_segment_distances(corners + side / 2.0, world.segments).min(axis=1)
    # Every square with a point within reach of a segment is searched; squares far beyond
    # the reach (by more than the margin the coarse check allows) are not.
    within = nearest <= reach + side / np.sqrt(2.0)
    assert np.all(mask.ravel()[within])
    assert not np.any(mask.ravel()[nearest > reach + side * (2.0 * np.sqrt(2.0) + 0.5)])
    assert within.sum() < mask.size  # the map's surroundings are partly out of reach


def test_segment_samples_are_no_farther_apart_than_asked():
    segments = np.array([[0.0, 0.0, 1.0, 0.0], [2.0, 2.0, 2.0, 2.0], [np.nan, 0.0, 1.0, 1.0]])
    samples = _segment_samples(segments, 0.3)
    # 1 m in four pieces of 0.25 m (five points), and the zero-length segment's one point;
    # the segment that is not finite gives none.
    np.testing.assert_allclose(
        samples, [[0.0, 0.0], [0.25, 0.0], [0.5, 0.0], [0.75, 0.0], [1.0, 0.0], [2.0, 2.0]]
    )


def test_distinct_poses():
    a = Pose2.from_deg(0.0, 0.0, 0.0)
    assert not distinct([a], Pose2.from_deg(0.2, 0.2, 2.0), 0.3, 3.0)
    assert distinct([a], Pose2.from_deg(0.3, 0.3, 0.0), 0.3, 3.0)
    assert distinct([a], Pose2.from_deg(0.0, 0.0, 4.0), 0.3, 3.0)
    assert not distinct([a], Pose2.from_deg(0.0, 0.0, 359.0), 0.3, 3.0)


@pytest.mark.parametrize("seed", [7101, 7202])
def test_search_ranks_the_true_pose_first_from_far_off(seed):
    """From 1.8 m and 18° away, the best grid pose lies within a cell and a degree of the truth."""
    rng = np.random.default_rng(seed)
    world = random_world(rng)
    search = HypothesisSearch(world.segments)
    for truth in random_free_poses(world, 4, rng):
        true = Pose2(*truth)
        points = simulate_scan(world, true, NOISE_FREE, rng, 0.0).points()
        sign = rng.choice([-1.0, 1.0], 3)
        guess = Pose2(true.x + sign[0] * 1.8, true.y + sign[1] * 1.8, true.theta + sign[2] * 0.314)
        best = search.around(points, guess, 20.0)[0]
        position, heading = _errors(best.pose, true)
        assert position <= 0.05 and heading <= 1.0
        assert best.score > 0.9


@pytest.mark.parametrize("seed", [7303, 7404])
def test_global_localization_in_a_world_without_symmetry(seed):
    rng = np.random.default_rng(seed)
    world = random_world(rng)
    localizer = Localizer.on_map(world.segments, global_search=True)
    for truth in random_free_poses(world, 3, rng):
        true = Pose2(*truth)
        scan = simulate_scan(world, true, NOISE_FREE, rng, 0.0)
        est = localizer.localize_global(extract_segments(scan), scan.points())
        position, heading = _errors(est.pose, true)
        assert position < 1e-3 and heading < 0.01
        assert est.status == STATUS_OK
        assert est.inlier_ratio == pytest.approx(1.0)


def test_global_localization_with_too_few_segments_keeps_the_pose_but_not_the_trust():
    """A local map too small for the two stages does not stop the search: the points find the
    pose, which the row keeps, but the status says the scan was too poor to trust it."""
    rng = np.random.default_rng(5)
    world = random_world(rng)
    true = Pose2(*random_free_poses(world, 1, rng)[0])
    scan = simulate_scan(world, true, NOISE_FREE, rng, 0.0)
    local = extract_segments(scan)
    localizer = Localizer.on_map(
        world.segments, LocalizeParams(min_segments=local.shape[0] + 1), global_search=True
    )
    est = localizer.localize_global(local, scan.points())
    position, heading = _errors(est.pose, true)
    assert position < 1e-3 and heading < 0.01
    assert est.status == STATUS_TOO_FEW_SEGMENTS
    assert np.isnan(est.align_theta_rad)  # stage 1 did not run


def test_global_localization_in_a_symmetric_room_is_ambiguous():
    """A bare 8 m × 5 m room looks the same from a pose and its half-turn about the centre."""
    corners = np.array([[0.0, 0.0], [8.0, 0.0], [8.0, 5.0], [0.0, 5.0]])
    room = World(np.hstack([corners, np.roll(corners, -1, axis=0)]))
    true = Pose2.from_deg(2.5, 1.5, 30.0)
    twin = Pose2.from_deg(8.0 - 2.5, 5.0 - 1.5, 30.0 - 180.0)
    scan = simulate_scan(room, true, NOISE_FREE, np.random.default_rng(1), 0.0)
    localizer = Localizer.on_map(room.segments, global_search=True)
    est = localizer.localize_global(extract_segments(scan), scan.points())
    assert est.status == STATUS_AMBIGUOUS
    found = sorted([est.pose, est.runner_up], key=lambda pose: _errors(pose, true)[0])
    for pose, expected in zip(found, (true, twin), strict=True):
        position, heading = _errors(pose, expected)
        assert position < 1e-3 and heading < 0.01
    assert est.runner_up_ratio == pytest.approx(est.inlier_ratio)


def test_distance_raster_visits_every_cell_within_reach():
    """Walking each segment column by column gives the distances of a full scan of the grid."""
    rng = np.random.default_rng(3)
    segments = np.vstack(
        [
            rng.uniform(0.0, 6.0, (12, 4)),
            [[1.0, 1.0, 1.0, 5.0], [0.5, 2.0, 5.5, 2.0], [3.0, 3.0, 3.0 + 1e-12, 4.0]],
        ]
    )
    raster = score_raster(segments, cell_m=0.05, radius_m=0.1, margin_m=0.1)
    nx, ny = raster.score.shape
    centres = raster.origin + 0.05 * np.stack(
        np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij"), axis=-1
    ).reshape(-1, 2)
    d = point_segment_distances(centres, segments).min(axis=1)
    expected = np.clip(1.0 - (np.minimum(d, 0.1).astype(np.float32) / 0.1) ** 2, 0.0, 1.0)
    np.testing.assert_allclose(raster.score.reshape(-1), expected, atol=2e-6)


def test_raster_past_its_cell_budget_takes_coarser_cells():
    wall = np.array([[0.0, 0.0, 10.0, 0.0]])
    raster = score_raster(wall, cell_m=0.05, radius_m=0.1, margin_m=0.1, max_cells=700)
    # 5 cm: 205 × 5 cells; 6.25 cm: 165 × 5; 7.8125 cm: 133 × 5 = 665.
    assert raster.score.shape == (133, 5)
    assert raster.cell_m == pytest.approx(0.05 * 1.25**2)
    # The radius grew with the cell (to 2 cells): one cell off the wall scores 1 − (1/2)².
    points = np.array([[5.0, 0.0], [5.0, raster.cell_m], [5.0, 3 * raster.cell_m]])
    np.testing.assert_allclose(raster.lookup(points), [1.0, 0.75, 0.0], atol=1e-6)


def test_lookup_of_points_that_are_not_finite_or_far_is_zero():
    raster = score_raster(np.array([[0.0, 0.0, 1.0, 0.0]]), cell_m=0.05, radius_m=0.1, margin_m=0.2)
    points = np.array([[np.nan, 0.0], [0.5, np.inf], [1e30, 0.0], [-1e300, 0.0], [0.5, 0.0]])
    np.testing.assert_array_equal(raster.lookup(points), [0.0, 0.0, 0.0, 0.0, 1.0])


def test_pyramid_of_a_huge_raster_gets_fewer_levels_not_more_memory():
    # Levels 1 and 2 of a 14,000² raster hold a cell per raster cell, level 3 one per four:
    # with padding of 2^depth − 1 cells, 2 · 14,003² < 4·10⁸ cells < 2.25 · 14,007².
    assert pyramid_depth((14_000, 14_000), 7) == 2
    assert pyramid_cells((14_000, 14_000), 2) == 2 * 14_003**2
    assert pyramid_depth((10_000, 10_000), 7) == 7
    assert pyramid_depth((100, 100), 0) == 0


@NO_PYRAMID
def test_search_with_no_pyramid_is_brute_force_and_finds_the_same_best():
    rng = np.random.default_rng(8200)
    world = random_world(rng)
    true = Pose2(*random_free_poses(world, 1, rng)[0])
    points = simulate_scan(world, true, NOISE_FREE, rng, 0.0).points()[::6]
    centre = np.array([true.x + 0.2, true.y - 0.1])
    headings = true.theta + np.deg2rad([-2.0, -1.0, 0.0, 1.0])
    flat = HypothesisSearch(world.segments, SearchParams(max_depth=0))
    deep = HypothesisSearch(world.segments)
    assert flat.pyramid.depth == 0
    best_flat = flat.search(points, headings, centre, 0.3)[0]
    best_deep = deep.search(points, headings, centre, 0.3)[0]
    assert best_flat == best_deep


@given(
    points=st.lists(
        st.tuples(
            st.floats(allow_nan=True, allow_infinity=True, width=64),
            st.floats(-40.0, 40.0),
        ),
        min_size=1,
        max_size=20,
    ),
    headings=st.lists(st.floats(-7.0, 7.0), min_size=1, max_size=5),
    start=st.tuples(st.floats(-1e3, 1e3), st.floats(-1e3, 1e3)),
)
@settings(max_examples=60, deadline=None)
def test_compiled_point_cells_are_what_numpy_gives(points, headings, start):
    """The search's compiled cell lookup equals rotating with ``geometry.rotation`` and
    ``score_raster.cell_indices``, cell for cell, for any points (NaN, infinite, far)."""
    points = np.array(points, dtype=float)
    origin, cell = np.array([-3.0, 2.5]), 0.05
    cos_sin = np.array([[np.cos(h), np.sin(h)] for h in headings])
    ix, iy = _point_cells(points, cos_sin, np.array(start), origin, cell)
    for k, h in enumerate(headings):
        with np.errstate(invalid="ignore", over="ignore"):
            expected = cell_indices((points @ rotation(h).T + np.array(start) - origin) / cell)
        np.testing.assert_array_equal(ix[k], expected[:, 0])
        np.testing.assert_array_equal(iy[k], expected[:, 1])


@pytest.mark.parametrize("seed", range(3))
def test_a_pose_known_beforehand_prunes_without_changing_the_best(seed):
    """Starting the pruning at a pose found already (stage 2's, right or wrong) finds the
    same best pose as a search that starts from nothing."""
    rng = np.random.default_rng(8300 + seed)
    world = random_world(rng)
    true = Pose2(*random_free_poses(world, 1, rng)[0])
    points = simulate_scan(world, true, NOISE_FREE, rng, 0.0).points()
    search = HypothesisSearch(world.segments)
    guess = Pose2(true.x + 0.8, true.y - 0.6, true.theta + 0.2)
    wrong = Pose2(guess.x - 1.0, guess.y + 0.5, guess.theta - 0.1)
    plain = search.around(points, guess, 20.0)
    for known in (true, wrong, Pose2(np.nan, 0.0, 0.0), Pose2(1e9, -1e9, 0.0)):
        assert search.around(points, guess, 20.0, known=known)[0] == plain[0]


@pytest.mark.parametrize("seed", range(4))
def test_the_climb_from_a_known_pose_ends_on_a_searched_pose_no_better_than_the_best(seed):
    """The lower bound the search prunes below is the exact sum of a grid pose it searches,
    at least the start's: were it above the best, the best would be pruned."""
    rng = np.random.default_rng(8400 + seed)
    world = random_world(rng)
    true = Pose2(*random_free_poses(world, 1, rng)[0])
    points = simulate_scan(world, true, NOISE_FREE, rng, 0.0).points()[::4]
    search = HypothesisSearch(world.segments)
    guess = np.array([true.x + rng.uniform(-0.2, 0.2), true.y + rng.uniform(-0.2, 0.2)])
    headings = true.theta + np.deg2rad(np.arange(-4.0, 4.5, 1.0))
    rows, start = _exhaustive(search, points, headings, guess, 0.3)
    sums = {(h, x, y): total for total, h, x, y in rows}
    n_cells = int(round(len(rows) / len(headings)) ** 0.5)
    cos_sin = np.column_stack([np.cos(headings), np.sin(headings)])
    ix, iy = _point_cells(points, cos_sin, start, search.fine.origin, search.fine.cell_m)
    for h, x, y in [(0, 0, 0), (len(headings) // 2, n_cells // 2, 3), (len(headings) - 1, 11, 2)]:
        climbed = _climbed(search.fine.score, ix, iy, h, x, y, n_cells)
        assert sums[(h, x, y)] <= climbed <= max(sums.values())
        assert climbed in set(sums.values())
    # From outside the searched square it keeps the start's own sum and climbs nowhere.
    outside = _exact_sum(search.fine.score, ix[0], iy[0], -50, -50)
    assert _climbed(search.fine.score, ix, iy, 0, -50, -50, n_cells) == outside


def test_a_square_is_shadowed_only_when_all_its_poses_are_near_a_kept_pose_as_good():
    """A square of shifts is passed over only if each of its poses would be dropped beside a
    kept pose (within 0.3 m at 5 cm cells and 3°) scoring at least the square's bound."""
    headings = np.deg2rad(np.arange(-10.0, 11.0, 1.0))
    kept = _Poses(
        sums=np.array([50.0, 30.0, 0.0]),
        h=np.array([10, 2, 0]),
        x=np.array([20, 60, 0]),
        y=np.array([20, 60, 0]),
    )
    no_points = np.zeros((headings.size, 0), dtype=np.int64)
    grid = SearchGrid(headings, no_points, no_points, n_cells=100, depth=0, cell=0.05)
    pruning = Pruning(k=3, keep=0.0, apart_m=0.3, apart_rad=np.deg2rad(3.0))

    def shadowed(h, x, y, span, bound, n_kept=2):
        return _shadowed(kept, n_kept, grid, pruning, h, x, y, span, bound)

    assert shadowed(10, 20, 20, 0, 50.0)  # the kept pose itself, no better: dropped
    assert not shadowed(10, 20, 20, 0, 50.5)  # a better one would replace it
    assert shadowed(13, 18, 18, 3, 49.0)  # 3°; corners (18..21)² within 0.3 m of (20, 20)
    assert not shadowed(14, 18, 18, 3, 49.0)  # 4° off
    # (16..22)²: corners 4 cells off each way (0.28 m); (15..21) × (16..22): 5 and 4 (0.32 m).
    assert shadowed(10, 16, 16, 6, 49.0) and not shadowed(10, 15, 16, 6, 49.0)
    # The second kept pose shadows what it beats near it; a third beyond n_kept counts not.
    assert shadowed(2, 59, 61, 1, 30.0) and not shadowed(2, 59, 61, 1, 31.0)
    assert not shadowed(0, 0, 0, 0, 0.0) and shadowed(0, 0, 0, 0, 0.0, n_kept=3)
