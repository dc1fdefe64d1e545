"""A uniform grid over a map's segments, to find those near a point without testing them all.

Large maps hold thousands of segments, of which a scan can see a few dozen.
Each segment is filed under every grid cell its bounding box touches; a
query for the segments within ``radius`` of a point gathers the cells of the
square around it, so it costs what the neighbourhood holds, not what the map
holds.

Refinement and the inlier measures ask the same question for every point of a
scan at once, within a few decimetres; they go through the compiled kernels
below, which walk the cells of the grid the same way (``SegmentGrid.nearest``,
``within``, ``mask_near``), best on a grid of fine cells (``NEAR_CELL_M``).
Their answers are exact: the cells only spare the segments that are too far.
"""

from __future__ import annotations

import numpy as np

from segloc_cli.geometry import as_segments, point_segment_distances
from segloc_cli.jit import njit
from segloc_cli.method.kernels import grown, list_if_within, point_segment_distance

DEFAULT_CELL_M = 4.0
"""Cell side: about a room's wall; small enough that a query's square holds little else."""

NEAR_CELL_M = 0.5
"""Cell side of a grid for what lies within a few decimetres of each point of a scan
(refinement's gates, the inlier band): a query's square then spans a handful of cells."""

QUERY_SLACK_M = 1e-6
"""Queries reach this much past their radius, against rounding at cell edges."""

MAX_FILED = 4_000_000
"""Most (segment, cell) entries the grid holds. A segment is filed under every cell of its
bounding box, so long diagonal segments fill many; past this the cells are made larger."""


