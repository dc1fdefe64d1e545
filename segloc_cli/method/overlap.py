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
the origin. (A scanner mounted off the robot's origin gives its local map in the
robot frame, so its sectors are taken from the robot's origin instead: 23 cm off,
that moves the stage-2 pose by tenths of a millimetre in simulation.) L is
parametrised as A + t·(B − A), t ∈ [0, 1]; the two sector rays and the two band
edges are each a linear inequality in t, so Cls is an interval of t. A cheap,
exact pre-filter first drops the pairs that cannot overlap for any candidate of
an iteration, which is what keeps large maps fast.

The search does each piece of work once where it can: what depends on a local
segment alone once per search, G's frame at a candidate once for all the local
segments paired with G, and G's line only for the pairs that cheap tests leave;
the map segments still within reach of the search are kept in a list that
shrinks as the grid does. The cheap tests tell a pair that adds nothing by
comparing the very numbers its interval is built from, without dividing them.
None of this changes a result: a pair told apart early is one the full
computation gives 0, and every other is computed by the same operations on the
same numbers, summed in the same order (only a NaN, from input that is not
finite, may come out with its sign bit flipped).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from segloc_cli.geometry import Pose2
from segloc_cli.jit import njit
from segloc_cli.method.kernels import (
    angular_interval,
    out_of_frame,
    point_into_frame,
    point_segment_distance,
    segment_distance_ends,
    wrap,
)
from segloc_cli.method.spatial import SegmentGrid, cell_span


@njit(cache=True)
def band_halfwidth(grid_m: float) -> float:
    """δ for grid spacing η: the largest distance from a point to its nearest grid node."""
    return np.sqrt(2.0) * grid_m / 2.0


MIN_INCIDENCE_DEG = 5.0
"""Shallowest angle between a scanner ray and a global segment at which they can pair."""

# The hot loops below run once per candidate × pair, tens of thousands of
# times per pose, on a handful of scalars each; compiled, they cost less than
# the array bookkeeping a vectorised version needs at these sizes.

# Columns of the per-local-segment table built once per search (``_local_map``).
_FAR, _MID, _HALF, _DX, _DY, _LEN = range(6)


@njit(cache=True)
def _ordered(gax, gay, gbx, gby):
    """Whether G (robot frame) subtends a sector at the scanner, and its ends (4) ordered
    counter-clockwise as seen from there."""
    turn = gax * gby - gay * gbx
    if abs(turn) <= 1e-12:
        return False, gax, gay, gbx, gby  # G lies on a line through the scanner: no sector
    if turn < 0.0:
        return True, gbx, gby, gax, gay
    return True, gax, gay, gbx, gby


class _Line(NamedTuple):
    """G's supporting line: its unit normal (nx, ny) and its offset n·A (m)."""

    nx: float
    ny: float
    off: float


class _LocalSegment(NamedTuple):
    """L as A + t·(dx, dy), t in [0, 1]: A (m), B − A (m) and L's length (m)."""

    ax: float
    ay: float
    dx: float
    dy: float
    length: float


class _SectorTerms(NamedTuple):
    """L = A + t·(dx, dy) lies left of the ray through G's first end where a0 + b0·t >= 0,
    right of the ray through its second where a1 + b1·t >= 0 (``_sector_terms``)."""

    a0: float
    b0: float
    a1: float
    b1: float


@njit(cache=True)
def _normal(gax, gay, gbx, gby):
    """G's ``_Line`` in the robot frame, for the ordered ends of a G that subtends a sector
    (and so has a length, unless its square underflows)."""
    ex, ey = gbx - gax, gby - gay
    g_len = np.sqrt(ex * ex + ey * ey)
    nx, ny = -ey / g_len, ex / g_len
    return _Line(nx, ny, nx * gax + ny * gay)


