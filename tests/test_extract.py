"""Local-map extraction on ray-cast scans of hand-made scenes."""

from __future__ import annotations

import dataclasses
import math
from itertools import pairwise

import numpy as np
import pytest

from segloc_cli.geometry import Pose2, transform_points, transform_segments
from segloc_cli.method.extract import (
    ExtractParams,
    _numpy_sum,
    breakpoints,
    direction_sigma_rad,
    extract_segments,
    fit_line,
    line_residuals,
)
from segloc_cli.scan import Scan
from segloc_cli.sim import (
    NOISE_FREE,
    SensorModel,
    beam_angles,
    cast_rays,
    random_free_poses,
    random_world,
    simulate_scan,
)

# An 8 m × 8 m room centred on the origin: walls x = ±4 and y = ±4.
ROOM = np.array([[-4, -4, 4, -4], [4, -4, 4, 4], [4, 4, -4, 4], [-4, 4, -4, -4]], dtype=float)
WALL_LINES = {"x=4": (0, 4.0), "x=-4": (0, -4.0), "y=4": (1, 4.0), "y=-4": (1, -4.0)}

# The scanner at (0.3, −0.2), turned so that beam 0 points just past the corner (4, 4)
# (by a quarter of the 1024-beam step): the scan starts on the wall y = 4 next to the
# corner and ends on the wall x = 4 next to it, so no wall crosses the angle 0 seam.
CORNER_POSE = Pose2(0.3, -0.2, float(np.arctan2(4.0 + 0.2, 4.0 - 0.3) + np.pi / 2048))
# The same spot facing +x: beam 0 hits the wall x = 4 in its middle, at y = −0.2.
MIDWALL_POSE = Pose2(0.3, -0.2, 0.0)


def scan_of(world: np.ndarray, pose: Pose2, readings: int = 1024, range_max: float = 30.0):
    """A noise-free 360° scan of ``world`` from ``pose`` (beam i at 2π·i/readings)."""
    angles = beam_angles(readings)
    ranges = cast_rays(world, [pose.x, pose.y], pose.theta + angles)
    return Scan(0.0, angles, ranges, range_max)


def hits_world(scan: Scan, pose: Pose2) -> np.ndarray:
    """The valid readings of ``scan`` as world points (K, 2)."""
    return transform_segments(np.hstack([scan.points(), scan.points()]), pose)[:, :2]


def wall_of(points: np.ndarray, tol: float) -> list[str | None]:
    """The room wall each point lies on (within ``tol``), or None."""
    names = []
    for p in np.atleast_2d(points):
        on = [name for name, (axis, value) in WALL_LINES.items() if abs(p[axis] - value) < tol]
        names.append(on[0] if len(on) == 1 else ("corner" if on else None))
    return names


def along(points: np.ndarray, wall: str) -> np.ndarray:
    """Coordinate of points along ``wall`` (y for the x = ±4 walls, x for the others)."""
    axis, _ = WALL_LINES[wall]
    return np.atleast_2d(points)[:, 1 - axis]


def assert_segments_on_room_walls(segs_world: np.ndarray, tol: float) -> dict[str, np.ndarray]:
    """Every segment lies along one wall within ``tol``; returns the segments per wall."""
    per_wall: dict[str, list[np.ndarray]] = {name: [] for name in WALL_LINES}
    for s in segs_world:
        ends = s.reshape(2, 2)
        candidates = [
            name
            for name, (axis, value) in WALL_LINES.items()
            if np.all(np.abs(ends[:, axis] - value) < tol)
        ]
        assert len(candidates) == 1, f"segment {s} does not lie along one wall (±{tol} m)"
        per_wall[candidates[0]].append(s)
    return {k: np.array(v).reshape(-1, 4) for k, v in per_wall.items()}


# --- noise-free square room -------------------------------------------------------------------


@pytest.mark.parametrize("readings", [1024, 2048])
def test_square_room_gives_four_segments_on_the_walls(readings):
    scan = scan_of(ROOM, CORNER_POSE, readings)
    segs = extract_segments(scan)
    assert segs.shape == (4, 4)
    world = transform_segments(segs, CORNER_POSE)
    per_wall = assert_segments_on_room_walls(world, tol=1e-3)
    hits = hits_world(scan, CORNER_POSE)
    hit_walls = np.array(wall_of(hits, 1e-9), dtype=object)
    for name, s in per_wall.items():
        assert s.shape == (1, 4), f"wall {name}: {s.shape[0]} segments"
        lo, hi = np.sort(along(s.reshape(2, 2), name))
        # Spans every beam that hit this wall (the corners count for both walls) ...
        on_wall = hits[(hit_walls == name) | (hit_walls == "corner")]
        assert lo <= along(on_wall, name).min() + 1e-3
        assert hi >= along(on_wall, name).max() - 1e-3
        # ... and stays within the wall.
        assert lo >= -4.0 - 1e-3
        assert hi <= 4.0 + 1e-3
        # The beam spacing near a corner, ≈ r·Δφ/cos 45° ≤ 5.7·(2π/1024)·√2 ≈ 5 cm at 1024
        # readings, is all that can be missing at each end.
        gap = 5.7 * (2 * np.pi / readings) * np.sqrt(2)
        assert hi - lo >= 8.0 - 2 * gap


