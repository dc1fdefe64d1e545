"""Segment maps and occupancy grids: segments drawn as cells, and walls traced out of cells.

Both work in a grid's own frame: metres, cell (column i, row j) covering
[i·r, (i + 1)·r) × [j·r, (j + 1)·r) for a cell side r, so row 0 lies at y = 0 and rows
grow with y. Masks are (rows, columns) boolean arrays indexed ``[row, column]``.

Tracing walls takes four steps.

1. The boundary between occupied and other cells is traced into closed rings (marching
   squares on the cell centres; cells that touch at a corner are one obstacle), each
   listing the occupied cells along it. A surface is taken through the centres of its
   outermost occupied cells: a laser hit marks the cell it falls in, so the surface passes
   through the cells' middles on average, and a wall one cell thick is the line of its
   cells' centres, listed there and back.
2. A ring is cut where it turns back round the free end of such a thin wall, each way
   along the wall a chain of its own; a ring that never turns back is one chain, from its
   cell farthest from its centroid (a corner) round to it again.
3. Each chain is split and merged, and each piece fitted, by the scan extraction's kernels
   (``extract``: recursive split, merge, total-least-squares fit) with a tolerance of
   ``SPLIT_CELLS`` cells. A merged piece that folds back on itself (round the end of a
   wall two or three cells thick) is split again unmerged, and a piece's end cells more
   than half a cell off its line (taken from the next wall round a corner) are trimmed.
   Pieces of fewer than ``ExtractParams.min_points`` cells or shorter than
   ``ExtractParams.min_length_m`` are left out, as in a scan.
4. Segments within half a cell across and one cell along are fused
   (``fusion.fuse_segments``), and a segment lying within half a cell of a longer one
   is dropped: a thin wall's ways there and back become one segment, while the faces of
   thicker walls stay apart, one per side, as a scanner sees them.
"""

from __future__ import annotations

import numpy as np

from segloc_cli.config import ExtractParams, FuseParams
from segloc_cli.geometry import segment_lengths

SPLIT_CELLS = 1.0
"""Split tolerance in cells: the cells of a digital straight line stray up to half a cell
from the line they draw, so a bend of more than a cell is a corner."""