@njit(cache=True)
def _zero_length(gax, gay, gbx, gby) -> bool:
    """Whether G's squared length rounds to zero, so that ``_normal`` divides by zero: it is
    then worked out even where no pair needs it, to raise the error it always raised
    (a G that subtends a sector gets there only with coordinates beyond 1e150)."""
    ex, ey = gbx - gax, gby - gay
    return ex * ex + ey * ey == 0.0


@njit(cache=True)
def _sector_terms(gax, gay, gbx, gby, lax, lay, dx, dy):
    """The ``_SectorTerms`` of L = A + t·(dx, dy) and G's sector (ordered ends), robot
    frame."""
    return _SectorTerms(
        gax * lay - gay * lax,
        gax * dy - gay * dx,
        lax * gby - lay * gbx,
        dx * gby - dy * gbx,
    )


@njit(cache=True)
def _outside_sector(terms) -> bool:
    """Whether both ends of L break one of the sector's constraints (``_SectorTerms``), told
    without dividing.

    Then the pair overlaps nothing: for a finite b, a + b rounds below 0 only if
    it is below 0, which puts the root -a/b outside [0, 1] on the side that
    empties the interval.
    """
    a0, b0, a1, b1 = terms
    # & and |, not `and` and `or`: both sides are cheap, and a branch here is unpredictable
    return ((a0 < 0.0) & (a0 + b0 < 0.0) & (abs(b0) < np.inf)) | (
        (a1 < 0.0) & (a1 + b1 < 0.0) & (abs(b1) < np.inf)
    )


@njit(cache=True)
def _both_outside_unit(p: float, q: float, d: float) -> bool:
    """Whether p / d and q / d (d ≠ 0) both round to at most 0 or both to at least 1, told
    without dividing: over a finite positive d a quotient keeps its numerator's sign, and
    is at least 1 when the numerator is at least d (the other way round for a negative d)."""
    if 0.0 < d < np.inf:
        return (p < 0.0 and q < 0.0) or (p >= d and q >= d)
    if -np.inf < d < 0.0:
        return (p > 0.0 and q > 0.0) or (p <= d and q <= d)
    return False  # an infinite or NaN d may make NaN quotients, which trim nothing


@njit(cache=True)
def _clipped_overlap(line, segment, terms, band_m, sin2_min) -> float:
    """|Cls| + |Cgs| in metres of G (its ``_Line``) and L (``_LocalSegment``) with their
    ``_SectorTerms``, all in the robot frame."""
    nx, ny, off = line
    lax, lay, dx, dy, l_len = segment
    a0, b0, a1, b1 = terms
    # The band |n·(A + t·d) − off| <= δ around G's line: t between (∓δ − s0) / sd.
    s0 = nx * lax + ny * lay - off
    sd = nx * dx + ny * dy
    below, above = -band_m - s0, band_m - s0
    if sd == 0.0:
        if abs(s0) > band_m:
            return 0.0
    elif _both_outside_unit(below, above, sd):
        return 0.0
    # L is A + t·(B − A), t in [lo, hi]; each constraint a + b·t >= 0 trims it.
    lo, hi = 0.0, 1.0
    for a, b in ((a0, b0), (a1, b1)):
        if b > 0.0:
            lo = max(lo, -a / b)
        elif b < 0.0:
            hi = min(hi, -a / b)
        elif a < 0.0:
            return 0.0
    # An empty interval stays empty: the band's trim only raises lo and lowers hi.
    if hi <= lo:
        return 0.0
    if sd != 0.0:
        t1, t2 = below / sd, above / sd
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
    return (hi - lo) * l_len + np.sqrt(cx * cx + cy * cy)


@njit(cache=True)
def _pair_overlap(gax, gay, gbx, gby, lax, lay, lbx, lby, band_m, sin2_min) -> float:
    """|Cls| + |Cgs| of one pair, both segments in the robot frame (scanner at the origin)."""
    facing, gax, gay, gbx, gby = _ordered(gax, gay, gbx, gby)
    if not facing:
        return 0.0
    dx, dy = lbx - lax, lby - lay
    terms = _sector_terms(gax, gay, gbx, gby, lax, lay, dx, dy)
    if _outside_sector(terms) and not _zero_length(gax, gay, gbx, gby):
        return 0.0
    line = _normal(gax, gay, gbx, gby)
    segment = _LocalSegment(lax, lay, dx, dy, np.sqrt(dx * dx + dy * dy))
    return _clipped_overlap(line, segment, terms, band_m, sin2_min)


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