class SegmentGrid:
    """Segments (M, 4), world frame, filed by the grid cells (side ``cell_m``) they touch."""

    def __init__(self, segments_world: np.ndarray, cell_m: float = DEFAULT_CELL_M):
        if not cell_m > 0.0:
            raise ValueError(f"cell_m must be > 0, got {cell_m}")
        self.segments_world = np.ascontiguousarray(as_segments(segments_world))
        self.cell_m = float(cell_m)
        self._cells: FiledCells | None = None
        self._everything: np.ndarray | None = None
        segments = self.segments_world
        if segments.shape[0] == 0:
            self._origin = np.zeros(2)
            self._shape = (1, 1)
            self._offsets = np.zeros(2, dtype=np.int64)
            self._members = np.zeros(0, dtype=np.int64)
            return
        lo = np.minimum(segments[:, 0:2], segments[:, 2:4])
        hi = np.maximum(segments[:, 0:2], segments[:, 2:4])
        self._origin = lo.min(axis=0)
        while True:
            first = self._cell_of(lo)
            last = self._cell_of(hi)
            span = last - first + 1
            counts = span[:, 0] * span[:, 1]
            shape = last.max(axis=0) + 1
            if counts.sum() <= MAX_FILED and shape[0] * shape[1] <= MAX_FILED:
                break
            self.cell_m *= 2.0
        self._shape = (int(shape[0]), int(shape[1]))
        owner = np.repeat(np.arange(segments.shape[0]), counts)
        k = np.arange(owner.size) - np.repeat(np.cumsum(counts) - counts, counts)
        ix = first[owner, 0] + k % span[owner, 0]
        iy = first[owner, 1] + k // span[owner, 0]
        cell = ix * self._shape[1] + iy
        order = np.argsort(cell, kind="stable")
        self._members = owner[order]
        n_cells = self._shape[0] * self._shape[1]
        self._offsets = np.searchsorted(cell[order], np.arange(n_cells + 1))

    def _cell_of(self, xy: np.ndarray) -> np.ndarray:
        # Clipped before the cast: a far (or infinite) point must not wrap around int64.
        cells = np.clip((np.asarray(xy, dtype=float) - self._origin) / self.cell_m, -1e15, 1e15)
        return np.floor(cells).astype(np.int64)

    def candidates(self, point_xy, radius_m: float) -> np.ndarray:
        """Sorted indices of the segments filed in the cells of the square ±``radius_m``.

        Every segment within ``radius_m`` of the point is among them (and some
        farther ones); the caller applies its own exact test.
        """
        centre = np.asarray(point_xy, dtype=float).reshape(2)
        reach = radius_m + QUERY_SLACK_M  # a segment exactly at the radius stays in
        if not (np.all(np.isfinite(centre)) and reach >= 0.0):
            # Nowhere (a NaN point or radius) is near nothing; an infinite radius holds all.
            if np.all(np.isfinite(centre)) and reach == np.inf:
                return np.arange(self.segments_world.shape[0])
            return np.zeros(0, dtype=np.int64)
        first = np.maximum(self._cell_of(centre - reach), 0)
        last = np.minimum(self._cell_of(centre + reach), np.array(self._shape) - 1)
        if np.any(last < first):
            return np.zeros(0, dtype=np.int64)
        ix = np.arange(first[0], last[0] + 1)
        rows = ix * self._shape[1]
        starts = self._offsets[rows + first[1]]
        stops = self._offsets[rows + last[1] + 1]  # cells of one column are contiguous
        lengths = stops - starts
        gathered = np.repeat(starts - np.cumsum(lengths) + lengths, lengths) + np.arange(
            lengths.sum()
        )
        return np.unique(self._members[gathered])

    def near(self, point_xy, radius_m: float) -> np.ndarray:
        """Sorted indices of the segments within ``radius_m`` (metres) of the point."""
        ids = self.candidates(point_xy, radius_m)
        if ids.size == 0:
            return ids
        distance = point_segment_distances(np.asarray(point_xy, float), self.segments_world[ids])
        return ids[distance[0] <= radius_m]

    @property
    def cells(self) -> FiledCells:
        """The grid as the compiled kernels take it: (origin (2,) m, cell side m, shape (2,),
        offsets (cells + 1,), members), the members of cell (ix, iy) being
        ``members[offsets[c]:offsets[c + 1]]`` with ``c = ix * shape[1] + iy``."""
        if self._cells is None:
            shape = np.array(self._shape, dtype=np.int64)
            self._cells = (self._origin, self.cell_m, shape, self._offsets, self._members)
        return self._cells

    def mask_all(self) -> np.ndarray:
        """Mask (M,) letting a query return every segment (one array, shared: do not edit)."""
        if self._everything is None:
            self._everything = np.ones(self.segments_world.shape[0], dtype=np.bool_)
        return self._everything

    def mask_near(self, point_xy, radius_m: float) -> np.ndarray:
        """Mask (M,) of the segments within ``radius_m`` (metres) of the point: ``near`` as a
        mask, compiled (its distances may differ from ``near``'s in the last bit)."""
        x, y = (float(v) for v in np.asarray(point_xy, dtype=float).reshape(2))
        return near_mask(self.cells, self.segments_world, x, y, float(radius_m))

    def nearest(
        self, points_world: np.ndarray, within_m: float, allowed: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Index (P,) of each point's nearest segment and its distance (P,) in metres, for
        the points (P, 2), world frame, that have one within ``within_m``; index -1 and
        distance inf for the others (and for points that are not finite).

        ``allowed`` (M,) bool restricts the segments considered. Among segments
        equally near, the lowest index wins, as in a scan of all segments in order.
        """
        points = np.ascontiguousarray(points_world, dtype=float).reshape(-1, 2)
        mask = self.mask_all() if allowed is None else allowed
        return nearest_filed(self.cells, self.segments_world, mask, points, float(within_m))

    def within(
        self, points_world: np.ndarray, radius_m: float, allowed: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per point (P, 2), world frame, the segments within ``radius_m`` (metres) of it, as
        CSR: offsets (P + 1,) into indices. A point's list is unordered, without repeats."""
        points = np.ascontiguousarray(points_world, dtype=float).reshape(-1, 2)
        mask = self.mask_all() if allowed is None else allowed
        return filed_within(self.cells, self.segments_world, mask, points, float(radius_m))[:2]


FiledCells = tuple[np.ndarray, float, np.ndarray, np.ndarray, np.ndarray]
"""``SegmentGrid.cells``: what the compiled queries below read of a grid."""


@njit(cache=True)
def _cell_index(scaled: float) -> np.int64:
    """Cell number of a coordinate already divided by the cell side; clipped before the cast
    as in ``SegmentGrid._cell_of``, so a far point cannot wrap around int64."""
    return np.int64(np.floor(min(max(scaled, -1e15), 1e15)))


@njit(cache=True)
def cell_span(cells, px: float, py: float, radius_m: float) -> tuple[int, int, int, int]:
    """Cells (ix0, ix1, iy0, iy1), bounds included, of the square ±``radius_m`` around the
    point (px, py), clipped to the grid: the cells ``SegmentGrid.candidates`` gathers.

    Empty (ix1 < ix0) for a point or radius that is not finite, but an infinite radius
    spans the whole grid.
    """
    origin, cell_m, shape = cells[0], cells[1], cells[2]
    reach = radius_m + QUERY_SLACK_M
    if not (np.isfinite(px) and np.isfinite(py) and reach >= 0.0):
        return 0, -1, 0, -1
    if reach == np.inf:
        return 0, shape[0] - 1, 0, shape[1] - 1
    ix0 = max(_cell_index((px - reach - origin[0]) / cell_m), 0)
    iy0 = max(_cell_index((py - reach - origin[1]) / cell_m), 0)
    ix1 = min(_cell_index((px + reach - origin[0]) / cell_m), shape[0] - 1)
    iy1 = min(_cell_index((py + reach - origin[1]) / cell_m), shape[1] - 1)
    if ix1 < ix0 or iy1 < iy0:
        return 0, -1, 0, -1
    return ix0, ix1, iy0, iy1


@njit(cache=True)
def near_mask(cells, segments, px, py, radius_m):
    """``SegmentGrid.mask_near`` compiled: mask (M,) of the segments within ``radius_m``."""
    offsets, members, ny = cells[3], cells[4], cells[2][1]
    mask = np.zeros(segments.shape[0], dtype=np.bool_)
    ix0, ix1, iy0, iy1 = cell_span(cells, px, py, radius_m)
    for ix in range(ix0, ix1 + 1):
        for k in range(offsets[ix * ny + iy0], offsets[ix * ny + iy1 + 1]):
            j = members[k]
            if not mask[j]:
                d = point_segment_distance(
                    px, py, segments[j, 0], segments[j, 1], segments[j, 2], segments[j, 3]
                )
                mask[j] = d <= radius_m
    return mask


@njit(cache=True)
def nearest_filed(cells, segments, allowed, points, within_m):
    """``SegmentGrid.nearest`` compiled: (index (P,), distance (P,)) of each point's nearest
    allowed segment within ``within_m``, -1 and inf where there is none."""
    offsets, members, ny = cells[3], cells[4], cells[2][1]
    n = points.shape[0]
    index = np.full(n, -1, dtype=np.int64)
    dist = np.full(n, np.inf)
    for i in range(n):
        px, py = points[i, 0], points[i, 1]
        ix0, ix1, iy0, iy1 = cell_span(cells, px, py, within_m)
        for ix in range(ix0, ix1 + 1):
            # The cells of one column are contiguous in ``members``.
            for k in range(offsets[ix * ny + iy0], offsets[ix * ny + iy1 + 1]):
                j = members[k]
                if not allowed[j]:
                    continue
                d = point_segment_distance(
                    px, py, segments[j, 0], segments[j, 1], segments[j, 2], segments[j, 3]
                )
                if d <= within_m and (d < dist[i] or (d == dist[i] and j < index[i])):
                    dist[i], index[i] = d, j
    return index, dist


@njit(cache=True)
def filed_within(cells, segments, allowed, points, radius_m):
    """``SegmentGrid.within`` compiled: CSR (offsets (P + 1,), indices) of the allowed
    segments within ``radius_m`` of each point, and each listed segment's distance (m)."""
    offsets, members, ny = cells[3], cells[4], cells[2][1]
    n = points.shape[0]
    starts = np.zeros(n + 1, dtype=np.int64)
    found = np.empty(max(64, 8 * n), dtype=np.int64)
    found_d = np.empty(found.size)
    count = np.int64(0)  # typed, so list_if_within compiles once, not for a literal 0
    listed_for = np.full(segments.shape[0], -1, dtype=np.int64)  # a segment filed in two cells
    for i in range(n):
        px, py = points[i, 0], points[i, 1]
        ix0, ix1, iy0, iy1 = cell_span(cells, px, py, radius_m)
        # Room for every segment filed in the square, made before its walk: an array
        # replaced inside the walk would slow every step of it.
        filed = 0
        for ix in range(ix0, ix1 + 1):
            filed += offsets[ix * ny + iy1 + 1] - offsets[ix * ny + iy0]
        if count + filed > found.size:
            size = max(2 * found.size, count + filed)
            found, found_d = grown(found, count, size), grown(found_d, count, size)
        for ix in range(ix0, ix1 + 1):
            for k in range(offsets[ix * ny + iy0], offsets[ix * ny + iy1 + 1]):
                j = members[k]
                if not allowed[j] or listed_for[j] == i:
                    continue
                listed_for[j] = i
                count = list_if_within(px, py, segments, j, radius_m, found, found_d, count)
        starts[i + 1] = count
    return starts, found[:count], found_d[:count]