def test_coarse_scan_corner_reading_does_not_tilt_a_wall():
    # 256 readings: near a corner the beams are ~20 cm apart, so the reading of the next
    # wall closest to the corner lies a few cm off this wall's line. Noise-free readings of
    # one wall are exactly collinear, so its segment must still lie on it to < 1 mm.
    scan = scan_of(ROOM, CORNER_POSE, 256)
    world = transform_segments(extract_segments(scan), CORNER_POSE)
    assert world.shape == (4, 4)
    ends = world.reshape(-1, 2)
    off = np.min(np.abs(np.abs(ends) - 4.0), axis=1)
    assert off.max() < 1e-3, (
        f"segment ends up to {off.max() * 1e3:.2f} mm off the walls: the split point is "
        "shared by the two pieces it separates (split_points keeps index i0 + k in both), so one "
        "wall's refit includes the next wall's corner reading. Drop a shared end point that "
        "does not fit the piece's line before the merge test and the refit"
    )


def test_missing_beams_shorten_only_their_wall():
    scan = scan_of(ROOM, CORNER_POSE)
    hits = hits_world(scan, CORNER_POSE)
    ranges = scan.ranges_m.copy()
    # No return from the wall x = 4 above y = 1.5.
    lost = (np.abs(hits[:, 0] - 4.0) < 1e-9) & (hits[:, 1] > 1.5)
    assert lost.sum() > 50
    ranges[lost] = np.inf
    last_seen = hits[(np.abs(hits[:, 0] - 4.0) < 1e-9) & (hits[:, 1] <= 1.5), 1].max()
    segs = extract_segments(Scan(0.0, scan.angles_rad, ranges, scan.range_max_m))
    per_wall = assert_segments_on_room_walls(transform_segments(segs, CORNER_POSE), 1e-3)
    assert all(s.shape == (1, 4) for s in per_wall.values())
    top = np.sort(per_wall["x=4"][0, [1, 3]])
    # The wall x = 4 is now seen from its bottom corner up to the last beam below 1.5 m.
    assert top[1] == pytest.approx(last_seen, abs=1e-3)
    assert top[0] < -3.9
    # The wall y = 4 still reaches the corner (4, 4) it shares with the lost part.
    assert per_wall["y=4"][0, [0, 2]].max() > 3.9


def test_invalid_readings_are_dropped():
    scan = scan_of(ROOM, CORNER_POSE, range_max=10.0)
    clean = extract_segments(scan)
    ranges = scan.ranges_m.copy()
    # Readings in the middle of the walls (beams 100, 300, … are far from every corner):
    # zero, negative, NaN, +inf, exactly range_max and beyond it.
    bad = {100: 0.0, 101: -1.0, 300: np.nan, 500: np.inf, 501: np.inf, 700: 10.0, 900: 12.5}
    for i, value in bad.items():
        ranges[i] = value
    dirty = Scan(0.0, scan.angles_rad, ranges, 10.0)
    assert dirty.valid.sum() == len(ranges) - len(bad)
    segs = extract_segments(dirty)
    # Dropping interior points of collinear readings changes no line and no end (to 0.1 mm:
    # a corner reading in a piece tilts its fit by a few µm, see the 256-reading test).
    assert segs.shape == clean.shape
    np.testing.assert_allclose(segs, clean, atol=1e-4)


def test_too_few_valid_readings_give_an_empty_map():
    # Four beams 4° apart on the wall x = 2, nothing else: exactly min_points (4) readings.
    angles = np.deg2rad([-6.0, -2.0, 2.0, 6.0])
    ranges = 2.0 / np.cos(angles)
    segs = extract_segments(Scan(0.0, angles, ranges))
    # One segment from (2, 2·tan(−6°)) to (2, 2·tan(6°)).
    t = 2.0 * np.tan(np.deg2rad(6.0))
    assert segs.shape == (1, 4)
    ends = segs.reshape(2, 2)[np.argsort(segs.reshape(2, 2)[:, 1])]
    np.testing.assert_allclose(ends, [[2.0, -t], [2.0, t]], atol=1e-12)
    # One of them invalid: three valid readings < min_points → empty (0, 4) map.
    for bad in (0.0, np.nan, np.inf):
        short = ranges.copy()
        short[1] = bad
        empty = extract_segments(Scan(0.0, angles, short))
        assert empty.shape == (0, 4)
    # Nothing valid at all, and no readings at all.
    assert extract_segments(Scan(0.0, angles, np.full(4, np.inf))).shape == (0, 4)
    assert extract_segments(Scan(0.0, np.zeros(0), np.zeros(0))).shape == (0, 4)
    # min_points is the setting that decides.
    assert extract_segments(Scan(0.0, angles, ranges), ExtractParams(min_points=5)).shape == (
        0,
        4,
    )


