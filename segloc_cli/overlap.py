"""Stage 2, map overlap: position (and a refined heading) by coarse-to-fine search.

Overlap of a local map placed at a candidate scanner pose with the global map,
for every pair (global segment G, local segment L):

- G's viewing sector is the wedge from the scanner bounded by the rays through
  G's endpoints; only the part of L inside it can pair with G.
- Of that part, Cls is what lies within ±δ of G's supporting line
  (δ = √2·η/2, the largest position error of the current grid of spacing η).
- Cgs is the part of G between the scanner rays through Cls's endpoints.
- The pair adds |Cls| + |Cgs|.

One guard is added to the paper's definition: the scanner rays through Cls's
endpoints must meet G's line at an incidence of at least ``min_incidence``.
A segment seen almost edge-on subtends a hairline sector, yet the rays
through any sliver of local segment inside it take in the whole of G, so a
candidate placed on the line of a distant wall would collect that wall's full
length. A scan cannot produce segments at such grazing incidence (the
breakpoint detector splits them), so such pairs are no evidence.

Everything is computed in the candidate's robot frame, where the scanner is at
the origin. L is parametrised as A + t·(B − A), t ∈ [0, 1]; the two sector
rays and the two band edges are each a linear inequality in t, so Cls is an
interval of t. A cheap, exact pre-filter first drops the pairs that cannot
overlap for any candidate of an iteration, which is what keeps large maps fast.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from segloc_cli.geometry import Pose2
from segloc_cli.kernels import (
    angular_interval,
    into_frame,
    out_of_frame,
    point_into_frame,
    point_segment_distance,
    segment_distance,
    wrap,
)
from segloc_cli.spatial import SegmentGrid


@njit(cache=True)
def band_halfwidth(grid_m: float) -> float:
    """δ for grid spacing η: the largest distance from a point to its nearest grid node."""
    return np.sqrt(2.0) * grid_m / 2.0


MIN_INCIDENCE_DEG = 5.0
"""Shallowest angle between a scanner ray and a global segment at which they can pair."""

# The two hot loops below run once per candidate × pair, tens of thousands of
# times per pose, on a handful of scalars each; compiled, they cost less than
# the array bookkeeping a vectorised version needs at these sizes.


@njit(cache=True)
def _pair_overlap(gax, gay, gbx, gby, lax, lay, lbx, lby, band_m, sin2_min) -> float:
    """|Cls| + |Cgs| of one pair, both segments in the robot frame (scanner at the origin)."""
    turn = gax * gby - gay * gbx
    if abs(turn) <= 1e-12:
        return 0.0  # G lies on a line through the scanner: no sector
    if turn < 0.0:  # order G's ends counter-clockwise as seen from the scanner
        gax, gay, gbx, gby = gbx, gby, gax, gay
    ex, ey = gbx - gax, gby - gay
    g_len = np.sqrt(ex * ex + ey * ey)
    nx, ny = -ey / g_len, ex / g_len
    off = nx * gax + ny * gay

    # L is A + t·(B − A), t in [lo, hi]; each constraint a + b·t >= 0 trims it.
    dx, dy = lbx - lax, lby - lay
    lo, hi = 0.0, 1.0
    for k in range(2):
        if k == 0:  # left of the ray through G's first end
            a, b = gax * lay - gay * lax, gax * dy - gay * dx
        else:  # right of the ray through G's second end
            a, b = lax * gby - lay * gbx, dx * gby - dy * gbx
        if b > 0.0:
            lo = max(lo, -a / b)
        elif b < 0.0:
            hi = min(hi, -a / b)
        elif a < 0.0:
            return 0.0
    # The band |n·(A + t·d) − off| <= δ around G's line.
    s0 = nx * lax + ny * lay - off
    sd = nx * dx + ny * dy
    if sd == 0.0:
        if abs(s0) > band_m:
            return 0.0
    else:
        t1, t2 = (-band_m - s0) / sd, (band_m - s0) / sd
        lo = max(lo, min(t1, t2))
        hi = min(hi, max(t1, t2))
    if hi <= lo:
        return 0.0

    # Cls's ends, and where the scanner rays through them meet G's line (Cgs).
    q0x, q0y = lax + lo * dx, lay + lo * dy
    q1x, q1y = lax + hi * dx, lay + hi * dy
    n_q0 = nx * q0x + ny * q0y
    n_q1 = nx * q1x + ny * q1y
    # |n·q| / |q| is the sine of the angle at which the ray through q meets G's line.
    if n_q0 * n_q0 < sin2_min * (q0x * q0x + q0y * q0y) or n_q0 == 0.0:
        return 0.0
    if n_q1 * n_q1 < sin2_min * (q1x * q1x + q1y * q1y) or n_q1 == 0.0:
        return 0.0
    k0, k1 = off / n_q0, off / n_q1
    cx, cy = k1 * q1x - k0 * q0x, k1 * q1y - k0 * q0y
    return (hi - lo) * np.sqrt(dx * dx + dy * dy) + np.sqrt(cx * cx + cy * cy)


@njit(cache=True)
def _overlaps_kernel(g, loc, poses, pair_g, pair_l, band_m, sin2_min):
    """Overlap (C,) of local segments ``loc`` (robot frame) placed at each pose (C, 3) with
    global segments ``g`` (world frame), summed over the listed (global, local) pairs."""
    out = np.zeros(poses.shape[0])
    for c in range(poses.shape[0]):
        px, py = poses[c, 0], poses[c, 1]
        cs, sn = np.cos(poses[c, 2]), np.sin(poses[c, 2])
        total = 0.0
        for k in range(pair_g.shape[0]):
            m, n = pair_g[k], pair_l[k]
            gax, gay = point_into_frame(g[m, 0], g[m, 1], px, py, cs, sn)
            gbx, gby = point_into_frame(g[m, 2], g[m, 3], px, py, cs, sn)
            total += _pair_overlap(
                gax, gay, gbx, gby, loc[n, 0], loc[n, 1], loc[n, 2], loc[n, 3], band_m, sin2_min
            )
        out[c] = total
    return out


def overlap_at_poses(
    segments_world: np.ndarray,
    segments_robot: np.ndarray,
    poses: np.ndarray,
    band_m: float,
    pairs: tuple[np.ndarray, np.ndarray] | None = None,
    min_incidence_deg: float = MIN_INCIDENCE_DEG,
) -> np.ndarray:
    """Overlap (C,) in metres of the local map (N, 4), robot frame, placed at each pose (C, 3).

    ``segments_world`` (M, 4) is the global map and ``band_m`` the band
    half-width δ. ``pairs`` (global indices, local indices) limits the sum to
    those pairs; by default every pair is considered.
    """
    poses = np.ascontiguousarray(np.atleast_2d(np.asarray(poses, dtype=float)))
    g = np.ascontiguousarray(np.asarray(segments_world, dtype=float).reshape(-1, 4))
    loc = np.ascontiguousarray(np.asarray(segments_robot, dtype=float).reshape(-1, 4))
    if pairs is None:
        pair_g = np.repeat(np.arange(len(g)), len(loc))
        pair_l = np.tile(np.arange(len(loc)), len(g))
    else:
        pair_g, pair_l = (np.asarray(a, dtype=np.int64) for a in pairs)
    sin_min = float(np.sin(np.deg2rad(min_incidence_deg)))
    return _overlaps_kernel(g, loc, poses, pair_g, pair_l, float(band_m), sin_min * sin_min)


@njit(cache=True)
def _pairs_kernel(g, g_robot, loc, local_world, spread_m, spread_rad, band_m, sin_min):
    n_local = loc.shape[0]
    if n_local == 0 or g.shape[0] == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    reach = np.empty(n_local)  # how far a local segment's points can move over the candidates
    l_mid = np.empty(n_local)
    l_half = np.empty(n_local)
    radius = 0.0
    for n in range(n_local):
        r1 = np.sqrt(loc[n, 0] ** 2 + loc[n, 1] ** 2)
        r2 = np.sqrt(loc[n, 2] ** 2 + loc[n, 3] ** 2)
        reach[n] = spread_m + max(r1, r2) * spread_rad
        radius = max(radius, max(r1, r2))
        l_mid[n], l_half[n] = angular_interval(loc[n, 0], loc[n, 1], loc[n, 2], loc[n, 3])
    # A pairing piece lies within band / sin(min incidence) of G.
    near = band_m / sin_min
    reach_max = reach.max()

    out_g = np.empty(g.shape[0] * n_local, dtype=np.int64)
    out_l = np.empty(g.shape[0] * n_local, dtype=np.int64)
    count = 0
    for m in range(g.shape[0]):
        gr = g_robot[m]
        dist0 = point_segment_distance(0.0, 0.0, gr[0], gr[1], gr[2], gr[3])
        # Range: every local point is within `radius` of the scanner.
        if dist0 > radius + near + reach_max + 1e-9:
            continue
        length = np.sqrt((g[m, 2] - g[m, 0]) ** 2 + (g[m, 3] - g[m, 1]) ** 2)
        nx, ny = -(g[m, 3] - g[m, 1]) / length, (g[m, 2] - g[m, 0]) / length
        off = nx * g[m, 0] + ny * g[m, 1]
        # Sector: G's angular interval widens by how far a shift of spread_m
        # and a turn of spread_rad can move its ends; a scanner that can reach
        # G itself may see it from the other side.
        r_ends = min(np.sqrt(gr[0] ** 2 + gr[1] ** 2), np.sqrt(gr[2] ** 2 + gr[3] ** 2))
        if dist0 > spread_m:
            widen = np.arcsin(min(spread_m / max(r_ends, 1e-12), 1.0))
        else:
            widen = np.pi
        g_mid, g_half = angular_interval(gr[0], gr[1], gr[2], gr[3])
        for n in range(n_local):
            lw = local_world[n]
            limit = band_m + reach[n]
            d1 = nx * lw[0] + ny * lw[1] - off
            d2 = nx * lw[2] + ny * lw[3] - off
            if (d1 > limit and d2 > limit) or (d1 < -limit and d2 < -limit):
                continue  # stays outside the band
            if abs(wrap(g_mid - l_mid[n])) > g_half + widen + spread_rad + l_half[n] + 1e-9:
                continue  # stays outside the sector
            if segment_distance(g[m], lw) > near + reach[n] + 1e-9:
                continue  # too far from G for a piece seen at a steep enough incidence
            out_g[count] = m
            out_l[count] = n
            count += 1
    return out_g[:count], out_l[:count]


def candidate_pairs(
    segments_world: np.ndarray,
    segments_robot: np.ndarray,
    centre: Pose2,
    spread_m: float,
    spread_rad: float,
    band_m: float,
    min_incidence_deg: float = MIN_INCIDENCE_DEG,
) -> tuple[np.ndarray, np.ndarray]:
    """The (global, local) index pairs that can overlap for some pose near ``centre``.

    Candidates lie within ``spread_m`` of the centre position and
    ``spread_rad`` of its heading. A pair is dropped only when it cannot
    contribute for any of them: the local segment stays outside the band of
    the global segment's line, or outside its viewing sector, or farther from
    the global segment than a pairing piece can be (a point within δ of G's
    line, inside G's sector and seen at an incidence of at least the minimum,
    lies within δ / sin(incidence) of G). Pairs dropped here would add
    exactly zero, so the overlap is unchanged.
    """
    g = np.ascontiguousarray(np.asarray(segments_world, dtype=float).reshape(-1, 4))
    loc = np.ascontiguousarray(np.asarray(segments_robot, dtype=float).reshape(-1, 4))
    sin_min = float(np.sin(np.deg2rad(min_incidence_deg)))
    x, y, theta = (float(v) for v in centre.as_array())
    return _pairs_at(
        g, loc, x, y, theta, float(spread_m), float(spread_rad), float(band_m), sin_min
    )


@njit(cache=True)
def _candidates(x, y, theta, eta, dtheta):
    out = np.empty((27, 3))
    k = 0
    for i in (-1.0, 0.0, 1.0):
        for j in (-1.0, 0.0, 1.0):
            for h in (-1.0, 0.0, 1.0):
                out[k, 0] = x + i * eta
                out[k, 1] = y + j * eta
                out[k, 2] = wrap(theta + h * dtheta)
                k += 1
    return out


def candidate_poses(centre: Pose2, grid_m: float, dtheta_rad: float) -> np.ndarray:
    """The 27 candidates (27, 3) of one iteration: a 3×3 grid of spacing ``grid_m`` × 3 headings."""
    x, y, theta = (float(v) for v in centre.as_array())
    return _candidates(x, y, theta, float(grid_m), float(dtheta_rad))


@dataclass(frozen=True)
class OverlapResult:
    """Outcome of the coarse-to-fine search.

    ``pose`` is the final estimate (world frame), ``overlap_m`` the overlap at
    it with the last iteration's band, ``track`` (I + 1, 3) the estimate
    before the first and after each of the I iterations run (I = K without
    re-centring), ``best_overlaps_m`` (I,) the best candidate overlap of each.
    """

    pose: Pose2
    overlap_m: float
    track: np.ndarray
    best_overlaps_m: np.ndarray


@njit(cache=True)
def _pairs_at(g, loc, x, y, theta, spread_m, spread_rad, band_m, sin_min):
    """``candidate_pairs`` around the pose (x, y, theta)."""
    g_robot = into_frame(g, x, y, theta)
    local_world = out_of_frame(loc, x, y, theta)
    return _pairs_kernel(g, g_robot, loc, local_world, spread_m, spread_rad, band_m, sin_min)


@njit(cache=True)
def _search_kernel(g, loc, x, y, theta, eta, dtheta, iterations, ratio, recentres, sin_min):
    """The loop of ``coarse_to_fine``: (track (T, 3), best overlaps (T − 1,), final overlap)."""
    track = np.empty((iterations + recentres + 1, 3))
    best_overlaps = np.empty(iterations + recentres)
    track[0] = x, y, theta
    steps, halvings, repeats_left = 0, 0, recentres
    while halvings < iterations:
        band = band_halfwidth(eta)
        candidates = _candidates(x, y, theta, eta, dtheta)
        pair_g, pair_l = _pairs_at(g, loc, x, y, theta, np.sqrt(2.0) * eta, dtheta, band, sin_min)
        overlaps = _overlaps_kernel(g, loc, candidates, pair_g, pair_l, band, sin_min * sin_min)
        best = overlaps.max()
        best_overlaps[steps] = best
        if best > 0.0:
            sw = sx = sy = ss = sc = 0.0
            for k in range(27):
                w = overlaps[k]
                if w >= ratio * best:
                    sw += w
                    sx += w * candidates[k, 0]
                    sy += w * candidates[k, 1]
                    ss += w * np.sin(candidates[k, 2])
                    sc += w * np.cos(candidates[k, 2])
            x, y, theta = sx / sw, sy / sw, wrap(np.arctan2(ss, sc))
        steps += 1
        track[steps] = x, y, theta
        moved_m = np.hypot(x - track[steps - 1, 0], y - track[steps - 1, 1])
        turned = abs(wrap(theta - track[steps - 1, 2]))
        if repeats_left > 0 and best > 0.0 and (moved_m > eta / 2.0 or turned > dtheta / 2.0):
            # The estimate left the central cell: search again at this scale
            # before refining, or the halved grid may no longer reach the pose.
            repeats_left -= 1
            continue
        eta /= 2.0
        dtheta /= 2.0
        halvings += 1
    final_band = np.sqrt(2.0) * eta  # the last iteration's: band_halfwidth(2·η)
    pair_g, pair_l = _pairs_at(g, loc, x, y, theta, 0.0, 0.0, final_band, sin_min)
    final = _overlaps_kernel(
        g, loc, track[steps : steps + 1], pair_g, pair_l, final_band, sin_min * sin_min
    )[0]
    return track[: steps + 1].copy(), best_overlaps[:steps].copy(), final


def coarse_to_fine(
    segments_world: np.ndarray,
    segments_robot: np.ndarray,
    start: Pose2,
    *,
    grid_m: float,
    dtheta_deg: float,
    iterations: int,
    ratio: float,
    recentres: int,
    index: SegmentGrid | None = None,
) -> OverlapResult:
    """Refine ``start`` (world frame) by the paper's coarse-to-fine overlap search.

    ``segments_world`` (M, 4) is the global map, ``segments_robot`` (N, 4) the
    local map. The tuning (first grid spacing ``grid_m`` in metres, first
    heading step ``dtheta_deg``, ``iterations``, ``ratio``, ``recentres``) has
    no defaults here: they live in ``LocalizeParams``.

    Each iteration scores 27 candidates around the current estimate, moves to
    the overlap-weighted mean of those scoring at least ``ratio`` × the best
    (headings averaged on the circle) and halves the grid and the heading
    step; ``iterations`` halvings in all (the paper's K). Each iteration's
    candidates are scored over the (global, local) pairs that
    ``candidate_pairs`` keeps, and the loop runs compiled.

    ``recentres`` > 0 allows up to that many extra iterations, spent where the
    estimate moved by more than half a grid step (or half a heading step): the
    search repeats at that scale instead of halving. With 0 the schedule is
    exactly the paper's.

    ``index``, a ``SegmentGrid`` of ``segments_world``, spares large maps: only
    the segments filed within reach of the whole search take part. The reach
    bounds how far the estimate can travel (√2·η per iteration) plus how far
    a pairing global segment can be from it, so the result is the same as
    without the index.
    """
    g = np.ascontiguousarray(np.asarray(segments_world, dtype=float).reshape(-1, 4))
    loc = np.ascontiguousarray(np.asarray(segments_robot, dtype=float).reshape(-1, 4))
    sin_min = float(np.sin(np.deg2rad(MIN_INCIDENCE_DEG)))
    dtheta = float(np.deg2rad(dtheta_deg))
    if index is not None:
        radius = float(np.hypot(loc[:, 0::2], loc[:, 1::2]).max(initial=0.0))
        travel = np.sqrt(2.0) * grid_m * (2.0 + recentres)
        turn = dtheta * (2.0 + recentres)
        reach = radius * (1.0 + turn) + travel + band_halfwidth(grid_m) / sin_min + 1e-6
        g = np.ascontiguousarray(g[index.candidates([start.x, start.y], reach)])
    track, best_overlaps, final = _search_kernel(
        g, loc, float(start.x), float(start.y), float(start.theta), float(grid_m), dtheta,
        int(iterations), float(ratio), int(recentres), sin_min,
    )  # fmt: skip
    return OverlapResult(Pose2(*track[-1]), float(final), track, best_overlaps)
