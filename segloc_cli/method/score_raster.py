"""Score rasters of a segment map: how well a point at each place would sit on a wall.

The hypothesis search (``search.py``) scores thousands of candidate poses per
scan. Looking each rotated, shifted point up in a raster is far cheaper than
measuring its distance to the segments, so the map is turned once into a
raster of per-cell scores: 1 on a segment, falling as 1 − (d/r)² to 0 at the
score radius r. A pyramid of coarser grids keeps the best score over squares
of 2, 4, … 2^depth cells; summed over a scan's points they bound the fine sums
of every shift inside a square, which is what lets the search skip regions
that cannot beat what it has already found (the multi-resolution idea of
correlative scan matching). The coarse levels keep one bound per few cells,
so that they stay small enough to be read from the processor's caches.

The compiled search takes the pyramid as a ``PyramidArrays`` and reads its flat layout
through the compiled helpers beside it (``level_grid``, ``level_cell``, ``level_cells``,
``level_square``). Numba's on-disk cache of a compiled caller is keyed on the caller's own
source file only: after editing those helpers, delete the ``*.nbi`` / ``*.nbc`` files in
``segloc_cli/__pycache__`` (or touch ``search.py``), or the search keeps the old ones.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from segloc_cli.geometry import as_segments
from segloc_cli.jit import njit
from segloc_cli.method.kernels import point_segment_distance

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

STRIDE_LAG = 2
"""Level l of a bound pyramid keeps one bound per 2^(l − STRIDE_LAG) cells (every cell up to
level STRIDE_LAG), each over a square that much wider than 2^l. The coarse levels, which a
global search reads for every heading all over the map, then fit in the processor's caches
instead of costing a memory fetch per point; the bounds loosen by a quarter of a square."""


def level_shift(level: int) -> int:
    """log2 of the stride (cells) of pyramid level ``level`` (squares of 2^level cells)."""
    return max(0, level - STRIDE_LAG)


def _level_shape(shape: tuple[int, int], pad: int, level: int) -> tuple[int, int]:
    stride = 2 ** level_shift(level)
    return (-(-(shape[0] + pad) // stride), -(-(shape[1] + pad) // stride))


def pyramid_cells(raster_shape: tuple[int, int], depth: int) -> int:
    """Cells of all ``depth`` levels of the bound pyramid of a raster of ``raster_shape``."""
    pad = 2**depth - 1
    return sum(
        int(np.prod(_level_shape(raster_shape, pad, level))) for level in range(1, depth + 1)
    )


def pyramid_depth(raster_shape: tuple[int, int], max_depth: int) -> int:
    """Levels of the bound pyramid of a raster: ``max_depth``, or fewer (at least 1) so that
    all levels together stay within ``MAX_PYRAMID_CELLS``."""
    depth = max_depth
    while depth > 1 and pyramid_cells(raster_shape, depth) > MAX_PYRAMID_CELLS:
        depth -= 1
    return depth


@dataclass(frozen=True)
class BoundPyramid:
    """Upper bounds of a fine score raster over squares of 2^l cells, l = 1..depth (the
    precomputed grids of fast correlative scan matching), in 255ths rounded up.

    Level l keeps a bound per 2^s cells, s = ``level_shift(l)``: its cell (q, r) holds the
    best fine score over cells [q·2^s − W, q·2^s − W + 2^l + 2^s − 1) in x (likewise in y
    with r), W = ``pad`` = 2^depth − 1. A point whose fine cell is ``b + u`` for a shift
    ``u`` in [0, 2^l) lies in the square of the level cell q = (b + W) >> s, so summing the
    level's values there bounds from above the fine sum of every such shift. Cells beyond
    the raster score 0. All levels are stored one after another in ``values`` so that the
    compiled search takes them as plain arrays.
    """

    values: np.ndarray
    """All levels' cells, uint8, level 1 first, each row-major."""
    offsets: np.ndarray
    """(depth,) int64: where each level starts in ``values``."""
    shapes: np.ndarray
    """(depth, 2) int64: each level's cells in x and y."""
    shifts: np.ndarray
    """(depth,) int64: each level's stride as a power of two."""
    pad: int

    @property
    def depth(self) -> int:
        return int(self.offsets.shape[0])

    def level(self, level: int) -> np.ndarray:
        """Level ``level``'s cells (a view), shape ``shapes[level − 1]``."""
        nx, ny = self.shapes[level - 1]
        start = self.offsets[level - 1]
        return self.values[start : start + nx * ny].reshape(nx, ny)

    def bound(self, level: int, bx: int, by: int) -> float:
        """The bound, in [0, 1], of level ``level`` for a square starting at fine cell
        (bx, by), bx, by ≥ −``pad``."""
        shift = self.shifts[level - 1]
        return self.level(level)[(bx + self.pad) >> shift, (by + self.pad) >> shift] / BOUND_LEVELS

    def arrays(self, fine: np.ndarray, phased: np.ndarray) -> PyramidArrays:
        """The pyramid as compiled code takes it, with the fine raster (NX, NY) it bounds and
        one of its levels split by phase (``phase_split``)."""
        return PyramidArrays(
            fine, self.values, self.offsets, self.shapes, self.shifts, self.pad, phased
        )


