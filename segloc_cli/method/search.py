"""Hypothesis search: many candidate poses, scored by how much of the scan lies on the map.

With a handful of local segments (a 180° scan of 180 beams gives 6–9) the
stage-2 overlap is nearly flat across a wide area, and a single descent from
the initial guess often ends on a wrong pose that overlaps just as well. The
search here asks the scan's points instead. For each candidate heading it
sums, over a grid of positions, the raster scores of the rotated and shifted
points (``score_raster.py``): first per coarse block, whose sums bound every shift
inside it, then at the fine resolution only inside the blocks whose bound
can still compete, best first. The result is a ranked list of distinct grid
poses, which the caller polishes by refinement and compares.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from segloc_cli.config import SearchParams
from segloc_cli.geometry import Pose2, wrap_angle
from segloc_cli.jit import njit, prange
from segloc_cli.method.kernels import wrap
from segloc_cli.method.score_raster import (
    BOUND_LEVELS,
    INDEX_LIMIT,
    PyramidArrays,
    level_cell,
    level_cells,
    level_grid,
    level_shift,
    level_square,
    max_pyramid,
    phase_split,
    pyramid_depth,
    score_raster,
)


@dataclass(frozen=True)
class GridPose:
    """A grid pose (world frame) and the mean score of the scan's points there, in [0, 1]."""

    pose: Pose2
    score: float


class SearchGrid(NamedTuple):
    """The grid poses a search scores, as compiled code takes them: every heading × every
    shift (x, y) in [0, ``n_cells``)² fine cells from the search's start (world frame)."""

    headings: np.ndarray
    """(H,) headings, rad."""
    ix: np.ndarray
    """(H, P) int64: the points' fine cells in x at shift (0, 0), per heading."""
    iy: np.ndarray
    """(H, P) int64: the same in y."""
    n_cells: int
    """Shifts along each axis."""
    depth: int
    """The pyramid level the search starts from: top squares of 2^depth × 2^depth shifts
    (0: single shifts, no pyramid)."""
    cell: float
    """Side of a fine cell (and of a shift), m."""


class Pruning(NamedTuple):
    """Which grid poses a search keeps: the ``k`` best distinct ones scoring at least
    ``keep`` times the best, two poses being alike within ``apart_m`` (m) and
    ``apart_rad`` (rad)."""

    k: int
    keep: float
    apart_m: float
    apart_rad: float


@njit(cache=True)
def _point_cells(points, cos_sin, start, origin, cell):
    """Fine cells (H, P) of points (P, 2), robot frame, turned by each heading (cos, sin per
    row of ``cos_sin``) and moved by ``start``, on the raster with cell (0, 0) at
    ``origin``: what ``score_raster.cell_indices`` gives, rounded half to even and clipped to
    ±``INDEX_LIMIT`` (NaN to −``INDEX_LIMIT``)."""
    n_h, n_p = cos_sin.shape[0], points.shape[0]
    ix = np.empty((n_h, n_p), dtype=np.int64)
    iy = np.empty((n_h, n_p), dtype=np.int64)
    for h in range(n_h):
        c, s = cos_sin[h, 0], cos_sin[h, 1]
        for p in range(n_p):
            px, py = points[p, 0], points[p, 1]
            ix[h, p] = _clipped_cell(((px * c + py * -s) + start[0] - origin[0]) / cell)
            iy[h, p] = _clipped_cell(((px * s + py * c) + start[1] - origin[1]) / cell)
    return ix, iy


@njit(cache=True)
def _clipped_cell(value):
    if value != value:
        return -INDEX_LIMIT
    if value > INDEX_LIMIT:
        return INDEX_LIMIT
    if value < -INDEX_LIMIT:
        return -INDEX_LIMIT
    return np.int64(np.rint(value))


@njit(cache=True)
def _beyond_limit(bx, by):
    """Whether a point's base cell lies beyond ``INDEX_LIMIT``: such points are skipped, so
    no index arithmetic can overflow and every read stays inside its raster."""
    return bx < -INDEX_LIMIT or bx > INDEX_LIMIT or by < -INDEX_LIMIT or by > INDEX_LIMIT


@njit(cache=True)
def _exact_sum(fine, ix, iy, x, y):
    """Sum over points of fine[ix[p] + x, iy[p] + y] (float64, in point order); 0 outside.

    Points whose base cell lies beyond ``INDEX_LIMIT`` are skipped, so no index
    arithmetic can overflow and every read stays inside ``fine``.
    """
    nx, ny = fine.shape
    total = 0.0
    for p in range(ix.shape[0]):
        bx, by = ix[p], iy[p]
        if _beyond_limit(bx, by):
            continue
        i, j = bx + x, by + y
        if 0 <= i < nx and 0 <= j < ny:
            total += fine[i, j]
    return total


class _MergedPoints(NamedTuple):
    """The points' cells on each pyramid level, merged (``_merge_heading``: ``cells``,
    ``linear``, ``weights``, ``counts``, ``boxes``), and the box of their fine cells per
    heading (``_cell_box``: ``fine_boxes``)."""

    cells: np.ndarray
    linear: np.ndarray
    weights: np.ndarray
    counts: np.ndarray
    boxes: np.ndarray
    fine_boxes: np.ndarray


@njit(cache=True)
def _merged_room(pyramid, grid):
    """Room for the points' merged cells (``_MergedPoints``, ``_merge_heading`` fills
    them in at each heading; the boxes of the fine cells are filled in here), and per level
    (depth, 3) its cells in x and y, and how far before the level a kept cell may lie."""
    ix, iy, depth, (n_h, n_p) = grid.ix, grid.iy, grid.depth, grid.ix.shape
    # Only the first counts[L, h] entries of a row are filled (and read).
    cells = np.empty((depth, n_h, n_p, 2), dtype=np.int32)
    linear = np.empty((depth, n_h, n_p), dtype=np.int64)
    weights = np.empty((depth, n_h, n_p), dtype=np.int32)
    counts = np.zeros((depth, n_h), dtype=np.int64)
    boxes = np.zeros((depth, n_h, 4), dtype=np.int64)
    shapes = np.empty((depth, 3), dtype=np.int64)
    for lv in range(depth):
        _, nx, ny = level_grid(pyramid, lv + 1)
        shapes[lv, 0], shapes[lv, 1] = nx, ny
        shapes[lv, 2] = level_cells(pyramid, lv + 1, grid.n_cells) + 1
    return _MergedPoints(cells, linear, weights, counts, boxes, _cell_box(ix, iy)), shapes


