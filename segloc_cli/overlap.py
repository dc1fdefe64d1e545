"""Stage 2, map overlap: position (and a refined heading) by coarse-to-fine search.

Overlap of a local map placed at a candidate scanner pose with the global map,
for every pair (global segment G, local segment L):

- G's viewing sector is the wedge from the scanner bounded by the rays through
  G's endpoints; only the part of L inside it can pair with G.
- Of that part, Cls is what lies within ±δ of G's supporting line
  (δ = √2·η/2, the largest position error of the current grid of spacing η).
- Cgs is the part of G between the scanner rays through Cls's endpoints.
- The pair adds |Cls| + |Cgs|.

Everything is computed in the candidate's robot frame, where the scanner is at
the origin. L is parametrised as A + t·(B − A), t ∈ [0, 1]; the two sector
rays and the two band edges are each a linear inequality in t, so Cls is an
interval of t found without branching, for all candidates × G × L at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from segloc_cli.geometry import Pose2, circular_mean, transform_segments, wrap_angle


def band_halfwidth(grid_m: float) -> float:
    """δ for grid spacing η: the largest distance from a point to its nearest grid node."""
    return np.sqrt(2.0) * grid_m / 2.0


def _cross(ax, ay, bx, by):
    return ax * by - ay * bx


def _half_line(lo, hi, a, b):
    """Tighten the interval [lo, hi] of t by the constraint a + b·t >= 0."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -a / b
    lo = np.where(b > 0, np.maximum(lo, t), lo)
    hi = np.where(b < 0, np.minimum(hi, t), hi)
    # b == 0: the constraint holds for every t or for none.
    hi = np.where((b == 0) & (a < 0), -np.inf, hi)
    return lo, hi


def _pair_overlaps(g, poses, loc, pair_g, pair_l, band_m):
    """Overlap (C,) summed over the given (global, local) pairs, for every pose (C, 3)."""
    c = np.cos(poses[:, 2])[:, None]
    s = np.sin(poses[:, 2])[:, None]
    gp = g[pair_g]
    dx1 = gp[None, :, 0] - poses[:, 0:1]
    dy1 = gp[None, :, 1] - poses[:, 1:2]
    dx2 = gp[None, :, 2] - poses[:, 0:1]
    dy2 = gp[None, :, 3] - poses[:, 1:2]
    # G's endpoints in each candidate's robot frame, scanner at the origin: (C, P).
    g1x, g1y = c * dx1 + s * dy1, c * dy1 - s * dx1
    g2x, g2y = c * dx2 + s * dy2, c * dy2 - s * dx2

    # Order G's endpoints counter-clockwise as seen from the scanner, so that its
    # sector is "left of ray 1 and right of ray 2". A G on a line through the
    # scanner subtends no sector and cannot pair.
    turn = _cross(g1x, g1y, g2x, g2y)
    swap = turn < 0
    ax_, bx_ = np.where(swap, g2x, g1x), np.where(swap, g1x, g2x)
    ay_, by_ = np.where(swap, g2y, g1y), np.where(swap, g1y, g2y)

    # G's supporting line: unit normal n, offset n·P = off.
    ex, ey = bx_ - ax_, by_ - ay_
    g_len = np.sqrt(ex * ex + ey * ey)
    nx, ny = -ey / g_len, ex / g_len
    off = nx * ax_ + ny * ay_

    lp = loc[pair_l]
    lax, lay = lp[:, 0], lp[:, 1]
    ldx, ldy = lp[:, 2] - lax, lp[:, 3] - lay

    # L is A + t·(B − A); each sector ray is a half-line constraint on t ...
    lo = np.zeros_like(turn)
    hi = np.ones_like(turn)
    lo, hi = _half_line(lo, hi, _cross(ax_, ay_, lax, lay), _cross(ax_, ay_, ldx, ldy))
    lo, hi = _half_line(lo, hi, _cross(lax, lay, bx_, by_), _cross(ldx, ldy, bx_, by_))
    # ... and the band |n·(A + t·d) − off| <= δ is an interval of t. Dividing by a
    # zero slope gives ±inf, which is the right interval (all or nothing).
    s0 = nx * lax + ny * lay - off
    sd = nx * ldx + ny * ldy
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-band_m - s0) / sd
        t2 = (band_m - s0) / sd
    lo = np.maximum(lo, np.minimum(t1, t2))
    hi = np.minimum(hi, np.maximum(t1, t2))
    paired = (hi > lo) & (np.abs(turn) > 1e-12)

    cls_len = (hi - lo) * np.sqrt(ldx * ldx + ldy * ldy)
    # Cgs: where the scanner rays through Cls's endpoints cross G's line.
    q0x, q0y = lax + lo * ldx, lay + lo * ldy
    q1x, q1y = lax + hi * ldx, lay + hi * ldy
    with np.errstate(divide="ignore", invalid="ignore"):
        k0 = off / (nx * q0x + ny * q0y)
        k1 = off / (nx * q1x + ny * q1y)
        cx, cy = k1 * q1x - k0 * q0x, k1 * q1y - k0 * q0y
        cgs_len = np.sqrt(cx * cx + cy * cy)
    total = np.where(paired & np.isfinite(cgs_len), cls_len + cgs_len, 0.0)
    return total.sum(axis=1)


