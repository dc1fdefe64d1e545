"""A uniform grid over a map's segments, to find those near a point without testing them all.

Large maps hold thousands of segments, of which a scan can see a few dozen.
Each segment is filed under every grid cell its bounding box touches; a
query for the segments within ``radius`` of a point gathers the cells of the
square around it, so it costs what the neighbourhood holds, not what the map
holds.
"""

from __future__ import annotations

import numpy as np

from segloc_cli.geometry import as_segments, point_segment_distances

DEFAULT_CELL_M = 4.0
"""Cell side: about a room's wall; small enough that a query's square holds little else."""

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
        self.segments_world = as_segments(segments_world)
        self.cell_m = float(cell_m)
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
        self._shape = tuple(int(v) for v in shape)
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
