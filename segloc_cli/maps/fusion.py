"""Global map from local maps at known poses.

Local maps are moved into the world frame and fused: segments that are nearly
collinear and overlap or nearly touch along their common line become one
segment, fitted to all of them with each weighted by its length, spanning the
union of their extents. Fusion repeats until no two segments match any more,
so chains of overlapping pieces collapse into one segment per wall and the
result holds no overlapping duplicates (see ``overlapping_duplicates``).

A chain of pairwise matches can drift: A matches B, B matches C, yet A and C
lie on different lines (two parallel walls a few centimetres apart, a wall and
the furniture along it). A group is fused into one segment only if every
member lies on the fitted line within the same tolerances; otherwise it is
regrown from its longest member, one line at a time.

Surveyed poses that are themselves estimates (a SLAM solution) put each wall down a little
differently from each pass, and the fused map holds the blur. ``polish_poses`` re-fits each
scan to the map the other half of the scans make, before fusing.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import NamedTuple

import numpy as np

from segloc_cli.config import FuseParams
from segloc_cli.geometry import Pose2, segment_lengths, transform_segments
from segloc_cli.jit import njit
from segloc_cli.progress import SILENT, Progress, ProgressFactory, silent

TOUCH_M = 1e-9
"""Overlap (metres) below which two pieces only touch: rounding, not a shared stretch."""


def fit_segments(segments: np.ndarray) -> np.ndarray:
    """One segment (4,) fitted to segments (K, 4): length-weighted total least squares.

    Each segment counts as a uniform line of mass, so the fit is the principal
    axis of all of them; the result spans the projections of every endpoint.
    Same frame as the input.
    """
    segments = np.asarray(segments, dtype=float).reshape(-1, 4)
    if segments.shape[0] == 0:
        raise ValueError("no segments to fit")
    return _fit_groups(segments, np.zeros(segments.shape[0], dtype=np.int64), 1)[0]


def _fit_groups(segments: np.ndarray, group: np.ndarray, n_groups: int) -> np.ndarray:
    """``fit_segments`` of each group at once: segments (K, 4) with labels 0..n_groups-1.

    Returns (n_groups, 4); every label must have at least one member.
    """
    p, q = segments[:, :2], segments[:, 2:]
    length = segment_lengths(segments)
    u = (q - p) / np.where(length > 0, length, 1.0)[:, None]
    mid = 0.5 * (p + q)

    def weighted_sum(values):
        return np.bincount(group, values, n_groups)

    total = weighted_sum(length)
    centroid = np.column_stack([weighted_sum(length * mid[:, k]) for k in (0, 1)]) / total[:, None]
    r = mid - centroid[group]
    # Second moment of a uniform segment about its midpoint is l³/12 · u uᵀ.
    inertia = length**3 / 12.0

    def moment(a, b):
        return weighted_sum(length * r[:, a] * r[:, b] + inertia * u[:, a] * u[:, b])

    # Major axis of the symmetric 2×2 scatter [[sxx, sxy], [sxy, syy]].
    axis = 0.5 * np.arctan2(2.0 * moment(0, 1), moment(0, 0) - moment(1, 1))
    direction = np.column_stack([np.cos(axis), np.sin(axis)])
    tp = _dot(p - centroid[group], direction[group])
    tq = _dot(q - centroid[group], direction[group])
    t_min = np.full(n_groups, np.inf)
    t_max = np.full(n_groups, -np.inf)
    np.minimum.at(t_min, group, np.minimum(tp, tq))
    np.maximum.at(t_max, group, np.maximum(tp, tq))
    return np.hstack([centroid + t_min[:, None] * direction, centroid + t_max[:, None] * direction])


GRID_CELL_M = 1.0
"""Cell size of the spatial grid that proposes candidate pairs."""


def _orientation_bins(segments: np.ndarray, angle_rad: float) -> tuple[np.ndarray, int]:
    """Bin (M,) of each segment's undirected orientation, and the number of bins.

    Bins are strictly wider than ``angle_rad``, so two segments whose
    orientations differ by at most that fall in the same or in neighbouring
    bins (cyclically: the last bin neighbours the first). With fewer than
    three bins there is no such split, and everything goes in one bin.
    """
    n_bins = int(np.pi / angle_rad) - 1 if angle_rad > 0 else 1
    if n_bins < 3:
        return np.zeros(segments.shape[0], dtype=np.int64), 1
    d = segments[:, 2:] - segments[:, :2]
    theta = np.mod(np.arctan2(d[:, 1], d[:, 0]), np.pi)
    return np.floor(theta / (np.pi / n_bins)).astype(np.int64) % n_bins, n_bins


PAIRING_ENTRIES = 1 << 13
"""About how many grid entries (a segment in one cell and orientation bin) are paired at once:
a large map's candidate pairs are found a stretch of grid columns at a time, which bounds
the memory they take and lets the progress of a long fusion be told."""


def _nearby_pairs(
    segments: np.ndarray, margin_m: float, angle_rad: float = np.pi
) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i < j) that may be closer than ``margin_m`` and within ``angle_rad``.

    Every such pair comes out exactly once, together with pairs that are not
    (the caller tests them): those whose bounding boxes, grown by the margin,
    share a grid cell and whose orientation bins are equal or neighbours.
    Far-apart segments and walls across a corner are never compared, so
    fusing a long log stays near linear.
    """
    found = [(i, j) for i, j, _ in _nearby_pair_stretches(segments, margin_m, angle_rad)]
    if not found:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    return np.concatenate([i for i, _ in found]), np.concatenate([j for _, j in found])