# --- direction uncertainty --------------------------------------------------------------------


def test_direction_sigma_by_hand():
    # Points at t = −1.5, −0.5, 0.5, 1.5 along x, d above or below: the fitted line is y = 0
    # (centroid at the origin), residuals all d, RMS over K − 2 = 2 degrees of freedom d·√2,
    # spread √(2·1.5² + 2·0.5²) = √5.
    d = 0.01
    pts = np.array([[-1.5, d], [-0.5, -d], [0.5, -d], [1.5, d]])
    centroid, direction = fit_line(pts)
    np.testing.assert_allclose(centroid, [0.0, 0.0], atol=1e-15)
    assert abs(direction[1]) < 1e-15
    assert direction_sigma_rad(pts, centroid, direction, 0.001) == pytest.approx(
        d * np.sqrt(2) / np.sqrt(5), rel=1e-12
    )
    # The scanner's noise is the floor when the points fit better than it.
    assert direction_sigma_rad(pts, centroid, direction, 0.05) == pytest.approx(
        0.05 / np.sqrt(5), rel=1e-12
    )


def test_sparse_far_wall_is_kept_when_its_direction_is_known():
    # A 1°-step scanner sees five readings on a wall 5 m ahead (x = 5, beams −2° … 2°).
    # Five readings 35 cm apart end to end fix the direction to σ ≈ 2.5°: a wall worth keeping.
    angles = np.deg2rad(np.arange(-2.0, 2.5, 1.0))
    ranges = 5.0 / np.cos(angles)
    y = 5.0 * np.tan(angles)
    expected = ExtractParams().range_sigma_m / np.sqrt(np.sum((y - y.mean()) ** 2))
    assert np.rad2deg(expected) < ExtractParams().max_direction_sigma_deg
    segs = extract_segments(Scan(0.0, angles, ranges))
    assert segs.shape == (1, 4)
    np.testing.assert_allclose(segs[0, [0, 2]], [5.0, 5.0], atol=1e-12)
    # A stricter bound just below that σ drops it: the bound, not the count, decided.
    strict = ExtractParams(max_direction_sigma_deg=0.99 * np.rad2deg(expected))
    assert extract_segments(Scan(0.0, angles, ranges), strict).shape == (0, 4)


def rough_wall_scan(half_span_deg: float, roughness_m: float) -> Scan:
    """1°-step readings on the wall x = 2 (robot frame), ±``roughness_m`` alternately off it."""
    angles = np.deg2rad(np.arange(-half_span_deg, half_span_deg + 0.5, 1.0))
    offsets = roughness_m * np.where(np.arange(angles.size) % 2 == 0, 1.0, -1.0)
    return Scan(0.0, angles, (2.0 + offsets) / np.cos(angles))


def test_rough_short_piece_is_dropped_but_a_rough_long_wall_is_kept():
    # Readings ±2 cm off the wall stay within the 5 cm split tolerance, so each span is one
    # piece. Over 28 cm (nine readings) such a surface leaves its direction uncertain by
    # about 4°; over 3.4 m by a fraction of a degree. Noise-free, the short piece is kept.
    assert extract_segments(rough_wall_scan(4.0, 0.0)).shape == (1, 4)
    assert extract_segments(rough_wall_scan(4.0, 0.02)).shape == (0, 4)
    long_wall = extract_segments(rough_wall_scan(40.0, 0.02))
    assert long_wall.shape == (1, 4)
    np.testing.assert_allclose(long_wall[0, [0, 2]], [2.0, 2.0], atol=0.01)


# --- breakpoints ------------------------------------------------------------------------------


