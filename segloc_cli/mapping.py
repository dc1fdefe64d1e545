"""Global map from local maps at known poses.

Local maps are moved into the world frame and fused: segments that are nearly
collinear and overlap or nearly touch along their common line become one
segment, fitted to all of them with each weighted by its length, spanning the
union of their extents. Fusion repeats until nothing more merges, so chains of
overlapping pieces collapse into one segment per wall.
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


def mergeable_pairs(segments: np.ndarray, params: FuseParams) -> np.ndarray:
    """Boolean (M, M) matrix of the pairs that describe the same wall (diagonal False)."""
    s = np.asarray(segments, dtype=float)
    p, q = s[:, :2], s[:, 2:]
    length = segment_lengths(s)
    u = (q - p) / length[:, None]
    normal = np.column_stack([-u[:, 1], u[:, 0]])

    cos_angle = np.abs(u @ u.T)
    parallel = cos_angle >= np.cos(np.deg2rad(params.angle_deg))

    # Distance of j's endpoints from i's line, both ways.
    off_p = np.abs(normal @ p.T - np.sum(normal * p, axis=1)[:, None])
    off_q = np.abs(normal @ q.T - np.sum(normal * p, axis=1)[:, None])
    offset = np.maximum(off_p, off_q)
    close = np.maximum(offset, offset.T) <= params.offset_m

    # Extents along i's direction: i spans [0, len_i]; j spans its endpoints' projections.
    tp = u @ p.T - np.sum(u * p, axis=1)[:, None]
    tq = u @ q.T - np.sum(u * p, axis=1)[:, None]
    j_lo, j_hi = np.minimum(tp, tq), np.maximum(tp, tq)
    gap = np.maximum(j_lo - length[:, None], -j_hi)
    touching = gap <= params.gap_m

    pairs = parallel & close & touching & touching.T
    np.fill_diagonal(pairs, False)
    return pairs


def _components(pairs: np.ndarray) -> np.ndarray:
    """Connected-component label (M,) of each segment in the graph ``pairs``."""
    labels = np.arange(pairs.shape[0])
    while True:
        neighbour_min = np.where(pairs, labels[None, :], labels[:, None]).min(axis=1)
        updated = np.minimum(labels, neighbour_min)
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
        pairs = mergeable_pairs(segments, params)
        if not pairs.any():
            break
        labels = _components(pairs)
        groups = np.unique(labels)
        segments = np.array([fit_segments(segments[labels == g]) for g in groups])
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