class PyramidArrays(NamedTuple):
    """A fine score raster and its ``BoundPyramid``, as plain arrays and numbers for compiled
    code, which reads the levels through ``level_grid``, ``level_cell``, ``level_cells`` and
    ``level_square``."""

    fine: np.ndarray
    """(NX, NY) float32 scores in [0, 1] (``ScoreRaster.score``)."""
    values: np.ndarray
    """``BoundPyramid.values``: every level's bounds in whole 255ths, one after another."""
    offsets: np.ndarray
    """(depth,) int64: where each level starts in ``values``."""
    shapes: np.ndarray
    """(depth, 2) int64: each level's cells in x and y."""
    shifts: np.ndarray
    """(depth,) int64: each level's stride as a power of two."""
    pad: int
    """W = 2^depth − 1: the fine cells a level's squares reach before the raster."""
    phased: np.ndarray
    """(step, step, A, B) uint8: the level a search starts from split by phase at the stride
    of its top squares (``phase_split``)."""


@njit(cache=True)
def level_grid(pyramid: PyramidArrays, level: int) -> tuple[np.ndarray, int, int]:
    """Level ``level``'s bounds in whole 255ths, flat and row-major (cell (i, j) at i·ny + j),
    and its cells in x and y (nx, ny)."""
    nx, ny = pyramid.shapes[level - 1, 0], pyramid.shapes[level - 1, 1]
    start = pyramid.offsets[level - 1]
    return pyramid.values[start : start + nx * ny], nx, ny


@njit(cache=True)
def level_cell(pyramid: PyramidArrays, level: int, b: int) -> int:
    """The cell, along either axis, of level ``level`` whose square holds the shifts
    [0, 2^level) of fine cell ``b`` (b ≥ −``pad``): what ``BoundPyramid.bound`` reads."""
    return (b + pyramid.pad) >> pyramid.shifts[level - 1]


@njit(cache=True)
def level_cells(pyramid: PyramidArrays, level: int, cells: int) -> int:
    """``cells`` fine cells (≥ 0) in cells of level ``level``, rounded down: a shift by a
    multiple of the level's stride moves every point's level cell by this many."""
    return cells >> pyramid.shifts[level - 1]


@njit(cache=True)
def level_square(pyramid: PyramidArrays, level: int, x: int, y: int) -> tuple[int, int, int]:
    """The square of 2^level shifts at corner (x, y), multiples of the stride of level
    ``level``, in that level's cells: its corner and side (x, y, side)."""
    shift = pyramid.shifts[level - 1]
    return x >> shift, y >> shift, 2**level >> shift


def _strided_max(window: np.ndarray, stride: int, axis: int) -> np.ndarray:
    """Every ``stride``-th cell along ``axis`` of a max-over-squares ``window``, widened by
    stride − 1 cells: the best of cells q·stride and q·stride + stride − 1 (clipped at the
    edge, which can only raise a bound)."""
    if stride == 1:
        return window
    n = window.shape[axis]
    first = np.arange(0, n, stride)
    last = np.minimum(first + stride - 1, n - 1)
    return np.maximum(np.take(window, first, axis=axis), np.take(window, last, axis=axis))


def _store_255ths(src: np.ndarray, dst: np.ndarray) -> None:
    """``dst`` (uint8) = ``src`` (float32 in [0, 1]) in 255ths rounded up, a band of rows at
    a time so that float64 temporaries stay small."""
    rows = max(1, 2**22 // max(1, src.shape[1]))
    for r0 in range(0, src.shape[0], rows):
        scaled = np.ceil(src[r0 : r0 + rows].astype(np.float64) * BOUND_LEVELS + 1e-6)
        dst[r0 : r0 + rows] = np.minimum(scaled, BOUND_LEVELS)


def max_pyramid(fine_score: np.ndarray, depth: int) -> BoundPyramid:
    """The ``BoundPyramid`` of ``depth`` levels over a fine score raster (NX, NY)."""
    nx, ny = fine_score.shape
    pad = 2**depth - 1
    shapes = np.array(
        [_level_shape((nx, ny), pad, lv) for lv in range(1, depth + 1)], np.int64
    ).reshape(depth, 2)
    sizes = shapes.prod(axis=1)
    offsets = np.cumsum(sizes) - sizes
    pyramid = BoundPyramid(
        np.empty(int(sizes.sum()), dtype=np.uint8),
        offsets,
        shapes,
        np.array([level_shift(lv) for lv in range(1, depth + 1)], dtype=np.int64),
        pad,
    )
    window = np.zeros((nx + pad, ny + pad), dtype=np.float32)
    window[pad:, pad:] = fine_score
    for level in range(1, depth + 1):
        half = 2 ** (level - 1)
        # Widen the squares from 2^(l-1) to 2^l cells: the best of two neighbours, per axis.
        window[:-half, :] = np.maximum(window[:-half, :], window[half:, :])
        window[:, :-half] = np.maximum(window[:, :-half], window[:, half:])
        stride = 2 ** level_shift(level)
        strided = _strided_max(_strided_max(window, stride, 0), stride, 1)
        _store_255ths(strided, pyramid.level(level))
    return pyramid


def phase_split(grid: np.ndarray, step: int) -> np.ndarray:
    """``grid`` (NX, NY) split by phase: out[p, r, a, b] = grid[a·step + p, b·step + r], 0 past
    the grid's edge; shape (step, step, ⌈NX/step⌉, ⌈NY/step⌉). Cells ``step`` apart in the
    grid are neighbours in one phase, so reading a grid at every step-th cell from a start
    reads consecutive cells."""
    nx, ny = grid.shape
    rows, columns = -(-nx // step), -(-ny // step)
    padded = np.zeros((rows * step, columns * step), dtype=grid.dtype)
    padded[:nx, :ny] = grid
    return np.ascontiguousarray(padded.reshape(rows, step, columns, step).transpose(1, 3, 0, 2))