class _Entries(NamedTuple):
    """The grid entries of ``_nearby_pair_stretches``, a segment per covered cell and
    orientation bin, and the stretches of grid columns they fall in."""

    owner: np.ndarray
    key: np.ndarray
    entry_bin: np.ndarray
    cx: np.ndarray
    cy: np.ndarray
    c_lo: np.ndarray
    bins: np.ndarray
    by_stretch: np.ndarray
    bounds: np.ndarray
    done: np.ndarray


def _grid_entries(
    segments: np.ndarray, margin_m: float, angle_rad: float, entries: int | None = None
) -> _Entries:
    """Every segment filed in each grid cell its box (grown by the margin) covers, in its
    own orientation bin and the next, and the stretches of columns of about ``entries``
    entries each that ``_nearby_pair_stretches`` takes one at a time."""
    n = segments.shape[0]
    bins, n_bins = _orientation_bins(segments, angle_rad)
    lo = np.minimum(segments[:, :2], segments[:, 2:]) - margin_m
    hi = np.maximum(segments[:, :2], segments[:, 2:]) + margin_m
    c_lo = np.floor(lo / GRID_CELL_M).astype(np.int64)
    c_hi = np.floor(hi / GRID_CELL_M).astype(np.int64)
    nx = c_hi[:, 0] - c_lo[:, 0] + 1
    ny = c_hi[:, 1] - c_lo[:, 1] + 1
    # One entry per (segment, covered cell, own bin or the next one).
    per_bin = 2 if n_bins > 1 else 1
    count = nx * ny * per_bin
    owner = np.repeat(np.arange(n), count)
    k = np.arange(owner.size) - np.repeat(np.cumsum(count) - count, count)
    cell = k // per_bin
    entry_bin = (bins[owner] + k % per_bin) % n_bins
    cx = c_lo[owner, 0] + cell % nx[owner]
    cy = c_lo[owner, 1] + cell // nx[owner]
    # The key grows with the column, so a stretch of columns is a stretch of sorted keys.
    cell_key = (cx - cx.min()) * (cy.max() - cy.min() + 1) + (cy - cy.min())
    key = cell_key * n_bins + entry_bin
    per_stretch = max(PAIRING_ENTRIES if entries is None else entries, 1)
    column_stretch = (np.cumsum(np.bincount(cx - cx.min())) - 1) // per_stretch
    stretch = column_stretch[cx - cx.min()]
    n_stretches = int(column_stretch[-1]) + 1
    by_stretch = np.argsort(stretch, kind="stable")
    bounds = np.searchsorted(stretch[by_stretch], np.arange(n_stretches + 1))
    done = np.bincount(column_stretch[c_hi[:, 0] - cx.min()], minlength=n_stretches)
    return _Entries(owner, key, entry_bin, cx, cy, c_lo, bins, by_stretch, bounds, done)