def overlap_at_poses(
    segments_world: np.ndarray,
    segments_robot: np.ndarray,
    poses: np.ndarray,
    band_m: float,
    pairs: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Overlap (C,) in metres of the local map (N, 4), robot frame, placed at each pose (C, 3).

    ``segments_world`` (M, 4) is the global map and ``band_m`` the band
    half-width δ. ``pairs`` (global indices, local indices) limits the sum to
    those pairs; by default every pair is considered.
    """
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    g = np.asarray(segments_world, dtype=float).reshape(-1, 4)
    loc = np.asarray(segments_robot, dtype=float).reshape(-1, 4)
    if pairs is None:
        pair_g, pair_l = (
            a.ravel() for a in np.meshgrid(np.arange(len(g)), np.arange(len(loc)), indexing="ij")
        )
    else:
        pair_g, pair_l = pairs
    if pair_g.size == 0:
        return np.zeros(poses.shape[0])
    return _pair_overlaps(g, poses, loc, pair_g, pair_l, band_m)


def candidate_pairs(
    segments_world: np.ndarray,
    segments_robot: np.ndarray,
    centre: Pose2,
    spread_m: float,
    spread_rad: float,
    band_m: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The (global, local) index pairs that can overlap for some pose near ``centre``.

    Candidates lie within ``spread_m`` of the centre position and
    ``spread_rad`` of its heading. A pair is dropped only when it cannot
    contribute for any of them: the local segment stays outside the band of
    the global segment's line, or outside its viewing sector. Pairs dropped
    here would add exactly zero, so the overlap is unchanged.
    """
    g = np.asarray(segments_world, dtype=float)
    loc = np.asarray(segments_robot, dtype=float)
    # Band test in the world frame: how far each local endpoint can move.
    local_world = transform_segments(loc, centre)
    reach = spread_m + np.hypot(loc[:, 0::2], loc[:, 1::2]) * spread_rad  # (N, 2)
    gl = np.hypot(g[:, 2] - g[:, 0], g[:, 3] - g[:, 1])
    nx = -(g[:, 3] - g[:, 1]) / gl
    ny = (g[:, 2] - g[:, 0]) / gl
    off = nx * g[:, 0] + ny * g[:, 1]
    d1 = (
        nx[:, None] * local_world[None, :, 0] + ny[:, None] * local_world[None, :, 1] - off[:, None]
    )
    d2 = (
        nx[:, None] * local_world[None, :, 2] + ny[:, None] * local_world[None, :, 3] - off[:, None]
    )
    limit1 = band_m + reach[None, :, 0]
    limit2 = band_m + reach[None, :, 1]
    outside = ((d1 > limit1) & (d2 > limit2)) | ((d1 < -limit1) & (d2 < -limit2))

    # Sector test in the centre's robot frame: G's angular interval widens by
    # how much a shift of spread_m and a turn of spread_rad can move its ends.
    g_robot = transform_segments(g, centre.inverse())
    r_ends = np.minimum(
        np.hypot(g_robot[:, 0], g_robot[:, 1]), np.hypot(g_robot[:, 2], g_robot[:, 3])
    )
    widen = np.arcsin(np.minimum(spread_m / np.maximum(r_ends, 1e-12), 1.0))
    # A scanner that can reach the segment itself may see it from the other side.
    widen = np.where(_distance_to_origin(g_robot) > spread_m, widen, np.pi)
    g_mid, g_half = _angular_interval(g_robot)
    l_mid, l_half = _angular_interval(loc)
    apart = np.abs(wrap_angle(g_mid[:, None] - l_mid[None, :]))
    unseen = apart > (g_half + widen + spread_rad)[:, None] + l_half[None, :] + 1e-9

    return np.nonzero(~(outside | unseen))


def _distance_to_origin(segments: np.ndarray) -> np.ndarray:
    """Distance (M,) from the origin to the closest point of each segment."""
    p, d = segments[:, :2], segments[:, 2:] - segments[:, :2]
    t = np.clip(-np.sum(p * d, axis=1) / np.maximum(np.sum(d * d, axis=1), 1e-300), 0.0, 1.0)
    return np.hypot(p[:, 0] + t * d[:, 0], p[:, 1] + t * d[:, 1])


def _angular_interval(segments: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centre and half-width (radians) of the angle each segment subtends at the origin."""
    a = np.arctan2(segments[:, 1], segments[:, 0])
    b = np.arctan2(segments[:, 3], segments[:, 2])
    half = 0.5 * np.abs(wrap_angle(b - a))
    mid = wrap_angle(a + 0.5 * wrap_angle(b - a))
    return mid, half


def candidate_poses(centre: Pose2, grid_m: float, dtheta_rad: float) -> np.ndarray:
    """The 27 candidates (27, 3) of one iteration: a 3×3 grid of spacing ``grid_m`` × 3 headings."""
    offsets = np.array([-1.0, 0.0, 1.0])
    ox, oy, ot = np.meshgrid(
        offsets * grid_m, offsets * grid_m, offsets * dtheta_rad, indexing="ij"
    )
    return np.column_stack(
        [centre.x + ox.ravel(), centre.y + oy.ravel(), wrap_angle(centre.theta + ot.ravel())]
    )


@dataclass(frozen=True)
class OverlapResult:
    """Outcome of the coarse-to-fine search.

    ``pose`` is the final estimate (world frame), ``overlap_m`` the overlap at
    it with the last iteration's band, ``track`` (K + 1, 3) the estimate
    before the first and after every iteration, ``best_overlaps_m`` (K,)
    the best candidate overlap of every iteration.
    """

    pose: Pose2
    overlap_m: float
    track: np.ndarray
    best_overlaps_m: np.ndarray


def coarse_to_fine(
    segments_world: np.ndarray,
    segments_robot: np.ndarray,
    start: Pose2,
    grid_m: float = 1.5,
    dtheta_deg: float = 4.0,
    iterations: int = 6,
    ratio: float = 0.9,
    recentres: int = 0,
) -> OverlapResult:
    """Refine ``start`` by the paper's coarse-to-fine overlap search.

    Each iteration scores 27 candidates around the current estimate, moves to
    the overlap-weighted mean of those scoring at least ``ratio`` × the best
    (headings averaged on the circle) and halves the grid and the heading
    step; ``iterations`` halvings in all (the paper's K).

    ``recentres`` > 0 allows up to that many extra iterations, spent where the
    estimate moved by more than half a grid step (or half a heading step): the
    search repeats at that scale instead of halving. With 0 the schedule is
    exactly the paper's.
    """
    estimate = start
    eta = float(grid_m)
    dtheta = float(np.deg2rad(dtheta_deg))
    track = [estimate.as_array()]
    best_overlaps = []
    segments_world = np.asarray(segments_world, dtype=float)
    repeats_left = recentres
    halvings = 0
    while halvings < iterations:
        band = band_halfwidth(eta)
        candidates = candidate_poses(estimate, eta, dtheta)
        pairs = candidate_pairs(
            segments_world, segments_robot, estimate, np.sqrt(2.0) * eta, dtheta, band
        )
        overlaps = overlap_at_poses(segments_world, segments_robot, candidates, band, pairs)
        best = float(overlaps.max())
        best_overlaps.append(best)
        if best > 0:
            keep = overlaps >= ratio * best
            w = overlaps[keep]
            x, y = (w @ candidates[keep, :2]) / w.sum()
            estimate = Pose2(float(x), float(y), circular_mean(candidates[keep, 2], w))
        track.append(estimate.as_array())
        moved = track[-1] - track[-2]
        still_moving = np.hypot(moved[0], moved[1]) > eta / 2 or abs(wrap_angle(moved[2])) > dtheta / 2
        if repeats_left > 0 and best > 0 and still_moving:
            # The estimate left the central cell: search again at this scale
            # before refining, or the halved grid may no longer reach the pose.
            repeats_left -= 1
            continue
        eta /= 2.0
        dtheta /= 2.0
        halvings += 1
    final_band = band_halfwidth(2.0 * eta)
    final = float(
        overlap_at_poses(segments_world, segments_robot, estimate.as_array(), final_band)[0]
    )
    return OverlapResult(estimate, final, np.array(track), np.array(best_overlaps))