# --- the search's bookkeeping -----------------------------------------------------------------


class _LocalMap(NamedTuple):
    """The local map as the search takes it (``_local_map``)."""

    segments: np.ndarray
    """(N, 4) local segments, robot frame, m."""
    table: np.ndarray
    """(N, 6) what the search needs of each whatever the pose: columns _FAR (range of its
    farther end, m), _MID and _HALF (centre and half-width of the angle it subtends, rad),
    _DX, _DY (B − A, m) and _LEN (length, m)."""
    radius: float
    """The largest range of any end (m; 0 for none)."""


class _Around(NamedTuple):
    """The candidate poses a pair table serves: within ``spread_m`` (m) and ``spread_rad``
    (rad) of (x, y, theta) (world frame), scored in a band of half-width ``band_m`` (m)
    around each global segment's line, at incidences whose sine is at least ``sin_min``."""

    x: float
    y: float
    theta: float
    spread_m: float
    spread_rad: float
    band_m: float
    sin_min: float


class _PairTable(NamedTuple):
    """The pairs of an iteration, grouped by global segment: ``group_g`` (M,) lists the
    global segments that pair with anything, in map order; ``group_end`` (M,) where each
    one's run of local indices ends in ``pair_l`` (M·N,), which holds them in increasing
    order. Read in order, the runs are ``candidate_pairs``' pairs, in its order. Only the
    first groups, as many as ``_filter_pairs`` says, are filled."""

    group_g: np.ndarray
    group_end: np.ndarray
    pair_l: np.ndarray


@njit(cache=True)
def _local_map(loc):
    """The ``_LocalMap`` of local segments (N, 4), robot frame."""
    table = np.empty((loc.shape[0], 6))
    radius = 0.0
    for n in range(loc.shape[0]):
        r1 = np.sqrt(loc[n, 0] ** 2 + loc[n, 1] ** 2)
        r2 = np.sqrt(loc[n, 2] ** 2 + loc[n, 3] ** 2)
        table[n, _FAR] = max(r1, r2)
        radius = max(radius, max(r1, r2))
        table[n, _MID], table[n, _HALF] = angular_interval(
            loc[n, 0], loc[n, 1], loc[n, 2], loc[n, 3]
        )
        dx, dy = loc[n, 2] - loc[n, 0], loc[n, 3] - loc[n, 1]
        table[n, _DX], table[n, _DY] = dx, dy
        table[n, _LEN] = np.sqrt(dx * dx + dy * dy)
    return _LocalMap(loc, table, radius)


@njit(cache=True)
def _world_line(g, m):
    """Unit normal and offset (nx, ny, off) of global segment m's line, world frame.

    A segment of zero length divides by zero here, as ever once within range.
    Recomputed at each use: that costs less than a lookup in a table kept across calls.
    """
    length = np.sqrt((g[m, 2] - g[m, 0]) ** 2 + (g[m, 3] - g[m, 1]) ** 2)
    nx, ny = -(g[m, 3] - g[m, 1]) / length, (g[m, 2] - g[m, 0]) / length
    return nx, ny, nx * g[m, 0] + ny * g[m, 1]