def test_breakpoint_splits_walls_at_different_depths():
    # Robot frame. Near wall y = 2 for x ∈ [−1, 0.5]; far wall y = 4 for x ∈ [−3.5, −1.5],
    # hidden behind the near one up to the ray through (−1, 2), i.e. visible for
    # x ∈ [−3.5, −2]. The scan jumps from (−1, 2) to (−2, 4): 2.2 m at 2 m range with
    # 0.35° beam spacing is a breakpoint.
    walls = np.array([[0.5, 2.0, -1.0, 2.0], [-1.5, 4.0, -3.5, 4.0]])
    scan = scan_of(walls, Pose2(0.0, 0.0, 0.0))
    valid = scan.valid
    r, a = scan.ranges_m[valid], scan.angles_rad[valid]
    breaks = breakpoints(r, a, ExtractParams())
    assert breaks.shape == (valid.sum() - 1,)
    (where,) = np.flatnonzero(breaks)
    assert r[where] == pytest.approx(2.0 / np.sin(a[where]), abs=1e-9)  # last on the near wall
    assert r[where + 1] == pytest.approx(4.0 / np.sin(a[where + 1]), abs=1e-9)  # first far
    segs = extract_segments(scan)
    assert segs.shape == (2, 4)
    near = segs[np.abs(segs[:, 1] - 2.0) < 1e-3]
    far = segs[np.abs(segs[:, 1] - 4.0) < 1e-3]
    assert near.shape == (1, 4)
    assert far.shape == (1, 4)
    np.testing.assert_allclose(near[0, [1, 3]], [2.0, 2.0], atol=1e-9)
    np.testing.assert_allclose(far[0, [1, 3]], [4.0, 4.0], atol=1e-9)
    # Spans: near from just inside x = 0.5 to the occluding edge x = −1; far from the
    # shadow edge x = −2 to just inside x = −3.5 (one beam ≤ 0.35°·4 m/sin 45° away).
    assert np.sort(near[0, [0, 2]]) == pytest.approx([-1.0, 0.5], abs=0.02)
    assert np.sort(far[0, [0, 2]]) == pytest.approx([-3.5, -2.0], abs=0.04)


def test_square_room_has_no_breakpoints():
    # Corners are continuous surfaces: neighbouring readings across them are close.
    scan = scan_of(ROOM, CORNER_POSE)
    assert not breakpoints(scan.ranges_m, scan.angles_rad, ExtractParams()).any()


def test_missing_readings_across_a_doorway_break_the_wall():
    # Robot frame: a wall y = 2 with a 0.6 m doorway at x ∈ [−0.3, 0.3] opening on nothing
    # (no return). The two pieces are collinear, but the opening spans 17° of beams that
    # saw no wall: they are two segments, not one wall across the doorway.
    walls = np.array([[2.0, 2.0, 0.3, 2.0], [-0.3, 2.0, -2.0, 2.0]])
    segs = extract_segments(scan_of(walls, Pose2(0.0, 0.0, 0.0)))
    xs = np.sort(segs[:, [0, 2]], axis=1)
    bridges = (xs[:, 0] < -0.3 + 1e-3) & (xs[:, 1] > 0.3 - 1e-3)
    assert not bridges.any(), (
        f"extracted {segs.tolist()}: a segment spans the doorway x ∈ [−0.3, 0.3] where no "
        "beam returned. breakpoints() never breaks when the angle between consecutive valid "
        "readings reaches the incidence λ (sin(λ − Δφ) is clamped to 1e-9, so the allowed gap "
        "is huge); a gap of Δφ ≥ λ should count as a breakpoint"
    )
    assert segs.shape == (2, 4)


# --- the 360° seam ----------------------------------------------------------------------------

BOX = np.array(
    [
        [-2.5, -0.5, -1.5, -0.5],
        [-1.5, -0.5, -1.5, 0.5],
        [-1.5, 0.5, -2.5, 0.5],
        [-2.5, 0.5, -2.5, -0.5],
    ]
)


def test_wrap_joins_the_wall_crossing_angle_zero():
    # Room with a box behind the robot (its shadow makes breakpoints elsewhere). Beam 0
    # points along +x and hits the wall x = 4 at y = −0.2: the first and last readings of the
    # scan are neighbours on that wall, which must come out as one segment.
    scan = scan_of(np.vstack([ROOM, BOX]), MIDWALL_POSE)
    segs = transform_segments(extract_segments(scan), MIDWALL_POSE)
    on_front = segs[np.all(np.abs(segs[:, [0, 2]] - 4.0) < 1e-3, axis=1)]
    assert on_front.shape == (1, 4)
    lo, hi = np.sort(on_front[0, [1, 3]])
    assert lo < -3.9
    assert hi > 3.9


def test_wrap_joins_the_wall_crossing_angle_zero_in_an_unbroken_scan():
    # The plain room from the same spot: no breakpoint anywhere, the whole scan is one
    # closed chain. The wall x = 4 still crosses the seam at beam 0.
    scan = scan_of(ROOM, MIDWALL_POSE)
    segs = transform_segments(extract_segments(scan), MIDWALL_POSE)
    on_front = segs[np.all(np.abs(segs[:, [0, 2]] - 4.0) < 1e-3, axis=1)]
    assert on_front.shape == (1, 4), (
        f"the wall x = 4 came out as {on_front.shape[0]} segments {on_front.tolist()}: with no "
        "breakpoint, _chains returns the single run [0, n) and never joins it across the "
        "seam, so the wall crossing beam 0 is split at beam 0 (or loses its short end)"
    )
    assert segs.shape == (4, 4)


# --- line fit ---------------------------------------------------------------------------------