def _stretch_order(entries: _Entries, s: int) -> np.ndarray:
    """The entries of stretch ``s``, by key, and of one key by segment."""
    chosen = entries.by_stretch[entries.bounds[s] : entries.bounds[s + 1]]
    return chosen[np.lexsort((entries.owner[chosen], entries.key[chosen]))]


def _nearby_pair_stretches(
    segments: np.ndarray,
    margin_m: float,
    angle_rad: float = np.pi,
    entries: int | None = None,
) -> Iterator[tuple[np.ndarray, np.ndarray, int]]:
    """``_nearby_pairs`` a stretch of grid columns at a time, west to east, each stretch of
    about ``entries`` grid entries (default ``PAIRING_ENTRIES``; a column with more is a
    stretch of its own): (i, j, done)
    per stretch, ``done`` the count of segments whose last column it holds, whose pairs are
    all out once it is (over all stretches, every segment). The pairs come in the order one
    stretch of all columns would give them."""
    n = segments.shape[0]
    if n < 2:
        yield np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), n
        return
    e = _grid_entries(segments, margin_m, angle_rad, entries)
    apart = np.arange(n)  # every segment a group of its own: no pair is left out
    out_i, out_j = np.empty(JOIN_PAIRS, dtype=np.int64), np.empty(JOIN_PAIRS, dtype=np.int64)
    for stretch in range(e.done.size):
        found_i, found_j = [], []
        for n_out in _stretch_pairs(e, stretch, apart, out_i, out_j):
            found_i.append(out_i[:n_out].copy())
            found_j.append(out_j[:n_out].copy())
        yield np.concatenate(found_i), np.concatenate(found_j), int(e.done[stretch])


def _stretch_pairs(
    e: _Entries, stretch: int, labels: np.ndarray, out_i: np.ndarray, out_j: np.ndarray
) -> Iterator[int]:
    """The candidate pairs of ``stretch`` not in one group of ``labels`` (``_open_pairs``),
    a batch at a time into ``out_i`` and ``out_j``: how many each time (at least once)."""
    order = _stretch_order(e, stretch)
    entries = (e.key[order], e.owner[order], e.cx[order], e.cy[order], e.entry_bin[order])
    state = np.zeros(3, dtype=np.int64)
    while state[2] == 0:
        yield _open_pairs(*entries, e.c_lo, e.bins, labels, state, out_i, out_j)


@njit(cache=True)
def _open_pairs(key, owner, cx, cy, entry_bin, c_lo, bins, labels, state, out_i, out_j):
    """The segment pairs (i < j) of entries sharing a key (a cell and bin; the stretch's
    entries sorted by key, then segment: ``key``, ``owner``, ``cx``, ``cy``, ``entry_bin``),
    each once, less those whose segments ``labels`` already puts in one group, from where
    ``state`` (3,: entry a, entry b, and 1 once the stretch is done) left off, into
    ``out_i``/``out_j`` until they are full; returns how many, ``state`` updated. Boxes
    that share cells share a rectangle of them, and segments in the same bin share it and
    the next: a pair is taken only in its lowest cell and bin."""
    n, n_out = key.size, 0
    a, b = state[0], state[1]
    while a < n:
        if b <= a:
            b = a + 1
        while b < n and key[b] == key[a]:
            i, j = owner[a], owner[b]
            if (
                labels[i] != labels[j]
                and cx[a] == max(c_lo[i, 0], c_lo[j, 0])
                and cy[a] == max(c_lo[i, 1], c_lo[j, 1])
                and (bins[i] != bins[j] or entry_bin[a] == bins[i])
            ):
                if n_out == out_i.size:
                    state[0], state[1] = a, b
                    return n_out
                out_i[n_out], out_j[n_out] = i, j
                n_out += 1
            b += 1
        a += 1
        b = a + 1
    state[0], state[1], state[2] = n, n, 1
    return n_out


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product of 2-vectors (..., 2), spelt out: faster than a reduction."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]


