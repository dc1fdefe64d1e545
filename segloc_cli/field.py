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
from segloc_cli.overlap import _point_segment_distance


@njit(cache=True)
def _distance_raster(segments, x0, y0, cell, nx, ny, max_d):
    """Distance (clipped at ``max_d``) from each cell centre to the nearest segment."""
    dist = np.full((nx, ny), max_d, dtype=np.float32)
    for s in range(segments.shape[0]):
        x1, y1, x2, y2 = segments[s, 0], segments[s, 1], segments[s, 2], segments[s, 3]
        i_lo = max(0, int(np.floor((min(x1, x2) - max_d - x0) / cell)))
        i_hi = min(nx - 1, int(np.ceil((max(x1, x2) + max_d - x0) / cell)))
        j_lo = max(0, int(np.floor((min(y1, y2) - max_d - y0) / cell)))
        j_hi = min(ny - 1, int(np.ceil((max(y1, y2) + max_d - y0) / cell)))
        for i in range(i_lo, i_hi + 1):
            cx = x0 + i * cell
            for j in range(j_lo, j_hi + 1):
                d = _point_segment_distance(cx, y0 + j * cell, x1, y1, x2, y2)
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
        """Integer cell indices (P, 2) of points (P, 2), world frame; may fall outside."""
        return np.rint((np.asarray(points_world) - self.origin) / self.cell_m).astype(np.int64)

    def lookup(self, points_world: np.ndarray) -> np.ndarray:
        """Scores (P,) of the cells holding the points, 0 outside the raster."""
        idx = self.cell_index(points_world)
        nx, ny = self.score.shape
        inside = (idx[:, 0] >= 0) & (idx[:, 0] < nx) & (idx[:, 1] >= 0) & (idx[:, 1] < ny)
        out = np.zeros(idx.shape[0], dtype=float)
        out[inside] = self.score[idx[inside, 0], idx[inside, 1]]
        return out


def score_raster(
    segments_world: np.ndarray, cell_m: float, radius_m: float, margin_m: float
) -> ScoreRaster:
    """Scores 1 − (d/radius)² (0 beyond ``radius_m``) over the map's extent plus ``margin_m``."""
    segments = np.ascontiguousarray(as_segments(segments_world, "map segments"))
    if segments.shape[0] == 0:
        return ScoreRaster(np.zeros((1, 1), dtype=np.float32), np.zeros(2), cell_m)
    ends = segments.reshape(-1, 2)
    lo = ends.min(axis=0) - margin_m
    n = np.ceil((ends.max(axis=0) + margin_m - lo) / cell_m).astype(int) + 1
    dist = _distance_raster(segments, lo[0], lo[1], cell_m, n[0], n[1], radius_m)
    score = np.clip(1.0 - (dist / radius_m) ** 2, 0.0, 1.0).astype(np.float32)
    return ScoreRaster(score, lo, float(cell_m))


def coarse_bound(fine_score: np.ndarray, factor: int) -> np.ndarray:
    """Block k of the result holds the best fine score over fine cells [k·f, k·f + 2f).

    A point whose fine cell is ``b + u`` for a shift ``u`` in [0, f) lies in
    those cells for block ``b // f`` (per axis), so summing block scores
    bounds from above the fine sum of every shift within one coarse step.
    """
    nx, ny = fine_score.shape
    bx, by = -(-nx // factor) + 1, -(-ny // factor) + 1
    padded = np.zeros((bx * factor, by * factor), dtype=np.float32)
    padded[:nx, :ny] = fine_score
    blocks = padded.reshape(bx, factor, by, factor).max(axis=(1, 3))
    bound = blocks.copy()
    bound[:-1, :] = np.maximum(bound[:-1, :], blocks[1:, :])
    out = bound.copy()
    out[:, :-1] = np.maximum(out[:, :-1], bound[:, 1:])
    return out