def test_fit_line_exact_on_collinear_points():
    # y = 0.5·x + 1 at x = −2, 0, 1, 5: centroid (1, 1.5), direction ±(2, 1)/√5.
    x = np.array([-2.0, 0.0, 1.0, 5.0])
    pts = np.column_stack([x, 0.5 * x + 1.0])
    centroid, direction = fit_line(pts)
    np.testing.assert_allclose(centroid, [1.0, 1.5], atol=1e-15)
    assert abs(direction @ np.array([2.0, 1.0]) / np.sqrt(5.0)) == pytest.approx(1.0, abs=1e-15)
    assert np.linalg.norm(direction) == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_allclose(line_residuals(pts, centroid, direction), 0.0, atol=1e-14)
    # Vertical and horizontal lines.
    c, d = fit_line(np.array([[3.0, -1.0], [3.0, 0.0], [3.0, 4.0]]))
    np.testing.assert_allclose(c, [3.0, 1.0], atol=1e-15)
    np.testing.assert_allclose(np.abs(d), [0.0, 1.0], atol=1e-15)
    c, d = fit_line(np.array([[-1.0, 2.0], [0.5, 2.0], [7.0, 2.0]]))
    np.testing.assert_allclose(c, [6.5 / 3.0, 2.0], atol=1e-15)
    np.testing.assert_allclose(np.abs(d), [1.0, 0.0], atol=1e-15)


