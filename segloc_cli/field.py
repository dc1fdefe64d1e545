"""Score rasters of a segment map: how well a point at each place would sit on a wall.

The hypothesis search (``search.py``) scores thousands of candidate poses per
scan. Looking each rotated, shifted point up in a raster is far cheaper than
measuring its distance to the segments, so the map is turned once into a
raster of per-cell scores: 1 on a segment, falling as 1 − (d/r)² to 0 at the
score radius r. A coarse raster keeps, per block of cells, the best score
within two blocks' reach; its sums are then upper bounds of the fine sums of
every shift inside one coarse step, which is what lets the search skip
regions that cannot beat what it has already found (the multi-resolution
idea of correlative scan matching).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from segloc_cli.geometry import as_segments
from segloc_cli.kernels import point_segment_distance

INDEX_LIMIT = 2**40
"""Cell indices are clipped to ±this before they reach the compiled sums: far beyond any
raster, yet small enough that adding a shift can never overflow 64 bits."""

MAX_RASTER_CELLS = 100_000_000
"""Most cells of a score raster (float32: 400 MB). A map whose extent would need more at the
asked cell size gets coarser cells (and a score radius grown in proportion) instead."""


def cell_indices(cells: np.ndarray) -> np.ndarray:
    """Positions in cells (any shape) → int64 indices, rounded and clipped to ±``INDEX_LIMIT``.

    Non-finite positions become ``-INDEX_LIMIT``, a cell outside every raster, so
    a point that is NaN or immeasurably far simply scores 0.
    """
    clipped = np.clip(np.nan_to_num(cells, nan=-INDEX_LIMIT), -INDEX_LIMIT, INDEX_LIMIT)
    return np.rint(clipped).astype(np.int64)


@njit(cache=True)
def _clamped_index(cells: float, n: int) -> int:
    """A position in cells (any float) → an index in [0, n − 1]; NaN gives 0."""
    if not cells > 0.0:
        return 0
    if cells >= n - 1:
        return n - 1
    return int(cells)


@njit(cache=True)
def _distance_raster(segments, x0, y0, cell, nx, ny, max_d):
    """Distance (clipped at ``max_d``) from each cell centre to the nearest segment.

    Each segment visits, column by column, only the cells within ``max_d`` of
    its part in that column's reach, so the work follows the segments' length,
    not the area of their bounding boxes. Non-finite segments are skipped.
    """
    dist = np.full((nx, ny), max_d, dtype=np.float32)
    reach = max_d + 1e-9  # a cell exactly at max_d is visited despite round-off
    for s in range(segments.shape[0]):
        x1, y1, x2, y2 = segments[s, 0], segments[s, 1], segments[s, 2], segments[s, 3]
        if not (np.isfinite(x1) and np.isfinite(y1) and np.isfinite(x2) and np.isfinite(y2)):
            continue
        i_lo = _clamped_index(np.floor((min(x1, x2) - reach - x0) / cell), nx)
        i_hi = _clamped_index(np.ceil((max(x1, x2) + reach - x0) / cell), nx)
        dx = x2 - x1
        for i in range(i_lo, i_hi + 1):
            cx = x0 + i * cell
            if dx != 0.0:
                ta, tb = (cx - reach - x1) / dx, (cx + reach - x1) / dx
                t_lo, t_hi = max(0.0, min(ta, tb)), min(1.0, max(ta, tb))
                if t_lo > t_hi:
                    continue
                ya, yb = y1 + t_lo * (y2 - y1), y1 + t_hi * (y2 - y1)
            else:
                ya, yb = y1, y2
            j_lo = _clamped_index(np.floor((min(ya, yb) - reach - y0) / cell), ny)
            j_hi = _clamped_index(np.ceil((max(ya, yb) + reach - y0) / cell), ny)
            for j in range(j_lo, j_hi + 1):
                d = point_segment_distance(cx, y0 + j * cell, x1, y1, x2, y2)
                if d < dist[i, j]:
                    dist[i, j] = d
    return dist


@dataclass(frozen=True)
class ScoreRaster:
    """Per-cell scores on a grid aligned with the world axes.

    Cell (i, j) is centred at ``origin + (i, j) * cell_m`` (metres, world
    frame). Points outside the raster score 0.
    """

    score: np.ndarray
    """(NX, NY) float32 scores in [0, 1]."""
    origin: np.ndarray
    """World position (2,) of the centre of cell (0, 0), metres."""
    cell_m: float

    def cell_index(self, points_world: np.ndarray) -> np.ndarray:
        """Integer cell indices (P, 2) of points (P, 2), world frame; may fall outside.

        Non-finite or very distant points get an index far outside the raster.
        """
        cells = (np.asarray(points_world, dtype=float) - self.origin) / self.cell_m
        return cell_indices(cells)

    def lookup(self, points_world: np.ndarray) -> np.ndarray:
        """Scores (P,) of the cells holding the points, 0 outside the raster."""
        idx = self.cell_index(points_world)
        nx, ny = self.score.shape
        inside = (idx[:, 0] >= 0) & (idx[:, 0] < nx) & (idx[:, 1] >= 0) & (idx[:, 1] < ny)
        out = np.zeros(idx.shape[0], dtype=float)
        out[inside] = self.score[idx[inside, 0], idx[inside, 1]]
        return out


def raster_cell(
    extent_m: np.ndarray, margin_m: float, cell_m: float, max_cells: int = MAX_RASTER_CELLS
) -> float:
    """The cell side (m) of a raster over ``extent_m`` (2,) plus a margin of ``margin_m`` on
    each side (the margin scales with the cell): ``cell_m``, or past ``max_cells`` cells the
    first of ``cell_m``·1.25^k that keeps the raster within them."""
    extent = np.asarray(extent_m, dtype=float)
    cell = float(cell_m)
    while True:
        n = np.ceil(extent / cell + 2.0 * margin_m / cell_m) + 1
        if n[0] * n[1] <= max_cells:
            return cell
        cell *= 1.25


def score_raster(
    segments_world: np.ndarray,
    cell_m: float,
    radius_m: float,
    margin_m: float,
    max_cells: int = MAX_RASTER_CELLS,
) -> ScoreRaster:
    """Scores 1 − (d/radius)² (0 beyond ``radius_m``) over the map's extent plus ``margin_m``.

    A map too large for ``max_cells`` cells of ``cell_m`` gets the raster's
    ``raster_cell`` side instead, with the radius and margin scaled alike, so
    memory stays bounded (the raster's ``cell_m`` tells which was used).
    """
    segments = np.ascontiguousarray(as_segments(segments_world, "map segments"))
    if segments.shape[0] == 0:
        return ScoreRaster(np.zeros((1, 1), dtype=np.float32), np.zeros(2), cell_m)
    ends = segments.reshape(-1, 2)
    cell = raster_cell(ends.max(axis=0) - ends.min(axis=0), margin_m, cell_m, max_cells)
    scale = cell / cell_m
    radius_m, margin_m = radius_m * scale, margin_m * scale
    lo = ends.min(axis=0) - margin_m
    n = np.ceil((ends.max(axis=0) + margin_m - lo) / cell).astype(int) + 1
    score = _distance_raster(segments, lo[0], lo[1], cell, n[0], n[1], radius_m)
    # In place, a band of rows at a time: the raster is the largest array the localizer holds,
    # and float64 temporaries of all of it would take twice its size again.
    rows = max(1, 2**22 // score.shape[1])
    for r0 in range(0, score.shape[0], rows):
        band = score[r0 : r0 + rows]
        band[:] = np.clip(1.0 - (band / radius_m) ** 2, 0.0, 1.0)
    return ScoreRaster(score, lo, float(cell))


BOUND_LEVELS = 255
"""Bounds above the finest level are stored as whole 255ths (uint8), rounded up."""

MAX_PYRAMID_CELLS = 400_000_000
"""Most cells of all levels of a bound pyramid together (uint8: 400 MB, as much as the
largest score raster): a map that large gets fewer levels rather than more memory."""


def pyramid_depth(raster_shape: tuple[int, int], max_depth: int) -> int:
    """Levels of the bound pyramid of a raster: ``max_depth``, or fewer (at least 1) so that
    all levels, each padded by 2^depth − 1 cells, stay within ``MAX_PYRAMID_CELLS``."""
    depth = max_depth
    while depth > 1:
        pad = 2**depth - 1
        if depth * (raster_shape[0] + pad) * (raster_shape[1] + pad) <= MAX_PYRAMID_CELLS:
            break
        depth -= 1
    return depth


def max_pyramid(fine_score: np.ndarray, depth: int) -> np.ndarray:
    """Bounds of the fine scores over squares of 2^l cells, for l = 1..``depth``.

    Level l (index l − 1 of the result) at (i + W, j + W), W = 2^depth − 1, holds the best
    fine score over cells [i, i + 2^l) × [j, j + 2^l), in 255ths rounded up (uint8), for i
    from −W: a point whose fine cell is ``b + u`` for a shift ``u`` in [0, 2^l) lies in
    that square for ``i = b``, so summing level-l values at ``b`` bounds from above the fine
    sum of every such shift (the precomputed grids of fast correlative scan matching).
    Cells beyond the raster score 0. Shape (depth, NX + W, NY + W).
    """
    nx, ny = fine_score.shape
    pad = 2**depth - 1
    window = np.zeros((nx + pad, ny + pad), dtype=np.float32)
    window[pad:, pad:] = fine_score
    out = np.empty((depth, nx + pad, ny + pad), dtype=np.uint8)
    for level in range(1, depth + 1):
        half = 2 ** (level - 1)
        # Widen the squares from 2^(l-1) to 2^l cells: the best of two neighbours, per axis.
        window[:-half, :] = np.maximum(window[:-half, :], window[half:, :])
        window[:, :-half] = np.maximum(window[:, :-half], window[:, half:])
        rows = max(1, 2**22 // window.shape[1])  # bands keep float64 temporaries small
        for r0 in range(0, window.shape[0], rows):
            scaled = np.ceil(window[r0 : r0 + rows].astype(np.float64) * BOUND_LEVELS + 1e-6)
            out[level - 1, r0 : r0 + rows] = np.minimum(scaled, BOUND_LEVELS)
    return out