def _lies_on(
    lines: np.ndarray, segments: np.ndarray, params: FuseParams
) -> tuple[np.ndarray, np.ndarray]:
    """Whether segments lie on lines, and their gaps along them; rows pair up, (4,) broadcasts.

    A segment lies on a line when its orientation is within ``angle_deg`` and
    both its ends are within ``offset_m`` of the (infinite) line. The gap is
    that of ``_gaps`` against the line's extent (metres, negative = overlap).
    Every match test of this module goes through here, so that a pair found by
    ``mergeable_pairs`` is also joined when its group is regrown.
    """
    start, end = lines[..., :2], lines[..., 2:]
    line_length = np.hypot(end[..., 0] - start[..., 0], end[..., 1] - start[..., 1])
    u = (end - start) / line_length[..., None]
    normal = np.stack([-u[..., 1], u[..., 0]], axis=-1)
    p, q = segments[..., :2], segments[..., 2:]
    d = q - p
    cos = np.abs(_dot(d, u)) / np.maximum(np.hypot(d[..., 0], d[..., 1]), 1e-300)
    offset = np.maximum(np.abs(_dot(p - start, normal)), np.abs(_dot(q - start, normal)))
    on = (cos >= np.cos(np.deg2rad(params.angle_deg))) & (offset <= params.offset_m)
    return on, _gaps(start, u, line_length, p, q)