@njit(cache=True)
def _filter_pairs(g, local, around, active, n_active, keep_m, pairs):
    """The pairs of global segments ``g`` (M, 4), world frame, among ``active[:n_active]``,
    and segments of the ``local`` map that can overlap for some pose ``around`` serves; see
    ``candidate_pairs``.

    Fills ``pairs`` (``_PairTable``) and returns the number of groups and of active
    segments left: ``active`` is compacted in place to those within ``keep_m`` metres
    (plus rounding slack) of this iteration's range, all that a search moving at most
    ``keep_m`` from here with no wider grid can still reach.
    """
    loc, table, radius = local
    x, y, theta, spread_m, spread_rad, band_m, sin_min = around
    group_g, group_end, pair_l = pairs
    n_local = loc.shape[0]
    if n_local == 0 or g.shape[0] == 0:
        return 0, n_active
    reach = np.empty(n_local)  # how far a local segment's points can move over the candidates
    for n in range(n_local):
        reach[n] = spread_m + table[n, _FAR] * spread_rad
    # A pairing piece lies within band / sin(min incidence) of G.
    near = band_m / sin_min
    reach_max = reach.max()
    # Range: every local point is within `radius` of the scanner.
    in_range = radius + near + reach_max + 1e-9
    local_world = out_of_frame(loc, x, y, theta)
    cs, sn = np.cos(theta), np.sin(theta)

    n_groups, count, kept = 0, 0, 0
    for k in range(n_active):
        m = active[k]
        gax, gay = point_into_frame(g[m, 0], g[m, 1], x, y, cs, sn)
        gbx, gby = point_into_frame(g[m, 2], g[m, 3], x, y, cs, sn)
        dist0 = point_segment_distance(0.0, 0.0, gax, gay, gbx, gby)
        # Far past the rounding of dist0 and of the moves that add up to keep_m.
        slack = 1e-6 + 1e-9 * (abs(x) + abs(y) + abs(gax) + abs(gay) + abs(gbx) + abs(gby))
        if dist0 > in_range + keep_m + slack:
            continue  # out of range here and at every later, nearer-sighted iteration
        active[kept] = m
        kept += 1
        if dist0 > in_range:
            continue
        nx, ny, off = _world_line(g, m)
        first = count
        seen = False  # G's sector, worked out once a local segment is in its band
        g_mid = g_half = widen = 0.0
        for n in range(n_local):
            lx1, ly1 = local_world[n, 0], local_world[n, 1]  # scalars: a row slice costs more
            lx2, ly2 = local_world[n, 2], local_world[n, 3]
            limit = band_m + reach[n]
            d1 = nx * lx1 + ny * ly1 - off
            d2 = nx * lx2 + ny * ly2 - off
            if (d1 > limit and d2 > limit) or (d1 < -limit and d2 < -limit):
                continue  # stays outside the band
            if not seen:
                g_mid, g_half, widen = _widened_sector(gax, gay, gbx, gby, dist0, spread_m)
                seen = True
            if (
                abs(wrap(g_mid - table[n, _MID]))
                > g_half + widen + spread_rad + table[n, _HALF] + 1e-9
            ):
                continue  # stays outside the sector
            gap = segment_distance_ends(g[m, 0], g[m, 1], g[m, 2], g[m, 3], lx1, ly1, lx2, ly2)
            if gap > near + reach[n] + 1e-9:
                continue  # too far from G for a piece seen at a steep enough incidence
            pair_l[count] = n
            count += 1
        if count > first:
            group_g[n_groups] = m
            group_end[n_groups] = count
            n_groups += 1
    return n_groups, kept


@njit(cache=True)
def _widened_sector(gax, gay, gbx, gby, dist0, spread_m):
    """Centre and half-width (rad) of G's angular interval (robot frame), and how much a
    shift of ``spread_m`` can widen it (π when the scanner can reach G itself, and may
    see it from the other side)."""
    r_ends = min(np.sqrt(gax**2 + gay**2), np.sqrt(gbx**2 + gby**2))
    if dist0 > spread_m:
        widen = np.arcsin(min(spread_m / max(r_ends, 1e-12), 1.0))
    else:
        widen = np.pi
    g_mid, g_half = angular_interval(gax, gay, gbx, gby)
    return g_mid, g_half, widen


