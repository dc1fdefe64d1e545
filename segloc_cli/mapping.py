"""Global map from local maps at known poses.

Local maps are moved into the world frame and fused: segments that are nearly
collinear and overlap or nearly touch along their common line become one
segment, fitted to all of them with each weighted by its length, spanning the
union of their extents. Fusion repeats until nothing more merges, so chains of
overlapping pieces collapse into one segment per wall.

A chain of pairwise matches can drift: A matches B, B matches C, yet A and C
lie on different lines (two parallel walls a few centimetres apart, a wall and
the furniture along it). A group is fused into one segment only if every
member lies on the fitted line within the same tolerances; otherwise it is
regrown from its longest member, one line at a time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from segloc_cli.geometry import Pose2, segment_lengths, transform_segments


@dataclass(frozen=True)
class FuseParams:
    """When two world-frame segments are one wall (metres, degrees)."""

    angle_deg: float = 3.0
    """Largest difference of undirected orientation."""
    offset_m: float = 0.06
    """Largest distance of either segment's endpoints from the other's line."""
    gap_m: float = 0.15
    """Largest gap between their extents along the common line (negative = overlap)."""


def fit_segments(segments: np.ndarray) -> np.ndarray:
    """One segment (4,) fitted to segments (K, 4): length-weighted total least squares.

    Each segment counts as a uniform line of mass, so the fit is the principal
    axis of all of them; the result spans the projections of every endpoint.
    """
    segments = np.asarray(segments, dtype=float).reshape(-1, 4)
    p, q = segments[:, :2], segments[:, 2:]
    length = segment_lengths(segments)
    mid = 0.5 * (p + q)
    total = length.sum()
    centroid = (length @ mid) / total
    d = mid - centroid
    u = (q - p) / np.where(length > 0, length, 1.0)[:, None]
    # Second moment of a uniform segment about its midpoint is l³/12 · u uᵀ.
    scatter = (d * length[:, None]).T @ d + ((u * (length**3 / 12.0)[:, None]).T @ u)
    evals, evecs = np.linalg.eigh(scatter)
    direction = evecs[:, np.argmax(evals)]
    t = np.concatenate([(p - centroid) @ direction, (q - centroid) @ direction])
    return np.concatenate([centroid + t.min() * direction, centroid + t.max() * direction])


GRID_CELL_M = 2.0
"""Cell size of the spatial grid that proposes candidate pairs."""


def _nearby_pairs(segments: np.ndarray, margin_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i < j) whose bounding boxes, grown by ``margin_m``, share a grid cell.

    Every pair of segments closer than ``margin_m`` is among them; far-apart
    segments are never compared, so fusing a long log stays near linear.
    """
    lo = np.minimum(segments[:, :2], segments[:, 2:]) - margin_m
    hi = np.maximum(segments[:, :2], segments[:, 2:]) + margin_m
    c_lo = np.floor(lo / GRID_CELL_M).astype(np.int64)
    c_hi = np.floor(hi / GRID_CELL_M).astype(np.int64)
    nx = c_hi[:, 0] - c_lo[:, 0] + 1
    ny = c_hi[:, 1] - c_lo[:, 1] + 1
    # One entry per (segment, covered cell).
    owner = np.repeat(np.arange(len(segments)), nx * ny)
    k = np.arange(owner.size) - np.repeat(np.cumsum(nx * ny) - nx * ny, nx * ny)
    cx = c_lo[owner, 0] + k % nx[owner]
    cy = c_lo[owner, 1] + k // nx[owner]
    key = (cx - cx.min()) * (cy.max() - cy.min() + 1) + (cy - cy.min())
    order = np.lexsort((owner, key))
    key, owner = key[order], owner[order]
    # Pair each entry with the entries after it in the same cell.
    group_end = np.searchsorted(key, key, side="right")
    count = group_end - np.arange(key.size) - 1
    first = np.repeat(np.arange(key.size), count)
    step = np.arange(first.size) - np.repeat(np.cumsum(count) - count, count)
    i, j = owner[first], owner[first + 1 + step]
    pair_key = np.unique(np.minimum(i, j) * len(segments) + np.maximum(i, j))
    return pair_key // len(segments), pair_key % len(segments)