def _matches(
    segments: np.ndarray, params: FuseParams, progress: Progress = SILENT
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs (i < j) that lie on each other's line, with the larger of their two gaps (m).

    Only pairs whose gap is at most ``gap_m`` are returned. Each segment compared with its
    neighbours is a step of ``progress``.
    """
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    margin_m = max(params.offset_m, params.gap_m)
    found = []
    for i, j, done in _nearby_pair_stretches(s, margin_m, np.deg2rad(params.angle_deg)):
        keep, gap = _mergeable(s, i, j, params)
        found.append((i[keep], j[keep], gap[keep]))
        progress.advance(done)
    i, j, gap = (np.concatenate(parts) for parts in zip(*found, strict=True))
    return i, j, gap


def _mergeable(
    s: np.ndarray, i: np.ndarray, j: np.ndarray, params: FuseParams
) -> tuple[np.ndarray, np.ndarray]:
    """Which pairs (i, j) of segments ``s`` are mergeable (each lies on the other's line,
    their gap at most ``gap_m``), and the larger of their two gaps (m)."""
    on_i, gap_i = _lies_on(s[i], s[j], params)
    on_j, gap_j = _lies_on(s[j], s[i], params)
    gap = np.maximum(gap_i, gap_j)
    return on_i & on_j & (gap <= params.gap_m), gap


JOIN_PAIRS = 1 << 16
"""Candidate pairs tested at once by ``_mergeable_groups``, between joins."""


def _mergeable_groups(
    segments: np.ndarray, params: FuseParams, progress: Progress = SILENT
) -> np.ndarray | None:
    """The group (M,) of each segment: the smallest index of those joined to it by a chain
    of ``mergeable_pairs``; None where no pair is mergeable. The candidate pairs of each
    stretch of the grid are listed ``JOIN_PAIRS`` at a time (``_open_pairs``), tested and
    joined, those already in one group left out: a wall seen from hundreds of poses makes
    tens of thousands of pairs, nearly all of them joined by the first few."""
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    labels = np.arange(s.shape[0])
    if s.shape[0] < 2:
        progress.advance(s.shape[0])
        return None
    joined = False
    margin_m = max(params.offset_m, params.gap_m)
    e = _grid_entries(s, margin_m, np.deg2rad(params.angle_deg))
    out_i, out_j = np.empty(JOIN_PAIRS, dtype=np.int64), np.empty(JOIN_PAIRS, dtype=np.int64)
    for stretch in range(e.done.size):
        for n_out in _stretch_pairs(e, stretch, labels, out_i, out_j):
            a, b = out_i[:n_out], out_j[:n_out]
            keep, _ = _mergeable(s, a, b, params)
            joined |= bool(keep.any())
            _join(labels, a[keep], b[keep])
        progress.advance(int(e.done[stretch]))
    return labels if joined else None


def _join(labels: np.ndarray, i: np.ndarray, j: np.ndarray) -> None:
    """Join the groups of the pairs (i, j) in ``labels`` (each node's group: the smallest
    node of it so far; a group's smallest node is its own), in place."""
    while True:
        a, b = labels[i], labels[j]
        differ = a != b
        if not differ.any():
            return
        np.minimum.at(labels, np.maximum(a, b)[differ], np.minimum(a, b)[differ])
        while True:  # every node to its group's smallest node
            up = labels[labels]
            if np.array_equal(up, labels):
                break
            labels[:] = up


def mergeable_pairs(
    segments: np.ndarray, params: FuseParams, progress: Progress = SILENT
) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i < j) of segments (M, 4) that describe the same wall.

    Each lies on the other's line (orientation within ``angle_deg``, both ends
    within ``offset_m`` of it) and their extents along it overlap or leave a
    gap of at most ``gap_m``. Any frame, metres. Each segment compared with its neighbours
    is a step of ``progress``.
    """
    i, j, _ = _matches(segments, params, progress)
    return i, j


def overlapping_duplicates(
    segments: np.ndarray, params: FuseParams | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i < j) of segments (M, 4) that are one stretch of wall held twice.

    Mergeable pairs (``mergeable_pairs``) whose extents overlap along each
    other's line by more than ``TOUCH_M``: pieces that merely touch or leave a
    gap are not duplicates. A fused map has none. Any frame, metres.
    """
    i, j, gap = _matches(segments, params or FuseParams())
    overlapping = gap < -TOUCH_M
    return i[overlapping], j[overlapping]


def _regrow(segments: np.ndarray, params: FuseParams) -> tuple[np.ndarray, np.ndarray]:
    """Segments (K, 4) of a group that no one line fits → one fitted segment per line they
    hold (L, 4), and the line each segment joined (K,).

    Starts from the longest segment and adds every segment that lies on the
    current line and is within ``gap_m`` of its extent, refitting after each
    step; what never joins seeds the next line.
    """
    lines: list[np.ndarray] = []
    line_of = np.empty(segments.shape[0], dtype=np.int64)
    remaining = np.argsort(-segment_lengths(segments), kind="stable")
    while remaining.size:
        members = remaining[:1]
        remaining = remaining[1:]
        line = segments[members[0]]
        while remaining.size:
            on, gap = _lies_on(line, segments[remaining], params)
            join = on & (gap <= params.gap_m)
            if not join.any():
                break
            members = np.concatenate([members, remaining[join]])
            remaining = remaining[~join]
            line = fit_segments(segments[members])
        line_of[members] = len(lines)
        lines.append(line)
    return np.array(lines), line_of