@njit(cache=True)
def _grouped_overlaps(g, local, poses, pairs, n_groups, band_m, sin2_min):
    """Overlap (C,) at each pose (C, 3) of the ``local`` map over the first ``n_groups``
    groups of ``pairs`` (``_PairTable``): the sum of ``_overlaps_kernel`` over the same
    pairs, in the same order, with G's frame worked out once per pose for all its local
    segments, and its line only once one needs it."""
    loc, table = local.segments, local.table
    group_g, group_end, pair_l = pairs
    out = np.zeros(poses.shape[0])
    in_sector = np.empty(loc.shape[0], dtype=np.int64)  # one G's pairs past the sector test
    for c in range(poses.shape[0]):
        px, py = poses[c, 0], poses[c, 1]
        cs, sn = np.cos(poses[c, 2]), np.sin(poses[c, 2])
        total = 0.0
        first = 0
        for k in range(n_groups):
            m, last = group_g[k], group_end[k]
            gax, gay = point_into_frame(g[m, 0], g[m, 1], px, py, cs, sn)
            gbx, gby = point_into_frame(g[m, 2], g[m, 3], px, py, cs, sn)
            facing, gax, gay, gbx, gby = _ordered(gax, gay, gbx, gby)
            # Most pairs are told to add nothing before G's line is needed; the pairs past
            # that test are gathered first, so the line is worked out only for them.
            passed = 0
            if facing:  # else every pair of G adds 0
                for j in range(first, last):
                    n = pair_l[j]
                    lax, lay, dx, dy = loc[n, 0], loc[n, 1], table[n, _DX], table[n, _DY]
                    terms = _sector_terms(gax, gay, gbx, gby, lax, lay, dx, dy)
                    in_sector[passed] = n  # kept only if it passes: written without a branch
                    passed += not _outside_sector(terms)
            if passed > 0 or (facing and _zero_length(gax, gay, gbx, gby)):
                line = _normal(gax, gay, gbx, gby)
                for i in range(passed):
                    n = in_sector[i]
                    lax, lay, dx, dy = loc[n, 0], loc[n, 1], table[n, _DX], table[n, _DY]
                    terms = _sector_terms(gax, gay, gbx, gby, lax, lay, dx, dy)
                    segment = _LocalSegment(lax, lay, dx, dy, table[n, _LEN])
                    total += _clipped_overlap(line, segment, terms, band_m, sin2_min)
            first = last
        out[c] = total
    return out


@njit(cache=True)
def _pairs_at(g, local, around, active, n_active):
    """``candidate_pairs`` of the ``local`` map for the poses ``around`` serves, among the
    global segments ``active[:n_active]``: (global indices, local indices)."""
    n_map = g.shape[0]
    pairs = _PairTable(
        np.empty(n_map, dtype=np.int64),
        np.empty(n_map, dtype=np.int64),
        np.empty(n_map * local.segments.shape[0], dtype=np.int64),
    )
    # keep_m inf: leaves `active` as it is
    n_groups, _ = _filter_pairs(g, local, around, active, n_active, np.inf, pairs)
    group_g, group_end, pair_l = pairs
    count = group_end[n_groups - 1] if n_groups > 0 else 0
    pair_g = np.empty(count, dtype=np.int64)
    first = 0
    for k in range(n_groups):
        pair_g[first : group_end[k]] = group_g[k]
        first = group_end[k]
    return pair_g, pair_l[:count].copy()


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
    around = _Around(x, y, theta, float(spread_m), float(spread_rad), float(band_m), sin_min)
    everything = np.arange(g.shape[0])
    return _pairs_at(g, _local_map(loc), around, everything, everything.size)


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
def _travel_left(x, y, theta, eta, dtheta, repeats_left, active, n_active):
    """How far (m) the estimate at (x, y, theta) can still move, and the number of map
    segments in the search's ``active`` list.

    The estimate moves at most √2·η per iteration, η halving after all but
    ``repeats_left`` of them; without η > 0 and Δα ≥ 0 (so that the grid's
    reach only shrinks) there is no bound (inf). An estimate that is not
    finite is in range of every segment, as no distance rules one out: the
    list is reset to all of them.
    """
    if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(theta)):
        for m in range(active.shape[0]):
            active[m] = m
        return np.inf, active.shape[0]
    if not (eta > 0.0 and dtheta >= 0.0):
        return np.inf, n_active
    return np.sqrt(2.0) * eta * (max(repeats_left, 0) + 2.0), n_active