def test_fit_line_is_total_least_squares():
    # Points (±1, ±0.1) on a rectangle: principal axis x, residuals 0.1 each.
    pts = np.array([[-1.0, 0.1], [1.0, 0.1], [1.0, -0.1], [-1.0, -0.1]])
    c, d = fit_line(pts)
    np.testing.assert_allclose(c, [0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(np.abs(d), [1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(line_residuals(pts, c, d), 0.1, atol=1e-15)


# --- noise ------------------------------------------------------------------------------------


def noisy_room_scan(seed: int) -> Scan:
    scan = scan_of(ROOM, CORNER_POSE)
    rng = np.random.default_rng(seed)
    ranges = scan.ranges_m + rng.normal(0.0, 0.012, scan.ranges_m.shape)  # σ = 1.2 cm
    return Scan(0.0, scan.angles_rad, ranges, scan.range_max_m)


def test_noisy_room_segment_ends_within_a_few_cm():
    for seed in range(20):
        world = transform_segments(extract_segments(noisy_room_scan(seed)), CORNER_POSE)
        assert 4 <= world.shape[0] <= 5
        ends = world.reshape(-1, 2)
        # Every end within 3 cm of a wall line, and within the room (+3 cm).
        dist = np.min(np.abs(np.abs(ends) - 4.0), axis=1)
        assert dist.max() < 0.03, f"seed {seed}: an end {dist.max():.3f} m off the walls"
        assert np.abs(ends).max() < 4.03
        # Each wall is covered along its length to within 20 cm of both corners (a noisy
        # corner can be cut off by a short chord within the 5 cm split tolerance).
        for name, (axis, value) in WALL_LINES.items():
            on = world[np.all(np.abs(world[:, [axis, axis + 2]] - value) < 0.03, axis=1)]
            assert on.shape[0] >= 1, f"seed {seed}: nothing on wall {name}"
            span = along(on.reshape(-1, 2), name)
            assert span.min() < -3.8
            assert span.max() > 3.8


def test_noisy_room_gives_one_segment_per_wall():
    # σ = 1.2 cm is the paper's scanner; the split tolerance is 5 cm (> 4σ). Yet at a
    # corner the split point is shared by both pieces, so a piece of one wall carries the
    # first reading of the next wall; that reading, a few cm off the line, blocks the merge
    # and tilts the refit.
    split = []
    for seed in range(20):
        segs = extract_segments(noisy_room_scan(seed))
        if segs.shape[0] != 4:
            split.append((seed, segs.shape[0]))
    assert not split, (
        f"(seed, segments) {split}: a wall came out in two pieces, one of them holding the "
        "neighbouring wall's corner reading. The split point shared by two pieces should "
        "not take part in the merge test and the refit of the piece it does not fit"
    )


# --- the compiled extraction against its numpy formulation ------------------------------------
#
# The extraction as it was written in numpy before it was compiled, kept as the reference
# the kernels must reproduce. numpy may take arctan2 and hypot from a vectorised library
# (where AVX-512 is present) that rounds a few results the other way than the C library the
# kernels call, so the two agree to round-off; given the same functions they agree to the
# bit.

_reference_arctan2 = np.arctan2
_reference_hypot = np.hypot


def _numpy_breakpoints(ranges_m, angles_rad, params):
    r = np.asarray(ranges_m, dtype=float)
    dphi = np.abs(np.diff(np.asarray(angles_rad, dtype=float)))
    lam = np.deg2rad(params.breakpoint_lambda_deg)
    with np.errstate(invalid="ignore", divide="ignore"):
        d_max = (
            r[:-1] * np.sin(dphi) / np.sin(np.maximum(lam - dphi, 1e-9)) + 3 * params.range_sigma_m
        )
    x = r * np.cos(angles_rad)
    y = r * np.sin(angles_rad)
    gap = _reference_hypot(np.diff(x), np.diff(y))
    return (gap > d_max) | (dphi >= lam)


def _numpy_fit_line(points):
    centroid = points.mean(axis=0)
    d = points - centroid
    sxx, syy, sxy = (d[:, 0] ** 2).sum(), (d[:, 1] ** 2).sum(), (d[:, 0] * d[:, 1]).sum()
    phi = 0.5 * _reference_arctan2(2.0 * sxy, sxx - syy)
    return centroid, np.array([np.cos(phi), np.sin(phi)])


def _numpy_line_residuals(points, centroid, direction):
    d = points - centroid
    return np.abs(d[:, 0] * direction[1] - d[:, 1] * direction[0])


def _along(offsets, direction):
    """Offsets (..., 2) projected on ``direction``, by products and one sum each, as the
    kernels do (a matrix product may fuse them)."""
    return offsets[..., 0] * direction[0] + offsets[..., 1] * direction[1]


def _numpy_direction_sigma_rad(points, centroid, direction, range_sigma_m):
    t = _along(points - centroid, direction)
    spread = float(np.sqrt(np.sum(t**2)))
    if spread == 0.0:
        return np.inf
    residuals = _numpy_line_residuals(points, centroid, direction)
    rms = float(np.sqrt(np.sum(residuals**2) / max(points.shape[0] - 2, 1)))
    return max(range_sigma_m, rms) / spread


def _numpy_split(points, start, stop, tol_m, out):
    stack = [(start, stop)]
    while stack:
        i0, i1 = stack.pop()
        if i1 - i0 <= 2:
            out.append((i0, i1))
            continue
        a, b = points[i0], points[i1 - 1]
        chord = b - a
        norm = _reference_hypot(*chord)
        seg = points[i0:i1] - a
        if norm < 1e-12:
            dist = _reference_hypot(seg[:, 0], seg[:, 1])
        else:
            dist = np.abs(seg[:, 0] * chord[1] - seg[:, 1] * chord[0]) / norm
        k = int(np.argmax(dist))
        if dist[k] > tol_m and 0 < k < i1 - i0 - 1:
            stack.append((i0 + k, i1))
            stack.append((i0, i0 + k + 1))
        else:
            out.append((i0, i1))


def _numpy_merge(points, ranges, tol_m):
    merged = []
    for r in ranges:
        if (
            merged
            and merged[-1][1] >= r[0]
            and _numpy_fits_one_line(points, merged[-1][0], r[1], tol_m)
        ):
            merged[-1] = (merged[-1][0], r[1])
            continue
        merged.append(r)
    return merged


def _numpy_fits_one_line(points, start, stop, tol_m):
    pts = points[start + 1 : stop - 1] if stop - start > 4 else points[start:stop]
    return bool(_numpy_line_residuals(pts, *_numpy_fit_line(pts)).max() <= tol_m)


def _numpy_fit_piece(pts):
    if pts.shape[0] > 4:
        interior = pts[1:-1]
        centroid, direction = _numpy_fit_line(interior)
        rms = np.sqrt(np.mean(_numpy_line_residuals(interior, centroid, direction) ** 2))
        ends = _numpy_line_residuals(pts[[0, -1]], centroid, direction)
        keep = np.ones(pts.shape[0], dtype=bool)
        keep[[0, -1]] = ends <= max(3.0 * rms, 1e-6)
        pts = pts[keep]
    centroid, direction = _numpy_fit_line(pts)
    return centroid, direction, pts


def _numpy_chains(points_count, breaks, wraps):
    cut = np.flatnonzero(breaks) + 1
    bounds = np.concatenate([[0], cut, [points_count]])
    runs = [(int(a), int(b)) for a, b in pairwise(bounds) if b > a]
    if wraps and len(runs) > 1:
        first, last = runs[0], runs[-1]
        runs = [(last[0], first[1] + points_count), *runs[1:-1]]
    return runs


def _numpy_extract_segments(scan, params=None):
    params = params or ExtractParams()
    all_angles = np.asarray(scan.angles_rad, dtype=float)
    valid = scan.valid & np.isfinite(all_angles)
    ranges = np.asarray(scan.ranges_m, dtype=float)[valid]
    angles = all_angles[valid]
    if ranges.size < params.min_points:
        return np.zeros((0, 4))
    points = np.column_stack([ranges * np.cos(angles), ranges * np.sin(angles)])
    breaks = _numpy_breakpoints(ranges, angles, params)
    step = np.median(np.abs(np.diff(angles))) if angles.size > 1 else 0.0
    span = (angles[-1] - angles[0]) % (2 * np.pi)
    closing_gap = 2 * np.pi - span
    wraps = bool(step > 0 and closing_gap <= 1.5 * step)
    if wraps:
        wrap_ranges = np.array([ranges[-1], ranges[0]])
        wrap_angles = np.array([angles[-1], angles[-1] + closing_gap])
        wraps = not bool(_numpy_breakpoints(wrap_ranges, wrap_angles, params)[0])
    n = points.shape[0]
    ring = np.concatenate([points, points]) if wraps else points
    tol = max(params.split_m, 3.0 * params.range_sigma_m)
    max_sigma_rad = np.deg2rad(params.max_direction_sigma_deg)
    segments = []
    for start, stop in _numpy_chains(n, breaks, wraps):
        if stop - start < params.min_points:
            continue
        pieces = []
        _numpy_split(ring, start, stop, tol, pieces)
        pieces = _numpy_merge(ring, pieces, tol)
        closed = wraps and stop - start == n
        if (
            closed
            and len(pieces) > 1
            and _numpy_fits_one_line(ring, pieces[-1][0], pieces[0][1] + n, tol)
        ):
            pieces = [(pieces[-1][0], pieces[0][1] + n), *pieces[1:-1]]
        for i0, i1 in pieces:
            if i1 - i0 < params.min_points:
                continue
            centroid, direction, pts = _numpy_fit_piece(ring[i0:i1])
            t0 = _along(pts[0] - centroid, direction)
            t1 = _along(pts[-1] - centroid, direction)
            if (
                pts.shape[0] < params.min_points
                or abs(t1 - t0) < params.min_length_m
                or _numpy_direction_sigma_rad(pts, centroid, direction, params.range_sigma_m)
                > max_sigma_rad
            ):
                continue
            segments.append(np.concatenate([centroid + t0 * direction, centroid + t1 * direction]))
    return np.array(segments).reshape(-1, 4)


COMPARED_PARAMS = {
    "default": ExtractParams(),
    "keep-everything": ExtractParams(min_points=2, min_length_m=0.0, max_direction_sigma_deg=180.0),
    "coarse": ExtractParams(split_m=0.2, breakpoint_lambda_deg=30.0, min_points=6),
}


def simulated_scans(seed: int) -> list[Scan]:
    """Noisy (the default scanner's 1.2 cm, dropouts, glass, clutter) and noise-free 360°
    scans of a random world at each scanner resolution, and a fan cut from each."""
    rng = np.random.default_rng(seed)
    world = random_world(rng, (rng.uniform(6.0, 20.0), rng.uniform(5.0, 14.0)))
    scans = []
    for readings, pose in zip(
        (128, 256, 1024, 2048), random_free_poses(world, 4, rng), strict=True
    ):
        for model in (SensorModel(), NOISE_FREE):
            sensor = dataclasses.replace(model, readings=readings)
            scan = simulate_scan(world, Pose2(*pose), sensor, rng, 0.0)
            scans.append(scan)
            first = int(rng.integers(0, readings // 2))
            last = first + int(rng.integers(readings // 8, readings // 2))
            fan = slice(first, last)
            scans.append(Scan(0.0, scan.angles_rad[fan], scan.ranges_m[fan], scan.range_max_m))
    return scans


def holed(scan: Scan, first: int, last: int) -> Scan:
    """``scan`` with no return from beams first … last − 1."""
    ranges = scan.ranges_m.copy()
    ranges[first:last] = np.inf
    return Scan(0.0, scan.angles_rad, ranges, scan.range_max_m)


def hand_made_scans() -> dict[str, Scan]:
    """The scenes of the tests above, and rings with one breakpoint (a hole in a wall)."""
    midwall = scan_of(ROOM, MIDWALL_POSE)
    n = len(midwall)
    wall_x2 = np.deg2rad([-6.0, -2.0, 2.0, 6.0])
    far = np.deg2rad(np.arange(-2.0, 2.5, 1.0))
    scans = {
        f"room-corner-{readings}": scan_of(ROOM, CORNER_POSE, readings)
        for readings in (256, 1024, 2048)
    }
    scans |= {
        "room-midwall": midwall,
        "room-and-box": scan_of(np.vstack([ROOM, BOX]), MIDWALL_POSE),
        "two-depths": scan_of(
            np.array([[0.5, 2.0, -1.0, 2.0], [-1.5, 4.0, -3.5, 4.0]]), Pose2(0.0, 0.0, 0.0)
        ),
        "doorway": scan_of(
            np.array([[2.0, 2.0, 0.3, 2.0], [-0.3, 2.0, -2.0, 2.0]]), Pose2(0.0, 0.0, 0.0)
        ),
        "four-beams": Scan(0.0, wall_x2, 2.0 / np.cos(wall_x2)),
        "sparse-far-wall": Scan(0.0, far, 5.0 / np.cos(far)),
        "rough-short": rough_wall_scan(4.0, 0.02),
        "rough-long": rough_wall_scan(40.0, 0.02),
        "noisy-room": noisy_room_scan(0),
        # A ring with one breakpoint (a hole in a wall) is one run, from the breakpoint
        # round to it. With the hole just before beam 0, the run's first piece crosses
        # beam 0 and the range that rejoins its last and first pieces runs past the end of
        # the points' second copy.
        "hole-before-seam": holed(midwall, n - 60, n - 20),
        "hole-after-seam": holed(midwall, 20, 60),
        "hole-in-side-wall": holed(midwall, 300, 350),
    }
    return scans


def assert_same_segments(compiled: np.ndarray, reference: np.ndarray, what: str) -> None:
    assert compiled.shape == reference.shape, f"{what}: {compiled.shape} vs {reference.shape}"
    np.testing.assert_allclose(compiled, reference, rtol=0.0, atol=1e-9, err_msg=what)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("params_name", COMPARED_PARAMS)
def test_compiled_extraction_equals_numpy_on_simulated_scans(seed, params_name):
    params = COMPARED_PARAMS[params_name]
    for i, scan in enumerate(simulated_scans(seed)):
        assert_same_segments(
            extract_segments(scan, params), _numpy_extract_segments(scan, params), f"scan {i}"
        )


@pytest.mark.parametrize("params_name", COMPARED_PARAMS)
def test_compiled_extraction_equals_numpy_on_hand_made_scenes(params_name):
    params = COMPARED_PARAMS[params_name]
    for name, scan in hand_made_scans().items():
        assert_same_segments(
            extract_segments(scan, params), _numpy_extract_segments(scan, params), name
        )


def test_with_the_same_arctan2_the_compiled_extraction_is_equal_to_the_bit(monkeypatch):
    # The C library's arctan2 and hypot, as the kernels call them: every sum, product and
    # branch is then the same, so the segments are too, to the last bit.
    monkeypatch.setitem(globals(), "_reference_arctan2", math.atan2)
    monkeypatch.setitem(globals(), "_reference_hypot", np.vectorize(math.hypot, otypes=[float]))
    scans = [*hand_made_scans().values(), *simulated_scans(0), *simulated_scans(1)]
    for params in COMPARED_PARAMS.values():
        for i, scan in enumerate(scans):
            compiled = extract_segments(scan, params)
            reference = _numpy_extract_segments(scan, params)
            assert compiled.shape == reference.shape, f"scan {i}"
            assert np.array_equal(compiled, reference), f"scan {i}"


def test_public_helpers_equal_their_numpy_formulation():
    params = ExtractParams()
    for scan in [*hand_made_scans().values(), *simulated_scans(2)]:
        r, a = scan.ranges_m[scan.valid], scan.angles_rad[scan.valid]
        assert np.array_equal(breakpoints(r, a, params), _numpy_breakpoints(r, a, params))
        points = scan.points()
        if points.shape[0] < 2:
            continue
        centroid, direction = fit_line(points)
        ref_centroid, ref_direction = _numpy_fit_line(points)
        np.testing.assert_allclose(centroid, ref_centroid, rtol=0.0, atol=1e-12)
        np.testing.assert_allclose(direction, ref_direction, rtol=0.0, atol=1e-12)
        np.testing.assert_array_equal(
            line_residuals(points, ref_centroid, ref_direction),
            _numpy_line_residuals(points, ref_centroid, ref_direction),
        )
        assert direction_sigma_rad(points, ref_centroid, ref_direction, 0.012) == pytest.approx(
            _numpy_direction_sigma_rad(points, ref_centroid, ref_direction, 0.012), rel=1e-12
        )


@pytest.mark.parametrize("size", [*range(20), 127, 128, 129, 136, 255, 256, 257, 1000, 4099])
def test_sums_are_added_in_numpy_order(size):
    # The fits equal numpy's to the bit only if their sums do: numpy adds pairwise.
    values = np.random.default_rng(size).normal(0.0, 3.0, size)
    assert _numpy_sum(values.copy(), size) == np.sum(values)


def test_a_mounted_scan_gives_its_segments_and_points_on_the_robot():
    """Segments are found in the scanner's frame and placed on the robot by the mounting:
    the unmounted scan's, moved by it; and likewise its points."""
    rng = np.random.default_rng(5)
    world = random_world(rng)
    pose = Pose2(*random_free_poses(world, 1, rng)[0])
    scan = simulate_scan(world, pose, SensorModel(), rng, 0.0)
    mount = Pose2(0.22, -0.04, math.radians(-25.0))
    mounted = dataclasses.replace(scan, mount=mount)

    alone = extract_segments(scan)
    assert alone.shape[0] >= 4
    np.testing.assert_allclose(
        extract_segments(mounted), transform_segments(alone, mount), rtol=0, atol=1e-12
    )
    np.testing.assert_allclose(
        mounted.points(), transform_points(scan.points(), mount), rtol=0, atol=1e-12
    )