def _gaps(start, direction, length, p, q) -> np.ndarray:
    """Gap between each extent p–q and a line's (start, unit direction, length) along the line.

    Negative where they overlap. Arguments broadcast: one line against many
    segments, or pairs row by row.
    """
    tp = _dot(p - start, direction)
    tq = _dot(q - start, direction)
    return np.maximum(np.minimum(tp, tq) - length, -np.maximum(tp, tq))


def _fuse_groups(
    segments: np.ndarray, labels: np.ndarray, params: FuseParams
) -> tuple[np.ndarray, np.ndarray]:
    """Segments (M, 4) with group labels (M,) → one or more segments per group, in group order,
    and the one each segment went into (M,).

    A lone segment is kept as it is; a group whose members all lie on their
    length-weighted fit becomes that fit; any other group is regrown.
    """
    _, first, group = np.unique(labels, return_index=True, return_inverse=True)
    n_groups = first.size
    size = np.bincount(group, minlength=n_groups)
    lines = _fit_groups(segments, group, n_groups)
    on, _ = _lies_on(lines[group], segments, params)
    consistent = np.bincount(group, ~on, n_groups) == 0
    lines[size == 1] = segments[first[size == 1]]
    out, out_group = [lines[consistent]], [np.flatnonzero(consistent)]
    # Where each segment goes among the pieces of ``out``, before they are put in group order.
    slot = np.cumsum(consistent) - 1
    went = slot[group]
    n_out = int(consistent.sum())
    members = np.split(np.argsort(group, kind="stable"), np.cumsum(size)[:-1])
    for g in np.flatnonzero(~consistent):
        regrown, line_of = _regrow(segments[members[g]], params)
        out.append(regrown)
        out_group.append(np.full(len(regrown), g))
        went[members[g]] = n_out + line_of
        n_out += len(regrown)
    order = np.argsort(np.concatenate(out_group), kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return np.concatenate(out)[order], rank[went]


def fuse_segments(
    segments_world: np.ndarray,
    params: FuseParams | None = None,
    progress: ProgressFactory = silent,
) -> np.ndarray:
    """Fuse duplicate observations of the same walls; returns (M', 4), M' <= M, same frame.

    Repeats until ``mergeable_pairs`` finds nothing, so the result has no
    overlapping duplicates either. Every round each group of matching segments
    loses at least one member (the longest one absorbs its partners), so the
    loop ends. ``progress`` counts the segments of the first round compared with their
    neighbours: that round takes the most time by far (fusing FR079's 38,163 local segments,
    the next round starts from 3,091).
    """
    return fuse_traced(segments_world, params, progress)[0]


def fuse_traced(
    segments_world: np.ndarray,
    params: FuseParams | None = None,
    progress: ProgressFactory = silent,
) -> tuple[np.ndarray, np.ndarray]:
    """``fuse_segments`` of segments (K, 4), and the index of the fused segment each of them
    went into (K,), −1 for those of zero length (left out)."""
    params = params or FuseParams()
    segments = np.asarray(segments_world, dtype=float).reshape(-1, 4)
    into = np.full(segments.shape[0], -1, dtype=np.int64)
    kept = np.flatnonzero(segment_lengths(segments) > 0)
    into[kept] = np.arange(kept.size)
    segments = segments[kept]
    with progress("fusing segments", segments.shape[0], "segment") as shown:
        while segments.shape[0] > 1:
            groups = _mergeable_groups(segments, params, shown)
            shown = SILENT
            if groups is None:
                break
            fused, went = _fuse_groups(segments, groups, params)
            if fused.shape[0] == segments.shape[0]:
                break  # cannot happen (see above); guards against an endless loop
            segments = fused
            into[kept] = went[into[kept]]
    return segments, into


def build_global_map(
    local_maps: list[np.ndarray],
    poses: list[Pose2],
    params: FuseParams | None = None,
    progress: ProgressFactory = silent,
) -> np.ndarray:
    """Global map (M, 4), world frame, from local maps (robot frame) observed at ``poses``;
    ``progress`` as in ``fuse_segments``."""
    return observed_map(local_maps, poses, params, progress)[0]


def observed_map(
    local_maps: list[np.ndarray],
    poses: list[Pose2],
    params: FuseParams | None = None,
    progress: ProgressFactory = silent,
    viewpoints: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``build_global_map``, and from how many viewpoints each of its segments was seen (M,).

    A segment's count is the number of distinct ``viewpoints`` labels (S,), one per local
    map, among the local maps that have a segment fused into it; by default every local
    map is a viewpoint of its own. Scans taken from one surveyed pose share a label, so a
    robot standing still does not see a passer-by standing with it many times over.
    """
    if len(local_maps) != len(poses):
        raise ValueError(f"{len(local_maps)} local maps but {len(poses)} poses")
    labels = np.arange(len(poses)) if viewpoints is None else np.asarray(viewpoints)
    if labels.shape != (len(poses),):
        raise ValueError(f"{labels.size} viewpoints for {len(poses)} local maps")
    if not local_maps:
        return np.zeros((0, 4)), np.zeros(0, dtype=np.int64)
    world = [transform_segments(lm, pose) for lm, pose in zip(local_maps, poses, strict=True)]
    segments, into = fuse_traced(np.concatenate(world), params, progress)
    seen_from = np.repeat(labels, [w.shape[0] for w in world])
    fused = into >= 0
    return segments, distinct_viewpoints(into[fused], seen_from[fused], segments.shape[0])


def distinct_viewpoints(segment: np.ndarray, viewpoint: np.ndarray, n: int) -> np.ndarray:
    """How many distinct viewpoints each of ``n`` segments has (n,), from sightings: pairs
    of a segment index (K,) and a viewpoint label (K,), repeats allowed."""
    pairs = np.unique(np.column_stack([segment, viewpoint]).reshape(-1, 2), axis=0)
    return np.bincount(pairs[:, 0], minlength=n)


def polish_poses(
    local_maps: list[np.ndarray],
    points: list[np.ndarray],
    poses: list[Pose2],
    params: FuseParams,
    progress: Progress = SILENT,
) -> list[Pose2]:
    """The scans' poses (world frame) after ``params.polish_rounds`` rounds of polishing.

    In each round the scans are split by order into two halves, alternately; each half's
    scans are fitted (``refine_pose``, their valid points (P, 2) in the robot frame) to the
    map the other half's local maps make at their current poses. A scan is never fitted to
    its own segments, which would hold it where it is. A fit that moves the pose by more
    than ``polish_max_shift_m`` or puts less than ``polish_min_inlier_ratio`` of the points on
    the map is not taken. ``progress`` counts the rounds.
    """
    from segloc_cli.method.refine import refine_pose
    from segloc_cli.method.spatial import NEAR_CELL_M, SegmentGrid

    n = len(poses)
    if not (len(local_maps) == len(points) == n):
        raise ValueError(f"{len(local_maps)} local maps, {len(points)} scans, {n} poses")
    halves = (np.arange(0, n, 2), np.arange(1, n, 2))
    current = list(poses)
    for _ in range(params.polish_rounds):
        polished = list(current)
        for fitted, other in (halves, halves[::-1]):
            segments = build_global_map([local_maps[i] for i in other],
                                        [current[i] for i in other], params)  # fmt: skip
            if segments.shape[0] == 0:
                continue
            index = SegmentGrid(segments, cell_m=NEAR_CELL_M)
            for i in fitted:
                fit = refine_pose(points[i], segments, current[i], index=index)
                shift = np.hypot(fit.pose.x - current[i].x, fit.pose.y - current[i].y)
                if fit.inlier_ratio >= params.polish_min_inlier_ratio and (
                    shift <= params.polish_max_shift_m
                ):
                    polished[i] = fit.pose
        current = polished
        progress.advance()
    return current