class _Schedule(NamedTuple):
    """The tuning of ``coarse_to_fine``: the first grid spacing η (m) and heading step Δα
    (rad), the halvings K, the share of the best overlap from which candidates are
    averaged, and the extra iterations allowed for re-centring."""

    eta: float
    dtheta: float
    iterations: int
    ratio: float
    recentres: int


@njit(cache=True)
def _search_kernel(g, loc, start, schedule, sin_min):
    """The loop of ``coarse_to_fine`` from ``start`` (x, y, theta), world frame, by the
    ``_Schedule``: (track (T, 3), best overlaps (T − 1,), final overlap)."""
    x, y, theta = start
    eta, dtheta, iterations, ratio, recentres = schedule
    track = np.empty((iterations + recentres + 1, 3))
    best_overlaps = np.empty(iterations + recentres)
    track[0, 0], track[0, 1], track[0, 2] = x, y, theta
    n_map = g.shape[0]
    local = _local_map(loc)
    active, n_active = np.arange(n_map), n_map
    pairs = _PairTable(
        np.empty(n_map, dtype=np.int64),
        np.empty(n_map, dtype=np.int64),
        np.empty(n_map * loc.shape[0], dtype=np.int64),
    )
    steps, halvings, repeats_left = 0, 0, recentres
    while halvings < iterations:
        band = band_halfwidth(eta)
        candidates = _candidates(x, y, theta, eta, dtheta)
        travel, n_active = _travel_left(x, y, theta, eta, dtheta, repeats_left, active, n_active)
        around = _Around(x, y, theta, np.sqrt(2.0) * eta, dtheta, band, sin_min)
        n_groups, n_active = _filter_pairs(g, local, around, active, n_active, travel, pairs)
        overlaps = _grouped_overlaps(g, local, candidates, pairs, n_groups, band, sin_min * sin_min)
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
        track[steps, 0], track[steps, 1], track[steps, 2] = x, y, theta
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
    _, n_active = _travel_left(x, y, theta, eta, dtheta, repeats_left, active, n_active)
    at_final = _Around(x, y, theta, 0.0, 0.0, final_band, sin_min)
    final_g, final_l = _pairs_at(g, local, at_final, active, n_active)
    final_pose = track[steps : steps + 1]
    final = _overlaps_kernel(g, loc, final_pose, final_g, final_l, final_band, sin_min * sin_min)
    return track[: steps + 1].copy(), best_overlaps[:steps].copy(), final[0]


def _within_reach(index: SegmentGrid, g: np.ndarray, x: float, y: float, reach_m: float):
    """The rows of ``g`` (the map ``index`` files) in the cells within ``reach_m`` of (x, y),
    in order: ``g`` itself when those cells are all of them."""
    ix0, ix1, iy0, iy1 = cell_span(index.cells, x, y, reach_m)
    shape = index.cells[2]
    every_cell = (ix0, iy0, ix1, iy1) == (0, 0, shape[0] - 1, shape[1] - 1)
    if every_cell and g.shape[0] == index.segments_world.shape[0]:
        return g  # SegmentGrid.candidates would list every segment, at a cost
    return np.ascontiguousarray(g[index.candidates([x, y], reach_m)])


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
        g = _within_reach(index, g, float(start.x), float(start.y), float(reach))
    schedule = _Schedule(float(grid_m), dtheta, int(iterations), float(ratio), int(recentres))
    at = (float(start.x), float(start.y), float(start.theta))
    track, best_overlaps, final = _search_kernel(g, loc, at, schedule, sin_min)
    return OverlapResult(Pose2(*track[-1]), float(final), track, best_overlaps)