@njit(cache=True)
def _merge_heading(pyramid, grid, sort, shapes, merged, h):
    """The points' cells at heading index h on ``BoundPyramid`` levels 1 to the grid's
    depth, merged, into ``merged`` (``_merged_room``, whose ``shapes`` it takes): per level
    L (at index L − 1), the level cells (Q, 2) of the points' squares at shift
    (0, 0), how many points each stands for (Q,), with Q in ``counts[L − 1, h]``, each
    cell's index into its level stored row-major (Q,), and the cells' bounding box (min x,
    max x, min y, max y). With ``sort`` every cell is listed once; without, only consecutive
    points are merged (a scan's points come in beam order, so most points sharing a cell
    are neighbours), which costs no sorting: the choice for a search that evaluates few
    nodes.

    A node of level L has a corner x that is a multiple of the level's stride 2^s, so a
    point of fine cell b reads the level at (b + W + x) >> s = ((b + W) >> s) + (x >> s):
    points in the same level cell read the same bound at every node, and the level's
    sums cost one read per merged cell, not per point. Points whose cells no shift
    within ``n_cells`` brings onto the level are left out, as are points beyond
    ``INDEX_LIMIT``.
    """
    ix, iy, depth, n_p = grid.ix[h], grid.iy[h], grid.depth, grid.ix.shape[1]
    # The points some level keeps, as offsets u = b + W from the levels' cell 0.
    kept = np.empty(n_p, dtype=np.int64)
    m = 0
    for p in range(n_p):
        bx, by = ix[p], iy[p]
        if _beyond_limit(bx, by):
            continue
        for lv in range(depth):
            ci, cj = level_cell(pyramid, lv + 1, bx), level_cell(pyramid, lv + 1, by)
            reach = shapes[lv, 2]
            if -reach <= ci < shapes[lv, 0] and -reach <= cj < shapes[lv, 1]:
                kept[m] = p
                m += 1
                break
    order = kept[:m]
    if sort and m > 1:
        top_shift = pyramid.shifts[depth - 1]
        order = order[_z_order(ix, iy, order, pyramid.pad, top_shift)]
    for lv in range(depth):
        row = _MergedRow(
            merged.cells[lv, h], merged.linear[lv, h], merged.weights[lv, h], 0, merged.boxes[lv, h]
        )
        merged.counts[lv, h] = _merge_level(pyramid, lv + 1, ix, iy, order, shapes[lv], row)