def line_cells(segments_grid: np.ndarray, resolution_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(column, row) arrays of the cells that draw segments (M, 4), metres, grid frame.

    Along the axis a segment runs along most, one cell for each column (or row) from the
    one holding an end to the one holding the other: the cell the segment crosses at that
    column's middle (its end, where it stops short of the middle). A line one cell thick,
    its cells touching at sides or corners; cells may repeat, and may lie outside any given
    grid (negative indices).
    """
    # Cell units with the cells' centres on the integers.
    cells = np.asarray(segments_grid, dtype=float).reshape(-1, 4) / resolution_m - 0.5
    start, end = cells[:, :2], cells[:, 2:]
    delta = end - start
    along = (np.abs(delta[:, 1]) > np.abs(delta[:, 0])).astype(np.int64)  # 0: x, 1: y
    index = np.arange(len(cells))
    first = np.floor(start[index, along] + 0.5).astype(np.int64)
    last = np.floor(end[index, along] + 0.5).astype(np.int64)
    count = np.abs(last - first) + 1
    owner = np.repeat(index, count)
    step = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    axis = along[owner]
    major = first[owner] + np.sign(last - first)[owner] * step
    span = delta[owner, axis]
    fraction = np.divide(
        major - start[owner, axis], span, out=np.zeros(owner.size), where=span != 0
    )
    minor = start[owner, 1 - axis] + np.clip(fraction, 0.0, 1.0) * delta[owner, 1 - axis]
    minor_cell = np.floor(minor + 0.5).astype(np.int64)
    return np.where(axis == 0, major, minor_cell), np.where(axis == 0, minor_cell, major)


def trace_walls(occupied: np.ndarray, resolution_m: float) -> np.ndarray:
    """Segments (K, 4), metres, grid frame, along the occupied cells of a mask (rows,
    columns) of cells ``resolution_m`` wide (see the module docstring)."""
    from segloc_cli.maps.fusion import fuse_segments  # kernels: loaded to trace, not to draw

    params = ExtractParams(split_m=SPLIT_CELLS * resolution_m)
    cells, chains = _chains(*_surface_rings(occupied))
    pieces = _chain_segments(cells, chains, resolution_m, params)
    fused = fuse_segments(pieces, FuseParams(offset_m=0.5 * resolution_m, gap_m=resolution_m))
    return fused[~_covered(fused, 0.5 * resolution_m)]


def _covered(segments: np.ndarray, within_m: float) -> np.ndarray:
    """Mask (M,) of the segments (M, 4) both of whose ends lie within ``within_m`` of one
    longer segment (of equal length: one listed before): a short piece of a face that fusion
    could not join, its direction too uncertain to pass the test both ways."""
    from segloc_cli.method.spatial import SegmentGrid

    lengths = segment_lengths(segments)
    offsets, near = SegmentGrid(segments).within(segments.reshape(-1, 2), within_m)
    point = np.repeat(np.arange(offsets.size - 1), np.diff(offsets))
    owner, end = point // 2, point % 2
    key = owner * segments.shape[0] + near
    both = np.intersect1d(key[end == 0], key[end == 1])
    shorter, longer = both // segments.shape[0], both % segments.shape[0]
    beaten = (lengths[longer] > lengths[shorter]) | (
        (lengths[longer] == lengths[shorter]) & (longer < shorter)
    )
    covered = np.zeros(segments.shape[0], dtype=bool)
    covered[shorter[beaten]] = True
    return covered


# Marching squares over the squares whose corners are four neighbouring cell centres,
# at (column, row) offsets (0, 0), (1, 0), (1, 1), (0, 1): the corners' bits (1, 2, 4, 8,
# set where occupied) give the square's case; each case crosses two or four of its sides,
# side k joining corner k to corner k + 1 (mod 4). A piece runs from one crossing to the
# next with the occupied corners on its left, so every crossing starts one piece and ends
# one, and the pieces close into rings. The two saddle cases keep occupied corners that
# touch diagonally joined.
_CORNERS = ((0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0))
_SIDES = ((0.5, 0.0), (1.0, 0.5), (0.5, 1.0), (0.0, 0.5))  # the sides' middles
_SADDLES = {5: ((0, 1), (2, 3)), 10: ((3, 0), (1, 2))}  # sides paired round a free corner


def _case_pieces() -> dict[int, tuple[tuple[int, int], ...]]:
    """For each case 1–14, its pieces as (from side, to side), occupied on the left."""
    table = {}
    for case in range(1, 15):
        bits = [(case >> k) & 1 for k in range(4)]
        crossed = [side for side in range(4) if bits[side] != bits[(side + 1) % 4]]
        pairs = _SADDLES.get(case, (tuple(crossed),))
        table[case] = tuple(_oriented(a, b, bits) for a, b in pairs)
    return table


def _oriented(a: int, b: int, bits: list[int]) -> tuple[int, int]:
    """(a, b) or (b, a): the order with the occupied corners left of the piece.

    Decided by the corners on the side of fewer: a saddle's piece has a lone free corner
    there, the other side mixing free and occupied ones.
    """
    (ax, ay), (bx, by) = _SIDES[a], _SIDES[b]
    left = [(bx - ax) * (cy - ay) - (by - ay) * (cx - ax) > 0 for cx, cy in _CORNERS]
    minority = left.count(True) <= 2
    corner = left.index(minority)
    return (a, b) if bool(bits[corner]) == minority else (b, a)


_PIECES = _case_pieces()


def _surface_rings(occupied: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The boundary of the occupied cells of a mask (rows, columns) as closed rings.

    Returns, ring after ring, the occupied cell (column, row) (N, 2) beside each crossing
    of the boundary, and the index (R + 1,) where each ring starts, N last.
    """
    padded = np.pad(np.asarray(occupied, dtype=bool), 1)
    rows, columns = occupied.shape
    case = (
        padded[:-1, :-1] * 1 + padded[:-1, 1:] * 2 + padded[1:, 1:] * 4 + padded[1:, :-1] * 8
    ).astype(np.int8)
    # Crossings are numbered by the pair of neighbouring cells they lie between: first
    # the pairs along a row (padded row i, columns j and j + 1), then those along a column
    # (rows i and i + 1, column j).
    along_rows = (rows + 2) * (columns + 1)
    square_i, square_j = np.nonzero((case != 0) & (case != 15))
    square_case = case[square_i, square_j]
    side_ids = np.stack(
        [
            square_i * (columns + 1) + square_j,
            along_rows + square_i * (columns + 2) + square_j + 1,
            (square_i + 1) * (columns + 1) + square_j,
            along_rows + square_i * (columns + 2) + square_j,
        ],
        axis=1,
    )
    starts, ends = [np.zeros(0, dtype=np.int64)], [np.zeros(0, dtype=np.int64)]
    for kind, pieces in _PIECES.items():
        at = np.flatnonzero(square_case == kind)
        for a, b in pieces:
            starts.append(side_ids[at, a])
            ends.append(side_ids[at, b])
    start, end = np.concatenate(starts), np.concatenate(ends)
    order = np.argsort(start, kind="stable")
    ids = start[order]
    successor = np.searchsorted(ids, end[order])
    ring_order = _ring_order(successor)
    ids = ids[ring_order]
    in_row = ids < along_rows
    i = np.where(in_row, ids // (columns + 1), (ids - along_rows) // (columns + 2))
    j = np.where(in_row, ids % (columns + 1), (ids - along_rows) % (columns + 2))
    # The occupied cell of the pair: (i, j) or its neighbour across the crossing.
    across = ~padded[i, j]
    cells = np.stack([j + (across & in_row) - 1, i + (across & ~in_row) - 1], axis=1)
    return cells, _ring_starts(successor, ring_order)


def _ring_order(successor: np.ndarray) -> np.ndarray:
    """The permutation that lists the cycles of ``successor`` (N,) one after another, each
    from its smallest index along the successor links, cycles in order of that index.

    Pointer jumping: log₂ N rounds of vectorised gathers instead of a walk per ring.
    """
    n = successor.size
    index = np.arange(n)
    label = index.copy()
    jump = successor.copy()
    rounds = max(1, int(n).bit_length())
    for _ in range(rounds):
        label = np.minimum(label, label[jump])
        jump = jump[jump]
    # Cut each cycle before its start and count the steps from every member to the cut.
    predecessor = np.empty(n, dtype=np.int64)
    predecessor[successor] = index
    last = predecessor[index[label == index]]
    link = successor.copy()
    link[last] = last
    steps = (link != index).astype(np.int64)
    for _ in range(rounds):
        steps = steps + steps[link]
        link = link[link]
    rank = np.bincount(label, minlength=n)[label] - 1 - steps
    return np.lexsort((rank, label))


def _ring_starts(successor: np.ndarray, ring_order: np.ndarray) -> np.ndarray:
    """Where each ring starts in ``ring_order``, N last: a ring ends at the crossing whose
    successor is not the next one listed."""
    n = ring_order.size
    position = np.empty(n, dtype=np.int64)
    position[ring_order] = np.arange(n)
    closes = position[successor[ring_order]] != np.arange(n) + 1
    return np.concatenate([[0], np.flatnonzero(closes) + 1]) if n else np.zeros(1, np.int64)


def _chains(cells: np.ndarray, starts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rings of cells (N, 2) starting at ``starts`` (R + 1,) as open chains to split.

    A ring turns back where it rounds the free end of a wall one cell thick: a cell whose
    neighbours along the ring (once repeats are dropped) are one cell. The ring is cut
    there, each way along the wall a chain of its own: a split can lose a turn that comes
    back onto its own chord. A ring that never turns back is one chain, from its cell
    farthest from its centroid (an extreme point: a corner) round to that cell again.

    Returns the chains' cells (K, 2), each ring once round from its first cut and closing
    on it, and each chain's index range [start, stop) (C, 2) in them; chains meet at cuts.
    """
    ring = np.repeat(np.arange(starts.size - 1), np.diff(starts))
    cells, ring = _without_repeats(cells, ring)
    # Rings of one or two cells (a lone cell, a pair) hold no piece: left out.
    sizes = np.bincount(ring, minlength=starts.size - 1)
    keep = sizes[ring] >= 3
    if not keep.any():
        return np.zeros((0, 2)), np.zeros((0, 2), dtype=np.int64)
    cells, ring = cells[keep], np.unique(ring[keep], return_inverse=True)[1]
    sizes = np.bincount(ring)
    starts = np.concatenate([[0], np.cumsum(sizes)])
    position = np.arange(cells.shape[0]) - starts[ring]
    before = starts[ring] + (position - 1) % sizes[ring]
    after = starts[ring] + (position + 1) % sizes[ring]
    cut = np.all(cells[before] == cells[after], axis=1)
    # Each ring from its first cut, or from its farthest cell when it has none.
    centroid = np.add.reduceat(cells, starts[:-1], axis=0) / sizes[:, None]
    score = np.sum((cells - centroid[ring]) ** 2, axis=1)
    score = np.where(cut, np.inf, score)
    first = _first_of_largest(score, ring, starts)
    turned = starts[ring] + (position + first[ring] - starts[ring]) % sizes[ring]
    cells, cut = cells[turned], cut[turned]
    # Each ring closes on its first cell, repeated in the slot before the next ring.
    slots = np.insert(np.arange(cells.shape[0]), starts[1:], starts[:-1])
    slot_starts = starts + np.arange(starts.size)
    bound = cut[slots]
    bound[slot_starts[:-1]] = True
    bound[slot_starts[1:] - 1] = True
    at = np.flatnonzero(bound)
    same_ring = np.searchsorted(slot_starts, at[1:], side="right") == np.searchsorted(
        slot_starts, at[:-1], side="right"
    )
    chains = np.stack([at[:-1], at[1:] + 1], axis=1)[same_ring]
    return cells[slots], chains


def _without_repeats(cells: np.ndarray, ring: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cells (N, 2) of rings (labels ``ring`` (N,), contiguous) less each cell that repeats
    the one before it along its ring (the last counting before the first)."""
    if cells.shape[0] == 0:
        return cells.astype(float), ring
    first = np.concatenate([[True], ring[1:] != ring[:-1]])
    last_of = np.flatnonzero(np.concatenate([ring[1:] != ring[:-1], [True]]))
    previous = np.arange(cells.shape[0]) - 1
    previous[first] = last_of
    keep = np.any(cells != cells[previous], axis=1)
    return cells[keep].astype(float), ring[keep]


def _first_of_largest(score: np.ndarray, ring: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """For each ring (R,), the index of its first largest score (rings of ``starts``)."""
    sizes = np.diff(starts)
    best = np.full(sizes.size, -np.inf)
    np.maximum.at(best, ring, score)
    is_best = score == best[ring]
    chosen = np.zeros(sizes.size, dtype=np.int64)
    _, first = np.unique(ring[is_best], return_index=True)
    chosen[np.unique(ring[is_best])] = np.flatnonzero(is_best)[first]
    return chosen


def _chain_segments(
    cells: np.ndarray, chains: np.ndarray, resolution_m: float, params: ExtractParams
) -> np.ndarray:
    """Straight pieces (K, 4), metres, grid frame, of the chains [start, stop) (C, 2) of
    cells (N, 2): each chain split and merged, and each piece fitted, as in a scan.

    A merged piece that folds back on itself (the way round the end of a wall two or three
    cells thick, whose faces one line fits within the tolerance) is split again without
    merging, so that each face keeps its own segment; each piece is then trimmed
    (``_trimmed``) before its fit.
    """
    # The scan extraction's kernels: to them a chain of cells is a run of points.
    from segloc_cli.method.extract import pieces_of_run, segment_of_piece, split_points

    xs = np.ascontiguousarray((cells[:, 0] + 0.5) * resolution_m)
    ys = np.ascontiguousarray((cells[:, 1] + 0.5) * resolution_m)
    sizes = chains[:, 1] - chains[:, 0]
    scratch = np.empty(xs.size)
    unmerged = np.empty((int(sizes.max(initial=0)) + 1, 2), dtype=np.int64)
    tol_m, min_points = float(params.split_m), int(params.min_points)
    min_length_m = float(params.min_length_m)
    # Neighbours along a chain lie at most a cell's diagonal apart.
    can_hold = np.sqrt(2.0) * resolution_m * (sizes - 1) >= min_length_m
    found = [np.zeros((0, 4))]
    for start, stop in chains[can_hold & (sizes >= min_points)].tolist():
        pieces = []
        for first, last in pieces_of_run(xs, ys, start, stop, tol_m, scratch).tolist():
            if _folds_back(xs[first:last], ys[first:last], 2.0 * tol_m):
                count = split_points(xs, ys, first, last, tol_m, unmerged)
                pieces.extend(unmerged[:count].tolist())
            else:
                pieces.append((first, last))
        out = np.empty((len(pieces), 4))
        kept = 0
        for piece_first, piece_last in pieces:
            first, last = _trimmed(xs, ys, piece_first, piece_last, 0.5 * resolution_m)
            # No direction test (σ = ∞): cells are not noisy readings.
            if last - first >= min_points and segment_of_piece(
                xs, ys, first, last, min_points, min_length_m, np.inf, 0.0, scratch, out[kept]
            ):
                kept += 1
        found.append(out[:kept])
    return np.concatenate(found)


def _trimmed(xs: np.ndarray, ys: np.ndarray, first: int, last: int, limit_m: float):
    """The piece [first, last) of points less its leading and trailing points farther than
    ``limit_m`` from its line (refitted as they go): the cells a merge took from the next
    wall round a corner, which a digital line's own cells (within half a cell) never are."""
    from segloc_cli.method.extract import fit_line, line_residuals

    while last - first > 2:
        points = np.column_stack([xs[first:last], ys[first:last]])
        off = line_residuals(points, *fit_line(points)) > limit_m
        if not (off[0] or off[-1]):
            break
        first += int(off[0])
        last -= int(off[-1])
    return first, last


def _folds_back(xs: np.ndarray, ys: np.ndarray, slack_m: float) -> bool:
    """Whether points (K,) in order run along their fitted line beyond the span between the
    first and the last by more than ``slack_m`` metres: out and back again."""
    from segloc_cli.method.extract import fit_line

    centroid, direction = fit_line(np.column_stack([xs, ys]))
    along = (xs - centroid[0]) * direction[0] + (ys - centroid[1]) * direction[1]
    return float(np.ptp(along) - abs(along[-1] - along[0])) > slack_m
