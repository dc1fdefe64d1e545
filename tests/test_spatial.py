"""The segment grid finds exactly the segments a brute-force distance test finds, and stage 2
gives the same answer with it as without it."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from segloc_cli.geometry import Pose2, point_segment_distances
from segloc_cli.method.extract import extract_segments
from segloc_cli.method.kernels import point_segment_distance
from segloc_cli.method.localize import Localizer
from segloc_cli.method.overlap import coarse_to_fine
from segloc_cli.method.spatial import SegmentGrid, filed_within
from segloc_cli.sim import SensorModel, random_free_poses, random_world, simulate_scan
from segloc_cli.world import World

coordinate = st.floats(-60.0, 60.0, allow_nan=False)


@settings(deadline=None, max_examples=200)
@given(
    ends=st.lists(st.tuples(coordinate, coordinate, coordinate, coordinate), max_size=60),
    point=st.tuples(coordinate, coordinate),
    radius=st.floats(0.0, 50.0),
    cell=st.sampled_from([0.25, 1.0, 4.0, 30.0]),
)
def test_near_matches_brute_force(ends, point, radius, cell):
    segments = np.array(ends, dtype=float).reshape(-1, 4)
    grid = SegmentGrid(segments, cell_m=cell)
    expected = (
        np.flatnonzero(point_segment_distances(point, segments)[0] <= radius)
        if segments.shape[0]
        else np.zeros(0, dtype=np.int64)
    )
    np.testing.assert_array_equal(grid.near(point, radius), expected)


@settings(deadline=None, max_examples=200)
@given(
    ends=st.lists(st.tuples(coordinate, coordinate, coordinate, coordinate), max_size=40),
    points=st.lists(st.tuples(coordinate, coordinate), min_size=1, max_size=20),
    radius=st.floats(0.0, 20.0),
    cell=st.sampled_from([0.25, 1.0, 4.0, 30.0]),
    keep=st.integers(0, 2**40),
)
def test_batch_queries_match_brute_force(ends, points, radius, cell, keep):
    """``within``, ``nearest`` and ``mask_near`` pick exactly what testing every allowed
    segment with the same compiled distance does."""
    segments = np.array(ends, dtype=float).reshape(-1, 4)
    xy = np.array(points, dtype=float)
    grid = SegmentGrid(segments, cell_m=cell)
    allowed = ((keep >> (np.arange(segments.shape[0]) % 40)) & 1) == 1  # a random subset
    dist = np.array([[point_segment_distance(*p, *s) for s in segments] for p in xy])
    dist = dist.reshape(len(xy), segments.shape[0])
    within = (dist <= radius) & allowed
    offsets, listed = grid.within(xy, radius, allowed)
    _, _, listed_d = filed_within(grid.cells, grid.segments_world, allowed, xy, radius)
    index, nearest = grid.nearest(xy, radius, allowed)
    for i in range(len(xy)):
        found = listed[offsets[i] : offsets[i + 1]]
        np.testing.assert_array_equal(np.sort(found), np.flatnonzero(within[i]))
        np.testing.assert_array_equal(listed_d[offsets[i] : offsets[i + 1]], dist[i, found])
        np.testing.assert_array_equal(grid.mask_near(xy[i], radius), dist[i] <= radius)
        if not within[i].any():
            assert index[i] == -1 and nearest[i] == np.inf
            continue
        closest = np.where(within[i], dist[i], np.inf)
        assert nearest[i] == closest.min()
        assert index[i] == np.argmin(closest)  # the first of equally near ones


def test_batch_queries_from_nowhere_find_nothing():
    segments = np.array([[0.0, 0.0, 10.0, 0.0], [0.0, 5.0, 1.0, 5.0]])
    grid = SegmentGrid(segments, cell_m=2.0)
    points = np.array([[np.nan, 0.0], [np.inf, 1.0], [1e30, -1e30], [0.5, 4.9]])
    index, dist = grid.nearest(points, 1.0)
    assert index.tolist() == [-1, -1, -1, 1]
    assert dist[:3].tolist() == [np.inf] * 3 and dist[3] == pytest.approx(0.1)
    # An infinite radius reaches every segment from any finite point, however far.
    offsets, listed = grid.within(points, np.inf)
    assert offsets.tolist() == [0, 0, 0, 2, 4]
    assert sorted(listed[2:].tolist()) == [0, 1]
    assert grid.nearest(points, np.nan)[0].tolist() == [-1] * 4


def test_long_wall_is_found_from_its_middle():
    """A segment spanning many cells is filed in each, not only at its ends."""
    grid = SegmentGrid(np.array([[0.0, 0.0, 100.0, 0.0], [0.0, 50.0, 1.0, 50.0]]), cell_m=2.0)
    np.testing.assert_array_equal(grid.near([50.0, 1.0], 1.5), [0])
    np.testing.assert_array_equal(grid.candidates([50.0, 30.0], 1.0), np.zeros(0))
    np.testing.assert_array_equal(grid.near([500.0, 500.0], 10.0), np.zeros(0))


def test_cell_size_must_be_positive():
    with pytest.raises(ValueError, match="cell_m"):
        SegmentGrid(np.zeros((1, 4)), cell_m=0.0)


def test_stage2_with_the_index_equals_stage2_without():
    """On nine generated rooms side by side, indexed stage 2 repeats the unindexed one exactly."""
    rooms = [random_world(np.random.default_rng(700 + k)) for k in range(9)]
    segments = np.concatenate(
        [room.segments + [25.0 * (k % 3), 20.0 * (k // 3)] * 2 for k, room in enumerate(rooms)]
    )
    block = World(segments, np.full(segments.shape[0], "wall"), "rooms")
    localizer = Localizer.on_map(segments)
    grid = localizer.prepared.index
    p = localizer.params
    tuning = dict(
        grid_m=p.grid_m,
        dtheta_deg=p.dtheta_deg,
        iterations=p.iterations,
        ratio=p.ratio,
        recentres=p.recentres,
    )
    rng = np.random.default_rng(9)
    for x, y, theta in random_free_poses(rooms[4], 6, rng):
        truth = Pose2(x + 25.0, y + 20.0, theta)  # in the middle room
        local = extract_segments(simulate_scan(block, truth, SensorModel(), rng, 0.0))
        guess = Pose2(truth.x + 0.8, truth.y - 0.6, truth.theta + 0.1)
        plain = coarse_to_fine(segments, local, guess, **tuning)
        indexed = coarse_to_fine(segments, local, guess, **tuning, index=grid)
        assert indexed.pose == plain.pose
        assert indexed.overlap_m == plain.overlap_m
        np.testing.assert_array_equal(indexed.track, plain.track)
        assert np.hypot(plain.pose.x - truth.x, plain.pose.y - truth.y) < 0.05


def test_grid_of_long_diagonals_grows_its_cells_and_still_finds_them(monkeypatch):
    """Long diagonal segments fill the cells of their whole bounding box; past the filing
    budget the cells grow, and queries still find exactly the segments in reach."""
    import segloc_cli.method.spatial as spatial

    monkeypatch.setattr(spatial, "MAX_FILED", 500)
    diagonals = np.array([[0.0, k, 100.0, 100.0 + k] for k in range(0, 20, 2)], dtype=float)
    grid = SegmentGrid(diagonals, cell_m=1.0)
    # Filed entries: 1 m cells 10 × 101², ..., 16 m cells 504, 32 m cells 160.
    assert grid.cell_m == 32.0
    for point in ([50.0, 50.0], [0.0, 19.0], [90.0, 10.0]):
        expected = np.flatnonzero(point_segment_distances(point, diagonals)[0] <= 3.0)
        np.testing.assert_array_equal(grid.near(point, 3.0), expected)


def test_queries_from_nowhere_find_nothing_and_an_infinite_radius_finds_all():
    segments = np.array([[0.0, 0.0, 10.0, 0.0], [0.0, 5.0, 1.0, 5.0]])
    grid = SegmentGrid(segments, cell_m=2.0)
    assert grid.near([np.nan, 0.0], 1.0).size == 0
    assert grid.near([0.0, 0.0], np.nan).size == 0
    assert grid.near([1e30, -1e30], 5.0).size == 0
    assert grid.near([0.0, 0.0], np.inf).tolist() == [0, 1]
    assert grid.near([0.0, 0.0], 1e300).tolist() == [0, 1]