def mergeable_pairs(segments: np.ndarray, params: FuseParams) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i < j) of segments (M, 4) that describe the same wall."""
    s = np.asarray(segments, dtype=float).reshape(-1, 4)
    i, j = _nearby_pairs(s, max(params.offset_m, params.gap_m))
    p, q = s[:, :2], s[:, 2:]
    length = segment_lengths(s)
    u = (q - p) / length[:, None]
    normal = np.column_stack([-u[:, 1], u[:, 0]])

    parallel = np.abs(np.sum(u[i] * u[j], axis=1)) >= np.cos(np.deg2rad(params.angle_deg))

    def offset(a, b):
        """Largest distance of b's endpoints from a's line."""
        c = np.sum(normal[a] * p[a], axis=1)
        return np.maximum(
            np.abs(np.sum(normal[a] * p[b], axis=1) - c),
            np.abs(np.sum(normal[a] * q[b], axis=1) - c),
        )

    close = np.maximum(offset(i, j), offset(j, i)) <= params.offset_m
    touching = (_gaps(p[i], u[i], length[i], p[j], q[j]) <= params.gap_m) & (
        _gaps(p[j], u[j], length[j], p[i], q[i]) <= params.gap_m
    )
    keep = parallel & close & touching
    return i[keep], j[keep]


def _fits_line(line: np.ndarray, segments: np.ndarray, params: FuseParams) -> np.ndarray:
    """Which segments (K, 4) lie on ``line`` (4,): orientation and both ends within tolerance."""
    p, q = line[:2], line[2:]
    length = float(np.hypot(*(q - p)))
    u = (q - p) / length
    normal = np.array([-u[1], u[0]])
    d = segments[:, 2:] - segments[:, :2]
    cos = np.abs(d @ u) / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-300)
    offset = np.maximum(
        np.abs((segments[:, :2] - p) @ normal), np.abs((segments[:, 2:] - p) @ normal)
    )
    return (cos >= np.cos(np.deg2rad(params.angle_deg))) & (offset <= params.offset_m)


def _fuse_group(segments: np.ndarray, params: FuseParams) -> list[np.ndarray]:
    """Segments (K, 4) linked by pairwise matches → one fitted segment per line they hold."""
    line = fit_segments(segments)
    if _fits_line(line, segments, params).all():
        return [line]
    lines = []
    remaining = segments[np.argsort(-segment_lengths(segments))]
    while remaining.shape[0]:
        members = remaining[:1]
        remaining = remaining[1:]
        line = members[0]
        while remaining.shape[0]:
            length = float(np.hypot(*(line[2:] - line[:2])))
            gaps = _gaps(line[:2], (line[2:] - line[:2]) / length, length, *np.hsplit(remaining, 2))
            join = _fits_line(line, remaining, params) & (gaps <= params.gap_m)
            if not join.any():
                break
            members = np.concatenate([members, remaining[join]])
            remaining = remaining[~join]
            line = fit_segments(members)
        lines.append(line)
    return lines


def _gaps(start, direction, length, p, q) -> np.ndarray:
    """Gap between each extent p–q and a line's (start, unit direction, length) along the line.

    Negative where they overlap. Arguments broadcast: one line against many
    segments, or pairs row by row.
    """
    tp = np.sum((p - start) * direction, axis=-1)
    tq = np.sum((q - start) * direction, axis=-1)
    return np.maximum(np.minimum(tp, tq) - length, -np.maximum(tp, tq))


def _components(n: int, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Connected-component label (n,) of each node of the graph with edges (i, j)."""
    labels = np.arange(n)
    while True:
        updated = labels.copy()
        np.minimum.at(updated, i, labels[j])
        np.minimum.at(updated, j, labels[i])
        updated = updated[updated]
        if np.array_equal(updated, labels):
            return labels
        labels = updated


def fuse_segments(segments_world: np.ndarray, params: FuseParams | None = None) -> np.ndarray:
    """Fuse duplicate observations of the same walls; returns (M', 4), M' <= M."""
    params = params or FuseParams()
    segments = np.asarray(segments_world, dtype=float).reshape(-1, 4)
    segments = segments[segment_lengths(segments) > 0]
    while segments.shape[0] > 1:
        i, j = mergeable_pairs(segments, params)
        if i.size == 0:
            break
        labels = _components(segments.shape[0], i, j)
        fused = np.array(
            [line for g in np.unique(labels) for line in _fuse_group(segments[labels == g], params)]
        )
        if fused.shape[0] == segments.shape[0]:
            break  # the only matches left link segments that lie on different lines
        segments = fused
    return segments


def build_global_map(
    local_maps: list[np.ndarray], poses: list[Pose2], params: FuseParams | None = None
) -> np.ndarray:
    """Global map (M, 4), world frame, from local maps (robot frame) observed at ``poses``."""
    if len(local_maps) != len(poses):
        raise ValueError(f"{len(local_maps)} local maps but {len(poses)} poses")
    if not local_maps:
        return np.zeros((0, 4))
    world = [transform_segments(lm, pose) for lm, pose in zip(local_maps, poses, strict=True)]
    return fuse_segments(np.concatenate(world), params)