@njit(cache=True)
def _spread_bits(v):
    """The low 32 bits of ``v`` (uint64) moved to the even bits."""
    v &= np.uint64(0xFFFFFFFF)
    v = (v | (v << np.uint64(16))) & np.uint64(0x0000FFFF0000FFFF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x00FF00FF00FF00FF)
    v = (v | (v << np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    v = (v | (v << np.uint64(2))) & np.uint64(0x3333333333333333)
    return (v | (v << np.uint64(1))) & np.uint64(0x5555555555555555)


@njit(cache=True)
def _z_order(ix, iy, points, pad, top_shift):
    """The order (indices into ``points``) that sorts the points' fine cells (``ix``, ``iy``
    at ``points``) by their Z-order (bits of x and y interleaved) from b + ``pad``: every
    level cell (b + W) >> s, s ≤ ``top_shift``, then holds consecutive points, so one sort
    serves every level. The cells a level keeps lie within a few raster widths of it, well
    within the 32 bits a coordinate gets here."""
    n = points.shape[0]
    lo_x, lo_y = ix[points[0]], iy[points[0]]
    for e in range(n):
        lo_x, lo_y = min(lo_x, ix[points[e]]), min(lo_y, iy[points[e]])
    # From a multiple of the widest stride, so that shifting keeps the cells apart alike.
    lo_x = ((lo_x + pad) >> top_shift) << top_shift
    lo_y = ((lo_y + pad) >> top_shift) << top_shift
    keys = np.empty(n, dtype=np.uint64)
    for e in range(n):
        u = np.uint64(ix[points[e]] + pad - lo_x)
        v = np.uint64(iy[points[e]] + pad - lo_y)
        keys[e] = _spread_bits(u) | (_spread_bits(v) << np.uint64(1))
    return np.argsort(keys, kind="mergesort")  # stable: ``_best_first``'s sort, compiled once


@njit(cache=True)
def _merge_level(pyramid, level, ix, iy, points, shape, row):
    """Merge the ``points`` (indices into one heading's fine cells ``ix``, ``iy``) on pyramid
    level ``level``, consecutive equal cells into one, into ``row`` (``_MergedRow``, its
    count unused), leaving out the cells the level does not keep (``shape``: its cells in x
    and y, and how far before it a kept cell may lie); returns how many cells it holds."""
    row_cells, row_linear, row_weights, _, box = row
    nx, ny, reach = shape[0], shape[1], shape[2]
    q = -1
    for e in range(points.shape[0]):
        p = points[e]
        ci, cj = level_cell(pyramid, level, ix[p]), level_cell(pyramid, level, iy[p])
        if not (-reach <= ci < nx and -reach <= cj < ny):
            continue
        if q >= 0 and ci == row_cells[q, 0] and cj == row_cells[q, 1]:
            row_weights[q] += 1
            continue
        q += 1
        row_cells[q, 0], row_cells[q, 1], row_weights[q] = ci, cj, 1
        row_linear[q] = ci * ny + cj
        if q == 0:
            box[0], box[1], box[2], box[3] = ci, ci, cj, cj
        else:
            box[0], box[1] = min(box[0], ci), max(box[1], ci)
            box[2], box[3] = min(box[2], cj), max(box[3], cj)
    return q + 1


@njit(cache=True)
def _children_exact(fine, ix, iy, box, x, y, out):
    """``_exact_sum`` at the four shifts (x, y), (x + 1, y), (x, y + 1), (x + 1, y + 1), into
    ``out`` (4,) in that order, in one pass over the points (the same sums, point by point).
    ``box`` (min x, max x, min y, max y) bounds the points' cells (``_cell_box``): when it
    lies inside ``fine`` at all four shifts, no point is checked."""
    nx, ny = fine.shape
    s0 = s1 = s2 = s3 = 0.0
    if box[0] + x >= 0 and box[1] + x + 1 < nx and box[2] + y >= 0 and box[3] + y + 1 < ny:
        for p in range(ix.shape[0]):
            i, j = ix[p] + x, iy[p] + y
            s0 += fine[i, j]
            s1 += fine[i + 1, j]
            s2 += fine[i, j + 1]
            s3 += fine[i + 1, j + 1]
        out[0], out[1], out[2], out[3] = s0, s1, s2, s3
        return
    for p in range(ix.shape[0]):
        bx, by = ix[p], iy[p]
        if _beyond_limit(bx, by):
            continue
        i, j = bx + x, by + y
        if -1 <= i < nx and -1 <= j < ny:
            in_i, in_j = 0 <= i, 0 <= j
            in_i1, in_j1 = i + 1 < nx, j + 1 < ny
            if in_i and in_j:
                s0 += fine[i, j]
            if in_i1 and in_j:
                s1 += fine[i + 1, j]
            if in_i and in_j1:
                s2 += fine[i, j + 1]
            if in_i1 and in_j1:
                s3 += fine[i + 1, j + 1]
    out[0], out[1], out[2], out[3] = s0, s1, s2, s3


@njit(cache=True)
def _cell_box(ix, iy):
    """(min x, max x, min y, max y) of the points' fine cells (H, P), per heading (H, 4); a
    heading with a point beyond ``INDEX_LIMIT`` gets a box no shift puts inside a raster."""
    n_h, n_p = ix.shape
    boxes = np.empty((n_h, 4), dtype=np.int64)
    for h in range(n_h):
        lo_x = lo_y = INDEX_LIMIT + 1
        hi_x = hi_y = -INDEX_LIMIT - 1
        for p in range(n_p):
            bx, by = ix[h, p], iy[h, p]
            if _beyond_limit(bx, by):
                lo_x, hi_x = -INDEX_LIMIT - 1, INDEX_LIMIT + 1
                break
            lo_x, hi_x = min(lo_x, bx), max(hi_x, bx)
            lo_y, hi_y = min(lo_y, by), max(hi_y, by)
        boxes[h, 0], boxes[h, 1], boxes[h, 2], boxes[h, 3] = lo_x, hi_x, lo_y, hi_y
    return boxes


class _MergedRow(NamedTuple):
    """The merged points of one level and heading (``_merge_heading``): their level cells
    (Q, 2), each one's index into the level (Q,), how many points each stands for (Q,), Q,
    and the cells' bounding box (min x, max x, min y, max y)."""

    cells: np.ndarray
    linear: np.ndarray
    weights: np.ndarray
    n_merged: int
    box: np.ndarray


QUARTER_CHECK = 32
"""Merged cells ``_children_bound`` sums between its checks of what is left to add."""


@njit(cache=True)
def _children_bound(level_bounds, row, square, out, threshold):
    """The bounds of one pyramid level (``level_grid``: values, nx, ny) at the four moves
    (xs, ys), (xs + half, ys), (xs, ys + half), (xs + half, ys + half) level cells of the
    merged points ``row`` (``_MergedRow``), ``square`` being (xs, ys, half)
    (``level_square``), into ``out`` (4,) in that order, in points' worth: each bounds
    ``_exact_sum`` for every shift within its square. Cells beyond the level score 0; when
    the cells' box lies inside the level at all four moves, no cell is checked.

    Returns whether a bound may beat the sum ``threshold``: where no cell is checked, the
    sums stop part way once none could (were every point left to add to score a whole
    255ths), and ``out`` holds partial sums, none above it."""
    values, nx, ny = level_bounds
    cells, linear, weights, count, box = row
    xs, ys, half = square
    s0 = s1 = s2 = s3 = 0
    inside_x = box[0] + xs >= 0 and box[1] + xs + half < nx
    if inside_x and box[2] + ys >= 0 and box[3] + ys + half < ny:
        base, across = xs * ny + ys, half * ny
        left = 0  # 255ths still to add at most
        for q in range(count):
            left += weights[q]
        left *= BOUND_LEVELS
        for start in range(0, count, QUARTER_CHECK):
            for q in range(start, min(count, start + QUARTER_CHECK)):
                b, w = linear[q] + base, weights[q]
                s0 += w * values[b]
                s1 += w * values[b + across]
                s2 += w * values[b + half]
                s3 += w * values[b + across + half]
                left -= w * BOUND_LEVELS
            # As the bounds are compared, in points' worth: a sum no larger stays below.
            if (max(max(s0, s1), max(s2, s3)) + left) / BOUND_LEVELS <= threshold:
                _in_points(s0, s1, s2, s3, out)
                return False
    else:
        for q in range(count):
            i0, j0 = cells[q, 0] + xs, cells[q, 1] + ys
            i1, j1 = i0 + half, j0 + half
            in_i0, in_j0 = 0 <= i0 < nx, 0 <= j0 < ny
            in_i1, in_j1 = 0 <= i1 < nx, 0 <= j1 < ny
            w = weights[q]
            if in_i0 and in_j0:
                s0 += w * values[i0 * ny + j0]
            if in_i1 and in_j0:
                s1 += w * values[i1 * ny + j0]
            if in_i0 and in_j1:
                s2 += w * values[i0 * ny + j1]
            if in_i1 and in_j1:
                s3 += w * values[i1 * ny + j1]
    _in_points(s0, s1, s2, s3, out)
    return True


@njit(cache=True)
def _in_points(s0, s1, s2, s3, out):
    """Four sums in 255ths into ``out`` (4,) in points' worth."""
    out[0], out[1] = s0 / BOUND_LEVELS, s1 / BOUND_LEVELS
    out[2], out[3] = s2 / BOUND_LEVELS, s3 / BOUND_LEVELS


SHORT_SUM_WEIGHT = 257
"""Points' worth of bounds a 16-bit sum holds: 257 · 255 ≤ 2^16 − 1."""


@njit(cache=True)
def _top_bounds(phased, cells, weights, count, out, box):
    """The bounds of the top squares (a, b) of one heading in ``box`` (``_allowed_box``: a
    in [box[0], box[1]), b in [box[2], box[3])), into ``out`` (A, B) in whole 255ths (0
    at the others): the sum over the merged points of the level at their cell moved by
    (a, b) top squares, read from the level split by phase (``phased``, ``phase_split``) so
    that a point's reads over all squares are rows of consecutive cells, added as vectors
    (the caller picks ``out``'s integer type wide enough for 255 per point).

    The points are summed ``SHORT_SUM_WEIGHT`` points' worth at a time in 16 bits, which
    cannot overflow there and adds twice as many cells per vector, then added to ``out``.
    """
    n_a, n_b = out.shape
    out[:, :] = 0
    short = np.zeros((n_a, n_b), dtype=np.uint16)
    held = 0
    for q in range(count):
        w = weights[q]
        if w > SHORT_SUM_WEIGHT:  # too heavy for 16 bits: straight into ``out``
            _add_rows(phased, cells[q, 0], cells[q, 1], out.dtype.type(w), out, box)
            continue
        if held + w > SHORT_SUM_WEIGHT:
            _flush(short, out, box)
            held = 0
        held += w
        _add_rows(phased, cells[q, 0], cells[q, 1], np.uint16(w), short, box)
    _flush(short, out, box)


@njit(cache=True)
def _add_rows(phased, ci, cj, w, out, box):
    """Add ``w`` times the level (split by phase) at cell (ci, cj) moved by (a, b) top
    squares to ``out`` (A, B) at (a, b) within ``box`` (``_allowed_box``), in ``out``'s
    type; cells beyond the level add 0."""
    step = phased.shape[0]
    rows, columns = phased.shape[2], phased.shape[3]
    lane = phased[ci % step, cj % step]
    qa, qb = ci // step, cj // step
    b0, b1 = max(box[2], -qb), min(box[3], columns - qb)
    if b0 >= b1:  # (and a negative slice end would count from the row's end)
        return
    kind = out.dtype.type
    for a in range(max(box[0], -qa), min(box[1], rows - qa)):
        # Slices first: indexing them by a plain range lets the loop be vectorized.
        row, total = lane[qa + a, qb + b0 : qb + b1], out[a, b0:b1]
        for b in range(row.shape[0]):
            total[b] += w * kind(row[b])


@njit(cache=True)
def _flush(short, out, box):
    """Add the 16-bit sums ``short`` to ``out`` within ``box`` and clear them."""
    for a in range(box[0], box[1]):
        row, total = short[a, box[2] : box[3]], out[a, box[2] : box[3]]
        for b in range(row.shape[0]):
            total[b] += row[b]
            row[b] = 0


def _allowed_box(top_mask: np.ndarray) -> np.ndarray:
    """The rows [a0, a1) and columns [b0, b1) holding every top square ``top_mask`` (A, A)
    allows, as (a0, a1, b0, b1) int64 (all 0 when it allows none): where ``_top_bounds``
    adds, which leaves out most of the squares of a long narrow map."""
    rows, columns = np.flatnonzero(top_mask.any(axis=1)), np.flatnonzero(top_mask.any(axis=0))
    if rows.size == 0:
        return np.zeros(4, dtype=np.int64)
    return np.array([rows[0], rows[-1] + 1, columns[0], columns[-1] + 1], dtype=np.int64)


@njit(cache=True)
def _count_bounds(out, unit, counts):
    """Count the top bounds ``out`` (A, A) of one heading, those ≥ 0, per point's worth: a
    bound b (``unit`` per point) in ``counts[b // unit]``."""
    for a in range(out.shape[0]):
        for b in range(out.shape[1]):
            v = out[a, b]
            if v >= 0:
                counts[int(v) // unit] += 1


@njit(cache=True)
def _batch_offsets(counts, low, high):
    """Where each heading's top squares with bounds in points' worth ``low`` to ``high``
    (``counts``, (H, bins)) start in a batch listing them heading by heading (H + 1,)."""
    offsets = np.zeros(counts.shape[0] + 1, dtype=np.int64)
    for h in range(counts.shape[0]):
        held = 0
        for b in range(low, high + 1):
            held += counts[h, b]
        offsets[h + 1] = offsets[h] + held
    return offsets


@njit(cache=True)
def _collect_heading(top, low_value, high_value, offsets, members, h):
    """Write the flat indices of heading h's top squares (``top`` (H, A²), flat index h·A² +
    a·A + b) whose bounds lie in [low_value, high_value) into ``members`` from
    ``offsets[h]``, in order."""
    m = offsets[h]
    if offsets[h + 1] == m:
        return
    row, first = top[h], h * top.shape[1]
    for f in range(row.size):
        if low_value <= row[f] < high_value:
            members[m] = first + f
            m += 1


@njit(cache=True)
def _collect(top, counts, low, high, unit):
    """The top squares (flat indices into ``top`` (H, A²), in order) whose bounds lie in
    points' worth ``low`` to ``high`` (``unit`` per point; ``counts`` per heading and point's
    worth, ``_count_bounds``)."""
    offsets = _batch_offsets(counts, low, high)
    members = np.empty(offsets[-1], dtype=np.int64)
    for h in range(top.shape[0]):
        _collect_heading(top, low * unit, (high + 1) * unit, offsets, members, h)
    return members


@njit(cache=True, parallel=True)
def _collect_parallel(top, counts, low, high, unit):
    """``_collect`` with the headings shared among numba's threads."""
    offsets = _batch_offsets(counts, low, high)
    members = np.empty(offsets[-1], dtype=np.int64)
    for h in prange(top.shape[0]):
        _collect_heading(top, low * unit, (high + 1) * unit, offsets, members, h)
    return members


@njit(cache=True)
def _best_first(top, members):
    """The top squares ``members`` (flat indices into ``top``, in order), best bound first,
    and of equal bounds the first in ``top`` first: an order of all the squares that
    batching does not change."""
    if members.size < 2:
        return members
    # Keyed by how far each bound lies below the best: a float64 ≥ 0, whose bits read as a
    # uint64 keep its order, so the sort is ``_z_order``'s, compiled once; a stable one, as
    # equal bounds (many, where squares of clutter score every point fully) keep their order.
    values = top[members].astype(np.float64)
    keys = (values.max() - values).view(np.uint64)
    return members[np.argsort(keys, kind="mergesort")]


@njit(cache=True)
def _batches(tally, first):
    """Ranges of bins of top squares (``tally``: how many squares each bin holds, the best
    bin last), best first, as rows [low, high], holding at least ``first``, then 4 times as
    many, … squares each: the order the search takes them in."""
    edges = np.empty((tally.size, 2), dtype=np.int64)
    n, size, held, high = 0, first, 0, tally.size - 1
    for b in range(tally.size - 1, -1, -1):
        held += tally[b]
        if held >= size or b == 0:
            edges[n, 0], edges[n, 1] = b, high
            n, high, held, size = n + 1, b - 1, 0, 4 * size
    return edges[:n]


@njit(cache=True)
def _keep_distinct(kept, n, grid, pruning):
    """Compact the first ``n`` of the ``kept`` poses (sorted best first) to those distinct from
    every better one kept; returns how many are kept."""
    score, hh, xx, yy = kept
    headings, cell = grid.headings, grid.cell
    apart_m, apart_rad = pruning.apart_m, pruning.apart_rad
    n_kept = 0
    for e in range(n):
        alone = True
        for o in range(n_kept):
            near = np.hypot(xx[e] - xx[o], yy[e] - yy[o]) * cell <= apart_m
            if near and abs(wrap(headings[hh[e]] - headings[hh[o]])) <= apart_rad:
                alone = False
                break
        if alone:
            score[n_kept], hh[n_kept], xx[n_kept], yy[n_kept] = score[e], hh[e], xx[e], yy[e]
            n_kept += 1
    return n_kept


@njit(cache=True)
def _shadowed(kept, n_kept, grid, pruning, h, x, y, span, bound):
    """Whether every pose of the square of shifts [x, x + span] × [y, y + span] at heading
    index h, none summing above ``bound``, is near one of the first ``n_kept`` ``kept`` poses
    at least as good: placed, each would be dropped as not distinct from it
    (``_keep_distinct``) and change nothing, nor would the kept pose be displaced while they
    are placed (none beats it)."""
    headings, apart_rad = grid.headings, pruning.apart_rad
    for o in range(n_kept):
        if kept.sums[o] < bound or abs(wrap(headings[h] - headings[kept.h[o]])) > apart_rad:
            continue
        # The square's farthest corner from the kept pose is the farthest of its poses.
        dx = max(abs(x - kept.x[o]), abs(x + span - kept.x[o]))
        dy = max(abs(y - kept.y[o]), abs(y + span - kept.y[o]))
        if np.hypot(dx, dy) * grid.cell <= pruning.apart_m:
            return True
    return False


MAX_CLIMB = 32
"""Most moves of the climb from a known pose to a better lower bound (``_climbed``)."""


@njit(cache=True)
def _climbed(fine, ix, iy, h, x, y, n_cells):
    """The best ``_exact_sum`` met climbing from the grid pose (heading index h, x, y): to the
    best of its neighbours (±1 heading index, ±1 cell each way) inside the searched grid
    ((H, P) points' cells ``ix``, ``iy``; n_cells² shifts) while one is better, at most
    ``MAX_CLIMB`` moves."""
    n_h = ix.shape[0]
    best = _exact_sum(fine, ix[h], iy[h], x, y)
    for _ in range(MAX_CLIMB):
        to_h, to_x, to_y = h, x, y
        for hh in range(max(h - 1, 0), min(h + 2, n_h)):
            for xx in range(max(x - 1, 0), min(x + 2, n_cells)):
                for yy in range(max(y - 1, 0), min(y + 2, n_cells)):
                    total = _exact_sum(fine, ix[hh], iy[hh], xx, yy)
                    if total > best:
                        best, to_h, to_x, to_y = total, hh, xx, yy
        if (to_h, to_x, to_y) == (h, x, y):
            break
        h, x, y = to_h, to_x, to_y
    return best


MIN_TOP_LEVEL = 3
MAX_TOP_SQUARES = 16_000_000
"""A search bounds every (heading, square) pair of one level in a first pass, as vectors,
and starts its branch and bound from there: bounds over squares of several metres prune
nothing in rooms, so it starts from the finest level from ``MIN_TOP_LEVEL`` (0.4 m squares)
whose pairs number at most this many (1.6 m squares over 300 m × 300 m at 1°; around a
guess, 0.4 m squares)."""

FIRST_BATCH = 4096
"""Top squares the search sorts and takes first, best bound first; then 4 times as many at a
time, so that a global search sorts only the squares its threshold leaves."""


class _Poses(NamedTuple):
    """Grid poses, one per entry: the sum of the points' scores (points' worth), the heading
    index and the shift (x, y)."""

    sums: np.ndarray
    h: np.ndarray
    x: np.ndarray
    y: np.ndarray


class _Squares(NamedTuple):
    """Squares of 2^level × 2^level shifts, one per entry: the level, the corner shift
    (x, y) and the bound (points' worth) on the sums of their poses."""

    level: np.ndarray
    x: np.ndarray
    y: np.ndarray
    bound: np.ndarray


@njit(cache=True)
def _bound_headings(pyramid, grid, sort, shapes, merged, top_mask, box, top, unit, counts):
    """At every heading, the points merged per level cell (``_merge_heading``, ``sort`` as
    there) into ``merged``, the bound of every top square (``_top_square_bounds``) into
    ``top``, and how many bounds there are per point's worth (``unit`` each) into
    ``counts`` (H, bins)."""
    for h in range(top.shape[0]):
        _merge_heading(pyramid, grid, sort, shapes, merged, h)
        _top_square_bounds(pyramid, grid, merged, top_mask, box, top, h)
        _count_bounds(top[h], unit, counts[h])


@njit(cache=True, parallel=True)
def _bound_headings_parallel(pyramid, grid, sort, shapes, merged, top_mask, box, top, unit, counts):
    """``_bound_headings`` with the headings shared among numba's threads."""
    for h in prange(top.shape[0]):
        _merge_heading(pyramid, grid, sort, shapes, merged, h)
        _top_square_bounds(pyramid, grid, merged, top_mask, box, top, h)
        _count_bounds(top[h], unit, counts[h])


@njit(cache=True)
def _top_square_bounds(pyramid, grid, merged, top_mask, box, top, h):
    """The bound of every top square of heading index h into ``top[h]`` (A, A) of ``top`` (H,
    A, A), heading first, then x, then y (A = ⌈n_cells / 2^depth⌉): whole 255ths from the
    level split by phase (``_top_bounds``), or without a pyramid (depth 0) the exact sums
    of the single shifts. Squares ``top_mask`` (A, A) leaves out (``box``: ``_allowed_box``
    of it) get −1."""
    out, n_top = top[h], top.shape[1]
    if grid.depth == 0:  # no pyramid: the top squares are single shifts
        for a in range(n_top):
            for b in range(n_top):
                out[a, b] = _exact_sum(pyramid.fine, grid.ix[h], grid.iy[h], a, b)
    else:
        lv = grid.depth - 1
        cells, weights = merged.cells[lv, h], merged.weights[lv, h]
        _top_bounds(pyramid.phased, cells, weights, merged.counts[lv, h], out, box)
    for a in range(n_top):
        for b in range(n_top):
            if not top_mask[a, b]:
                out[a, b] = -1


@njit(cache=True)
def _place_leaf(kept, n_kept, grid, pruning, h, x, y, total):
    """Place the grid pose (h, x, y) summing ``total`` among the first ``n_kept`` ``kept``
    poses, in order, and keep the best ``k`` distinct ones; returns how many are kept and
    the sum a square's bound must now beat to be searched: the k-th best kept sum (0 until
    k are kept), and at least ``keep`` times the best."""
    e = n_kept
    while e > 0 and kept.sums[e - 1] < total:
        kept.sums[e], kept.h[e] = kept.sums[e - 1], kept.h[e - 1]
        kept.x[e], kept.y[e] = kept.x[e - 1], kept.y[e - 1]
        e -= 1
    kept.sums[e], kept.h[e], kept.x[e], kept.y[e] = total, h, x, y
    k = pruning.k
    n_kept = min(_keep_distinct(kept, n_kept + 1, grid, pruning), k)
    return n_kept, max(kept.sums[k - 1] if n_kept == k else 0.0, pruning.keep * kept.sums[0])


@njit(cache=True)
def _push_children(stack, n_stack, sums, level, x, y, n_cells, threshold):
    """Push onto the ``stack`` (``n_stack`` high) the four squares of 2^(level − 1) shifts
    making the square of 2^level at corner (x, y), whose bounds ``sums`` (4,) holds in the
    order of ``_children_exact``, that lie on the grid of ``n_cells``² shifts and beat
    ``threshold``: the weakest first, so that the strongest is searched first, and of equal
    ones the first of the four first (the order np.argsort gave them: it sorts so few by a
    stable insertion sort); returns the stack's new height."""
    half, bottom = 2 ** (level - 1), n_stack
    for c in range(4):
        cx, cy = x + (c % 2) * half, y + (c // 2) * half
        if not (cx < n_cells and cy < n_cells and sums[c] > threshold):
            continue
        e = n_stack  # insert it above the squares it does not beat
        while e > bottom and sums[c] < stack.bound[e - 1]:
            stack.level[e], stack.x[e] = stack.level[e - 1], stack.x[e - 1]
            stack.y[e], stack.bound[e] = stack.y[e - 1], stack.bound[e - 1]
            e -= 1
        stack.level[e], stack.x[e], stack.y[e], stack.bound[e] = level - 1, cx, cy, sums[c]
        n_stack += 1
    return n_stack


class _Descent(NamedTuple):
    """What a branch and bound's batches share (``_descend``): the search's arrays, the top
    squares' bounds (flat) and their divisor to points' worth, the kept poses (``_Poses``,
    best first, with room for one more while a leaf is placed)."""

    pyramid: PyramidArrays
    grid: SearchGrid
    pruning: Pruning
    merged: _MergedPoints
    top: np.ndarray
    divisor: float
    kept: _Poses


def _branch_and_bound(
    pyramid: PyramidArrays,
    grid: SearchGrid,
    pruning: Pruning,
    top_mask: np.ndarray,
    known: float,
    top: np.ndarray,
    first_batch: int,
    threads: bool = False,
    floor: float = 0.0,
) -> _Poses:
    """The ``pruning.k`` best distinct grid poses (``_Poses``: sums, heading indices, x, y),
    best first, of the fine sums over the ``grid``, by depth-first branch and bound over the
    bound pyramid (``PyramidArrays``).

    The search bounds every square of 2^``depth`` shifts that ``top_mask`` allows at every
    heading in one pass (``_top_square_bounds``), takes them best bound first (of equal
    bounds the first in ``top`` first), and splits a square in four while its bound beats
    the threshold and it is not ``_shadowed``: the threshold is the k-th best distinct sum
    kept so far (0 until k are kept), and at least ``keep`` times the best, ``known`` being
    a sum already found; until a sum above ``floor`` is found, the threshold is ``floor``
    (no pose at or below it is the best). The best sum is exact; the runner-ups are the
    best distinct sums the pruning leaves (a better pose that is not distinct from one kept
    replaces it).
    ``top`` (H, A, A), A = ⌈n_cells / 2^depth⌉, takes the top squares' bounds: of an
    integer type wide enough for their sums in 255ths, or float64 for a search without a
    pyramid (depth 0). The top squares are taken in batches of whole points' worth of
    bounds, the best first, holding ``first_batch`` squares or more, then 4 times as many
    (``_batches``), counted per heading as they are bounded (``_count_bounds``) so that a
    batch is collected heading by heading (``_collect``).

    With ``threads``, numba's threads share the headings, and from the second batch on find
    the batch's squares with a quarter that beats the threshold (``_survivors``): the
    others, whose quarters all fall at or below it, would be split and dropped, which
    changes nothing, so the answer is the same as on one thread.
    """
    depth, n_h = grid.depth, grid.ix.shape[0]
    n_top = -(-grid.n_cells // 2**depth)
    merged, shapes = _merged_room(pyramid, grid)
    # How many top squares' bounds there are per heading and point's worth, 0 to all points.
    counts = np.zeros((n_h, grid.ix.shape[1] + 2), dtype=np.int32)
    # Sorting pays once the search spans many top squares (a global search).
    bound_headings = _bound_headings_parallel if threads else _bound_headings
    box = _allowed_box(top_mask)
    unit = BOUND_LEVELS if depth > 0 else 1  # a point's worth of bound: 255ths, or exact sums
    bound_headings(pyramid, grid, n_top > 2, shapes, merged, top_mask, box, top, unit, counts)
    by_heading = top.reshape(n_h, -1)
    flat = top.reshape(-1)
    hxy = np.zeros((3, pruning.k + 1), dtype=np.int64)  # heading indices, x and y
    kept = _Poses(np.zeros(pruning.k + 1), hxy[0], hxy[1], hxy[2])
    divisor = float(unit)
    descent = _Descent(pyramid, grid, pruning, merged, flat, divisor, kept)
    # A sum already found is at most the best.
    n_kept, threshold = 0, max(pruning.keep * known, floor)
    collect = _collect_parallel if threads else _collect
    for number, (low, high) in enumerate(_batches(counts.sum(axis=0), first_batch)):
        if high + 1 <= threshold:  # every bound left is below (high + 1) points' worth
            break
        members = collect(by_heading, counts, low, high, unit)
        if threads and number > 0 and depth > 0:
            members = members[_survivors(pyramid, grid, merged, flat, divisor, members, threshold)]
        members = _best_first(flat, members)
        n_kept, threshold, done = _descend(descent, members, n_kept, threshold)
        if done:
            break
    n_kept = int(np.searchsorted(-kept.sums[:n_kept], -pruning.keep * kept.sums[0], "right"))
    return _Poses(kept.sums[:n_kept], kept.h[:n_kept], kept.x[:n_kept], kept.y[:n_kept])


@njit(cache=True)
def _descend(descent, members, n_kept, threshold):
    """Search the top squares ``members`` (flat indices into ``descent.top``, best bound
    first), placing leaves among the ``n_kept`` kept poses, from the
    sum ``threshold``; returns how many are kept, the threshold, and whether the search is
    done (a top square's bound fell to the threshold)."""
    pyramid, grid, pruning, merged, top, divisor, kept = descent
    depth, step = grid.depth, 2**grid.depth
    n_top = -(-grid.n_cells // step)
    n_kept = np.int64(n_kept)  # not the literal 0, which numba would compile callees for too
    # The squares left to search (at most three per level, and one), and the bounds of the
    # four squares making one.
    lxy = np.zeros((3, 4 * depth + 4), dtype=np.int64)  # their levels, x and y
    stack, sums = _Squares(lxy[0], lxy[1], lxy[2], np.zeros(4 * depth + 4)), np.zeros(4)
    for i in range(members.size):
        flat = members[i]
        if top[flat] / divisor <= threshold:
            return n_kept, threshold, True
        h = flat // (n_top * n_top)
        stack.level[0], stack.x[0] = depth, (flat // n_top) % n_top * step
        stack.y[0], stack.bound[0] = flat % n_top * step, top[flat] / divisor
        n_stack = 1
        while n_stack > 0:
            n_stack -= 1
            level, x, y = stack.level[n_stack], stack.x[n_stack], stack.y[n_stack]
            bound = stack.bound[n_stack]
            if bound <= threshold:
                continue
            if _shadowed(kept, n_kept, grid, pruning, h, x, y, 2**level - 1, bound):
                continue
            if level == 0:  # a leaf, whose bound is its exact sum: place it among the kept
                n_kept, threshold = _place_leaf(kept, n_kept, grid, pruning, h, x, y, bound)
                continue
            if _quarter_bounds(pyramid, grid, merged, h, level, x, y, sums, threshold):
                n_stack = _push_children(stack, n_stack, sums, level, x, y, grid.n_cells, threshold)
    return n_kept, threshold, False


@njit(cache=True)
def _quarter_bounds(pyramid, grid, merged, h, level, x, y, sums, threshold):
    """The bounds of the four squares making the square of 2^level shifts at corner (x, y)
    and heading index h, into ``sums`` (4,) in the order ``_push_children`` takes them:
    their exact sums when they are single shifts. Returns whether one may beat the sum
    ``threshold`` (else ``sums`` may be partial: ``_children_bound``)."""
    if level == 1:
        box = merged.fine_boxes[h]
        _children_exact(pyramid.fine, grid.ix[h], grid.iy[h], box, x, y, sums)
        return True
    lv = level - 2  # where the quarters' level is in `merged`
    row = _MergedRow(
        merged.cells[lv, h],
        merged.linear[lv, h],
        merged.weights[lv, h],
        merged.counts[lv, h],
        merged.boxes[lv, h],
    )
    square = level_square(pyramid, level - 1, x, y)
    return _children_bound(level_grid(pyramid, level - 1), row, square, sums, threshold)


SURVIVOR_LANES = 64
"""Shares of ``_survivors``' squares, each taking every 64th: a batch lists its squares
heading by heading, and those above the threshold crowd at a few headings, so contiguous
shares would leave most of the work to one thread."""


@njit(cache=True, parallel=True)
def _survivors(pyramid, grid, merged, top, divisor, members, threshold):
    """Which of the top squares ``members`` (flat indices into ``top``, bounds in points'
    worth times ``divisor``) have a quarter on the grid whose bound beats the sum
    ``threshold``, on numba's threads (``_descend`` for the arguments)."""
    depth, step = grid.depth, 2**grid.depth
    n_top, n_cells, half = -(-grid.n_cells // step), grid.n_cells, step // 2
    alive = np.zeros(members.size, dtype=np.bool_)
    for lane in prange(SURVIVOR_LANES):
        sums = np.empty(4)
        for i in range(lane, members.size, SURVIVOR_LANES):
            flat = members[i]
            if top[flat] / divisor <= threshold:
                continue
            h, x, y = flat // (n_top * n_top), (flat // n_top) % n_top * step, flat % n_top * step
            if not _quarter_bounds(pyramid, grid, merged, h, depth, x, y, sums, threshold):
                continue
            for c in range(4):
                cx, cy = x + (c % 2) * half, y + (c // 2) * half
                if cx < n_cells and cy < n_cells and sums[c] > threshold:
                    alive[i] = True
    return alive


@njit(cache=True)
def _within_disk(occupied, radius, rim):
    """Which cells of a grid (NA, NB), less a ``rim`` of cells on every side, have an
    occupied cell within ``radius`` cells (centre to centre): (NA − 2·rim, NB − 2·rim), by a
    window along each row offset counted from prefix sums."""
    na, nb = occupied.shape
    prefix = np.zeros((na, nb + 1), dtype=np.int64)
    for a in range(na):
        for b in range(nb):
            prefix[a, b + 1] = prefix[a, b] + occupied[a, b]
    near = np.zeros((max(0, na - 2 * rim), max(0, nb - 2 * rim)), dtype=np.bool_)
    reach = int(np.floor(radius))
    for dx in range(-reach, reach + 1):
        half = int(np.floor(np.sqrt(max(radius * radius - dx * dx, 0.0)) + 1e-9))
        for a in range(max(rim, -dx), min(na - rim, na - dx)):
            row = prefix[a + dx]
            if row[nb] == 0:
                continue
            cells = near[a - rim]
            for b in range(rim, nb - rim):
                if not cells[b - rim] and row[min(nb, b + half + 1)] > row[max(0, b - half)]:
                    cells[b - rim] = True
    return near


def _segment_samples(segments: np.ndarray, spacing_m: float) -> np.ndarray:
    """Points (N, 2) along segments (M, 4) no farther than ``spacing_m`` apart, ends included;
    non-finite segments give none."""
    segments = segments[np.isfinite(segments).all(axis=1)]
    lengths = np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1])
    pieces = np.ceil(lengths / spacing_m).astype(np.int64) + 1
    owner = np.repeat(np.arange(segments.shape[0]), pieces)
    first = np.cumsum(pieces) - pieces
    t = (np.arange(owner.size) - first[owner]) / np.maximum(pieces[owner] - 1, 1)
    a, b = segments[owner, :2], segments[owner, 2:]
    return a + (b - a) * t[:, None]


def distinct(poses: list[Pose2], pose: Pose2, distinct_m: float, distinct_deg: float) -> bool:
    """Whether ``pose`` differs from every pose in ``poses`` by the given margins."""
    for other in poses:
        near = np.hypot(pose.x - other.x, pose.y - other.y) <= distinct_m
        turn = abs(np.rad2deg(wrap_angle(pose.theta - other.theta)))
        if near and turn <= distinct_deg:
            return False
    return True


class HypothesisSearch:
    """Scores candidate poses of scans against one map (M, 4), world frame."""

    def __init__(self, segments_world: np.ndarray, params: SearchParams | None = None):
        self.params = params or SearchParams()
        p = self.params
        self.segments_world = np.asarray(segments_world, dtype=float).reshape(-1, 4)
        self.fine = score_raster(
            self.segments_world, p.cell_m, p.score_radius_m, margin_m=p.score_radius_m
        )
        self.pyramid = max_pyramid(
            self.fine.score, pyramid_depth(self.fine.score.shape, p.max_depth)
        )
        """The fine raster's bounds over squares of 2 to 2^max_depth cells."""
        self._phase_levels: dict[int, np.ndarray] = {}

    def search(
        self,
        points_robot: np.ndarray,
        headings_rad: np.ndarray,
        centre_xy: np.ndarray,
        half_width_m: float,
        reach_m: float | None = None,
        known: Pose2 | None = None,
        first_batch: int = FIRST_BATCH,
        threads: bool | None = None,
    ) -> list[GridPose]:
        """The ``hypotheses`` best distinct grid poses, best first, in a square around
        ``centre_xy``.

        Every heading is combined with every position on the fine grid of the
        square (spacing ``cell_m``), and the score of a pose is the mean raster
        score of the points there. Branch and bound finds the best exactly; poses
        under ``keep_fraction`` of its score are not kept, nor a best under
        ``min_score`` (nothing is found). With
        ``reach_m``, positions farther than that from every map segment are not
        searched (a scan seen from there could not reach the map). ``first_batch`` top
        squares are sorted and searched first (the answer does not depend on it). With
        ``threads`` (by default for a search with ``reach_m``: of the whole map) numba's
        threads share the work, with the same answer.
        """
        p = self.params
        # Contiguous: a strided view (points[::4]) would have numba compile the kernels anew.
        points = np.ascontiguousarray(points_robot, dtype=float).reshape(-1, 2)
        headings = np.atleast_1d(np.asarray(headings_rad, dtype=float))
        if points.shape[0] == 0 or headings.size == 0 or self.segments_world.shape[0] == 0:
            return []
        if not (np.all(np.isfinite(centre_xy)) and np.isfinite(half_width_m)):
            return []
        cell = self.fine.cell_m
        half_cells = int(np.ceil(half_width_m / cell))
        start = np.asarray(centre_xy, dtype=float) - half_cells * cell
        n_cells = 2 * half_cells + 1
        depth = self._top_depth(n_cells, headings.size)
        # Fine cell of every point at every heading, the shift being ``start``.
        cos_sin = np.column_stack([np.cos(headings), np.sin(headings)])
        ix, iy = _point_cells(points, cos_sin, start, self.fine.origin, cell)
        mask = self._reachable(start, n_cells, depth, reach_m)
        n_top = mask.shape[0]
        wide_enough = points.shape[0] * BOUND_LEVELS < 2**31  # int32 top bounds, summed fast
        if depth == 0:
            top_type: type = np.float64
        else:
            top_type = np.int32 if wide_enough else np.int64
        found = _branch_and_bound(
            self.pyramid.arrays(self.fine.score, self._phased(depth)),
            SearchGrid(headings, ix, iy, n_cells, depth, cell),
            Pruning(p.hypotheses, p.keep_fraction, p.distinct_m, np.deg2rad(p.distinct_deg)),
            mask,
            self._known_sum(ix, iy, headings, start, n_cells, known),
            np.empty((headings.size, n_top, n_top), dtype=top_type),
            first_batch,
            threads=reach_m is not None if threads is None else threads,
            floor=p.min_score * points.shape[0],
        )
        xy = start + cell * np.column_stack([found.x, found.y])
        return [
            GridPose(
                Pose2(float(px), float(py), float(headings[k])), float(total / points.shape[0])
            )
            for (px, py), k, total in zip(xy, found.h, found.sums, strict=True)
        ]

    def _top_depth(self, n_cells: int, n_headings: int) -> int:
        """The level the branch and bound starts from: the finest level from
        ``MIN_TOP_LEVEL`` whose squares number at most ``MAX_TOP_SQUARES`` over all headings
        (at most the level whose one square spans the search)."""
        whole = min(self.pyramid.depth, int(np.ceil(np.log2(n_cells))))
        depth = min(MIN_TOP_LEVEL, whole)
        while depth < whole and n_headings * (-(-n_cells // 2**depth)) ** 2 > MAX_TOP_SQUARES:
            depth += 1
        return depth

    def _phased(self, depth: int) -> np.ndarray:
        """Pyramid level ``depth`` split by phase at the stride of its top squares (kept)."""
        if depth == 0:
            return np.zeros((1, 1, 1, 1), dtype=np.uint8)
        if depth not in self._phase_levels:
            step = 2 ** (depth - level_shift(depth))
            self._phase_levels[depth] = phase_split(self.pyramid.level(depth), step)
        return self._phase_levels[depth]

    def _known_sum(
        self,
        ix: np.ndarray,
        iy: np.ndarray,
        headings: np.ndarray,
        start: np.ndarray,
        n_cells: int,
        known: Pose2 | None,
    ) -> float:
        """A lower bound on the best sum, so the search can prune below it from the start: the
        sum at the grid pose nearest ``known``, or a better one of the searched grid poses
        found climbing from it (0 without ``known``, or off the grid).

        The grid pose nearest a good pose can score far below the best: half a heading
        step turns the farthest points by several raster cells.
        """
        if known is None or not np.isfinite([known.x, known.y, known.theta]).all():
            return 0.0
        h = int(np.argmin(np.abs(wrap_angle(headings - known.theta))))
        x, y = np.rint((np.array([known.x, known.y]) - start) / self.fine.cell_m)
        if abs(x) > INDEX_LIMIT or abs(y) > INDEX_LIMIT:
            return 0.0
        return _climbed(self.fine.score, ix, iy, h, int(x), int(y), n_cells)

    def _reachable(
        self, start: np.ndarray, n_cells: int, depth: int, reach_m: float | None
    ) -> np.ndarray:
        """Which squares of 2^depth positions (from ``start``) come within ``reach_m`` of a
        map segment and meet the settings' region, if any (all of them when ``reach_m`` is
        None: a search around a guess)."""
        step = 2**depth
        n_top = -(-n_cells // step)
        if reach_m is None:
            return np.ones((n_top, n_top), dtype=np.bool_)
        side = step * self.fine.cell_m
        # The squares holding points every side/2 along the segments: the nearest point of a
        # segment to a square's centre lies within side/4 of such a sample, and a sample
        # within side/√2 of its square's centre, so comparing centres with the reach grown
        # by side·(√2 + 1/4) keeps every square within reach (and a few more).
        samples = _segment_samples(self.segments_world, side / 2.0)
        limit = reach_m + side * (np.sqrt(2.0) + 0.25)
        # Occupied squares as far as ``limit`` beyond the searched ones: a segment outside a
        # region can still be seen from inside it.
        rim = int(np.ceil(limit / side))
        occupied = np.zeros((n_top + 2 * rim, n_top + 2 * rim), dtype=np.bool_)
        cells = np.floor((samples - start) / side).astype(np.int64) + rim
        inside = np.all((cells >= 0) & (cells < occupied.shape[0]), axis=1)
        occupied[cells[inside, 0], cells[inside, 1]] = True
        mask = _within_disk(occupied, limit / side, rim).ravel()
        if self.params.region is not None:  # squares that meet the region's rectangle
            x0, y0, x1, y1 = self.params.region
            corners = start + side * np.stack(
                np.meshgrid(np.arange(n_top), np.arange(n_top), indexing="ij"), axis=-1
            ).reshape(-1, 2)
            far = corners + side
            meets = (corners[:, 0] <= x1) & (far[:, 0] >= x0)
            mask &= meets & (corners[:, 1] <= y1) & (far[:, 1] >= y0)
        return mask.reshape(n_top, n_top)

    def around(
        self,
        points_robot: np.ndarray,
        initial: Pose2,
        window_deg: float,
        extra_headings=(),
        known: Pose2 | None = None,
    ) -> list[GridPose]:
        """Search the square of ``half_width_m`` around the guess, headings within ± window;
        ``known``, a pose found already (stage 2's), lets it prune from the start."""
        p = self.params
        steps = np.arange(-window_deg, window_deg + 1e-9, p.heading_step_deg)
        headings = np.concatenate([initial.theta + np.deg2rad(steps), np.asarray(extra_headings)])
        centre = np.array([initial.x, initial.y])
        return self.search(points_robot, wrap_angle(headings), centre, p.half_width_m, known=known)

    def everywhere(self, points_robot: np.ndarray) -> list[GridPose]:
        """Search at every heading with no initial guess: within ``region`` if the settings
        give one, else over the whole map wherever the scan's farthest reading could reach
        a map segment from.

        Every heading, not only stage 1's peaks: over a whole map the vote's
        strongest peaks often miss the true heading of a 180° scan.
        """
        p = self.params
        points = np.asarray(points_robot, dtype=float).reshape(-1, 2)
        radii = np.hypot(points[:, 0], points[:, 1])
        reach = float(radii[np.isfinite(radii)].max(initial=0.0))
        headings = np.deg2rad(np.arange(0.0, 360.0, p.heading_step_deg))
        centre, half = self.extent()
        return self.search(points, headings, centre, half, reach)

    def extent(self) -> tuple[np.ndarray, float]:
        """Centre (2,) and half side (m) of the square a global search covers: the region's
        if the settings give one, else the whole map's."""
        if self.params.region is not None:
            x0, y0, x1, y1 = self.params.region
            lo, hi = np.array([x0, y0]), np.array([x1, y1])
        else:
            ends = self.segments_world.reshape(-1, 2)
            lo, hi = ends.min(axis=0), ends.max(axis=0)
        return (lo + hi) / 2.0, float((hi - lo).max() / 2.0)
