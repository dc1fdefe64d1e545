"""Synthetic scans and worlds: the paper's range sensor rendered on a ``World``.

The default sensor model follows the Schwartz Electro-Optics Explorer used by
Reina & Gonzalez (2000): a 360° scan of 1024 readings per revolution (it offers
128/256/1024/2048) with Gaussian range noise of about 1.2 cm. Any other fan can be
chosen (a SICK LMS's 181 or 361 beams over 180°). On top of the ideal ray cast
the model adds the things a real log holds: range quantisation, readings lost to
dropouts, glass that mostly lets the beam through, and short spurious returns from
people walking past.

Frames: beam angles are in the robot frame (x forward, counter-clockwise);
rays are cast in the world frame at ``pose.theta + angle``. Units are metres
and radians; ``noise_cm`` and ``*_deg`` names are the only exceptions.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from segloc_cli.geometry import (
    TWO_PI,
    Pose2,
    as_segments,
    chained_motions,
    point_segment_distances,
    relative_motion,
    rotation,
    wrap_angle,
)
from segloc_cli.scan import MAX_RANGE_M, MAX_READINGS, Scan, evenly_spaced_angles
from segloc_cli.world import World

EXPLORER_READINGS = (128, 256, 1024, 2048)
"""Readings per revolution the Explorer offers."""

FULL_CIRCLE_DEG = 360.0
"""The widest field of view: a full turn, whose beams start straight ahead (``beam_angles``)."""

MAX_NOISE_CM = 100
"""Largest range noise σ (cm) a simulated scanner takes, however it is chosen (option or
world file): at a metre the scans hold no room a map could be matched to."""


# Initial errors of the paper's Table 1 (Reina & Gonzalez 2000), "surveyed minus
# initial guess", one row per logged pose: x cm, y cm, heading degrees.
PAPER_TABLE1_INITIAL_ERRORS = np.array(
    [
        [182.2, 36.0, -9.75],
        [-63.7, 49.5, -15.6],
        [-91.2, 168.5, 7.82],
        [33.2, -131.8, -17.3],
        [-10.9, -14.7, -19.9],
        [47.2, -168.2, 14.1],
        [16.2, 38.7, -6.71],
        [74.4, -75.1, 16.4],
        [-56.3, 18.1, 3.7],
        [-46.5, -133.6, 0.5],
    ]
)

# Rays leaving closer than this are treated as starting on the segment, not hitting it.
_MIN_HIT_M = 1e-9
# Accept hits a hair past the endpoints so beams through a shared vertex are not lost.
_ENDPOINT_SLACK = 1e-12


@dataclass(frozen=True)
class SensorModel:
    """Parameters of the simulated range scanner.

    ``readings`` beams per scan (2 to ``MAX_READINGS``) spread over ``fov_deg``
    degrees (above 0, at most 360; see ``beam_angles``); ``noise_cm`` Gaussian
    range noise σ in centimetres; ``resolution_m`` the range quantum (0 disables
    rounding); ``range_max_m`` the largest range returned; ``dropout_prob`` the
    chance a reading is lost; ``glass_return_prob`` the chance a beam reaching a
    glass segment returns from it rather than passing through (1: glass is
    opaque); ``clutter_clusters`` the Poisson mean number of clusters of spurious
    short returns per scan (0: none). The defaults are the Explorer's.
    """

    readings: int = 1024
    noise_cm: float = 1.2
    resolution_m: float = 0.001
    range_max_m: float = 30.0
    dropout_prob: float = 0.005
    glass_return_prob: float = 0.1
    clutter_clusters: float = 1.5
    fov_deg: float = FULL_CIRCLE_DEG

    def __post_init__(self) -> None:
        if isinstance(self.readings, bool) or not 2 <= self.readings <= MAX_READINGS:
            raise ValueError(f"readings must be 2 to {MAX_READINGS}, got {self.readings}")
        if not 0.0 < self.fov_deg <= FULL_CIRCLE_DEG:
            raise ValueError(f"fov_deg must be above 0 and at most 360, got {self.fov_deg}")
        if not 0.0 <= self.noise_cm <= MAX_NOISE_CM:
            raise ValueError(f"noise_cm must be 0 to {MAX_NOISE_CM:g}, got {self.noise_cm}")
        if not self.resolution_m >= 0.0:
            raise ValueError(f"resolution_m must be >= 0, got {self.resolution_m}")
        if not self.range_max_m > 0.0:
            raise ValueError(f"range_max_m must be > 0, got {self.range_max_m}")
        for name in ("dropout_prob", "glass_return_prob"):
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {p}")
        if not self.clutter_clusters >= 0.0:
            raise ValueError(f"clutter_clusters must be >= 0, got {self.clutter_clusters}")

    @property
    def is_explorer(self) -> bool:
        """Whether this is a fan the Explorer scans: a full turn of a readings count it offers."""
        return self.fov_deg == FULL_CIRCLE_DEG and self.readings in EXPLORER_READINGS

    @property
    def choices(self) -> dict[str, Any]:
        """This model as ``SENSOR_CHOICES`` name it: clutter on while there is any, glass on
        while it lets beams through (``sensor_model`` of them makes a model like this one)."""
        return {
            "readings": int(self.readings),
            "fov_deg": float(self.fov_deg),
            "noise_cm": float(self.noise_cm),
            "clutter": self.clutter_clusters > 0.0,
            "glass": self.glass_return_prob < 1.0,
        }


SENSOR_CHOICES: dict[str, type] = {
    "readings": int,
    "fov_deg": float,
    "noise_cm": float,
    "clutter": bool,
    "glass": bool,
}
"""What a user chooses of the simulated scanner (``simulate``'s options, a world file's
``sensor``), by name, with the type of its value; ``sensor_model`` makes the model of them.
``clutter`` False means no spurious returns; ``glass`` False makes glass opaque."""

_SWITCHED_OFF = {"clutter": ("clutter_clusters", 0.0), "glass": ("glass_return_prob", 1.0)}
"""The field each switch of ``SENSOR_CHOICES`` sets when off, and the value it sets."""


def sensor_model(chosen: Mapping[str, Any]) -> SensorModel:
    """The ``SensorModel`` of ``chosen`` (keys of ``SENSOR_CHOICES``; any left out, and a
    switch that is on, keep the Explorer's defaults). ``ValueError`` says which value is
    out of range; a key that is no choice is a ``KeyError``."""
    unknown = set(chosen) - set(SENSOR_CHOICES)
    if unknown:
        raise KeyError(f"no sensor choice {sorted(unknown)}")
    fields = {k: v for k, v in chosen.items() if k not in _SWITCHED_OFF}
    for key, (name, off) in _SWITCHED_OFF.items():
        if chosen.get(key) is False:
            fields[name] = off
    return SensorModel(**fields)


NOISE_FREE = SensorModel(
    noise_cm=0.0, resolution_m=0.0, dropout_prob=0.0, glass_return_prob=0.0, clutter_clusters=0.0
)
"""Exact ranges: no noise, quantisation, dropouts, glass returns or clutter."""


def beam_angles(readings: int, fov_deg: float = FULL_CIRCLE_DEG) -> np.ndarray:
    """Beam angles (readings,) in radians, robot frame, counter-clockwise.

    A full turn (``fov_deg`` 360) starts straight ahead: ``2π·i/readings``, i = 0 ..
    readings−1, the last beam one step short of the first. A narrower fan is centred
    straight ahead with its first and last beams on its edges, ``−fov/2`` to ``+fov/2``
    in steps of ``fov/(readings−1)``, as a SICK LMS or a Hokuyo scans.
    """
    if readings < 1:
        raise ValueError(f"readings must be >= 1, got {readings}")
    if fov_deg == FULL_CIRCLE_DEG:
        return TWO_PI * np.arange(readings) / readings
    half_rad = float(np.deg2rad(fov_deg)) / 2.0
    return evenly_spaced_angles(readings, -half_rad, half_rad)


def cast_rays(
    segments_world: np.ndarray,
    origin_xy: ArrayLike,
    angles_world_rad: np.ndarray,
    transparent: np.ndarray | None = None,
) -> np.ndarray:
    """Distance along each ray to the nearest segment it hits.

    ``segments_world`` (M, 4) metres; ``origin_xy`` (2,) the common ray origin,
    world frame; ``angles_world_rad`` (N,) ray directions in the world frame.
    ``transparent`` is an optional (N, M) bool mask: beam i passes through
    segment j where it is True. Returns ranges (N,) in metres, ``inf`` where a
    ray hits nothing. Rays parallel to a segment do not hit it. Rays are cast
    ``_RAY_BLOCK_PAIRS`` ray-segment pairs at a time, so that a building's plan of
    thousands of segments takes megabytes, not gigabytes.
    """
    segments = as_segments(segments_world)
    angles = np.asarray(angles_world_rad, dtype=float).reshape(-1)
    origin = np.asarray(origin_xy, dtype=float).reshape(2)
    mask = None if transparent is None else np.asarray(transparent, dtype=bool)
    if mask is not None and mask.shape != (angles.shape[0], segments.shape[0]):
        raise ValueError(
            f"transparent must have shape {(angles.shape[0], segments.shape[0])}, got {mask.shape}"
        )
    if segments.shape[0] == 0:
        return np.full(angles.shape, np.inf)
    block = max(1, _RAY_BLOCK_PAIRS // segments.shape[0])
    ranges = np.empty(angles.shape)
    for start in range(0, angles.shape[0], block):
        rows = slice(start, start + block)
        ranges[rows] = _cast_block(
            segments, origin, angles[rows], None if mask is None else mask[rows]
        )
    return ranges


_RAY_BLOCK_PAIRS = 1 << 20
"""Ray-segment pairs cast at once: each of ``_cast_block``'s arrays takes 8 MB."""


def _cast_block(
    segments: np.ndarray, origin: np.ndarray, angles: np.ndarray, transparent: np.ndarray | None
) -> np.ndarray:
    """``cast_rays`` of the rays ``angles`` (N,) against ``segments`` (M, 4), all at once."""
    ox, oy = origin
    dx = np.cos(angles)[:, None]  # (N, 1)
    dy = np.sin(angles)[:, None]
    ex = (segments[:, 2] - segments[:, 0])[None, :]  # (1, M)
    ey = (segments[:, 3] - segments[:, 1])[None, :]
    wx = (segments[:, 0] - ox)[None, :]
    wy = (segments[:, 1] - oy)[None, :]

    # origin + t·d = p1 + u·e  ⇒  t = (w × e)/(d × e),  u = (w × d)/(d × e)
    denom = dx * ey - dy * ex  # (N, M)
    parallel = denom == 0.0
    safe = np.where(parallel, 1.0, denom)
    t = (wx * ey - wy * ex) / safe
    u = (wx * dy - wy * dx) / safe
    hit = ~parallel & (t > _MIN_HIT_M) & (u >= -_ENDPOINT_SLACK) & (u <= 1.0 + _ENDPOINT_SLACK)
    if transparent is not None:
        hit &= ~transparent
    return np.where(hit, t, np.inf).min(axis=1)


def _clutter_ranges(
    angles_rad: np.ndarray, mean_clusters: float, rng: np.random.Generator
) -> np.ndarray:
    """Ranges (N,) of spurious returns along the evenly spaced beams ``angles_rad`` (N,),
    ``inf`` where a beam sees no clutter.

    Each cluster is an object 0.3–0.6 m across at 0.8–5 m (a person walking by),
    covering the consecutive beams that its width subtends; on a full turn it may
    cover the last beams and the first, on a narrower fan it ends at the fan's edge.
    """
    n_beams = angles_rad.shape[0]
    clutter = np.full(n_beams, np.inf)
    step_rad = abs(float(angles_rad[1] - angles_rad[0])) if n_beams > 1 else TWO_PI
    full_turn = n_beams * step_rad >= TWO_PI * (1.0 - 1e-9)
    for _ in range(int(rng.poisson(mean_clusters))):
        range_m = rng.uniform(0.8, 5.0)
        width_m = rng.uniform(0.3, 0.6)
        count = min(n_beams, max(1, round(width_m / range_m / step_rad)))
        first = int(rng.integers(n_beams))
        beams = first + np.arange(count)
        beams = beams % n_beams if full_turn else beams[beams < n_beams]
        clutter[beams] = np.minimum(clutter[beams], range_m)
    return clutter


def simulate_scan(
    world: World,
    pose: Pose2,
    sensor: SensorModel,
    rng: np.random.Generator,
    time_s: float,
) -> Scan:
    """One scan of ``world`` taken by a scanner at ``pose`` (world frame).

    The scan holds ``sensor.readings`` beams over ``sensor.fov_deg`` at
    ``beam_angles`` (robot frame) and ranges in metres, with invalid readings (no
    return within ``range_max_m``, dropouts) written as 0.0. The result depends
    only on the arguments and the state of ``rng``.
    """
    angles_rad = beam_angles(sensor.readings, sensor.fov_deg)
    return Scan(
        time_s=float(time_s),
        angles_rad=angles_rad,
        ranges_m=render_ranges(world, pose, angles_rad, sensor, rng),
        range_max_m=float(sensor.range_max_m),
    )


def render_ranges(
    world: World,
    pose: Pose2,
    angles_rad: np.ndarray,
    sensor: SensorModel,
    rng: np.random.Generator,
) -> np.ndarray:
    """Ranges (N,) in metres that ``sensor`` at ``pose`` reads along beams ``angles_rad``.

    Beam angles are in the robot frame, evenly spaced, and may be any fan (a 360°
    Explorer revolution, a Hokuyo's 240°); ``sensor.readings`` and ``fov_deg`` are
    not used. Noise, quantisation, dropouts, glass and clutter as in
    ``simulate_scan``; 0.0 marks an invalid reading.
    """
    segments = as_segments(world.segments, "world segments")
    materials = np.asarray(world.materials).reshape(-1)
    if materials.shape[0] != segments.shape[0]:
        raise ValueError(
            f"world {world.name!r}: {segments.shape[0]} segments but {materials.shape[0]} materials"
        )
    angles_rad = np.asarray(angles_rad, dtype=float).reshape(-1)
    n = angles_rad.shape[0]

    glass = materials == "glass"
    passes = rng.random((n, int(glass.sum()))) >= sensor.glass_return_prob
    transparent = None  # a plan of walls alone needs no (beams × segments) mask
    if glass.any():
        transparent = np.zeros((n, segments.shape[0]), dtype=bool)
        transparent[:, glass] = passes
    true_m = cast_rays(segments, (pose.x, pose.y), pose.theta + angles_rad, transparent)

    ranges_m = np.minimum(true_m, _clutter_ranges(angles_rad, sensor.clutter_clusters, rng))
    ranges_m = ranges_m + rng.normal(0.0, sensor.noise_cm / 100.0, n)
    if sensor.resolution_m > 0.0:
        ranges_m = np.round(ranges_m / sensor.resolution_m) * sensor.resolution_m
    lost = rng.random(n) < sensor.dropout_prob

    invalid = ~np.isfinite(ranges_m) | (ranges_m <= 0.0) | (ranges_m >= sensor.range_max_m) | lost
    ranges_m[invalid] = 0.0
    return ranges_m


# --- initial guesses -------------------------------------------------------------------------


def paper_initial_errors(n: int) -> np.ndarray:
    """The initial errors of the paper's Table 1, (n, 3): dx m, dy m, dtheta rad.

    Errors are "surveyed minus initial guess"; row k is Table 1 row k mod 10.
    """
    rows = PAPER_TABLE1_INITIAL_ERRORS[np.arange(n) % len(PAPER_TABLE1_INITIAL_ERRORS)]
    return np.column_stack([rows[:, 0] / 100.0, rows[:, 1] / 100.0, np.deg2rad(rows[:, 2])])


def uniform_initial_errors(
    n: int, xy_m: float, theta_deg: float, rng: np.random.Generator
) -> np.ndarray:
    """Initial errors (n, 3), dx, dy uniform in ±``xy_m`` metres, dtheta in ±``theta_deg`` (rad)."""
    xy = rng.uniform(-xy_m, xy_m, size=(n, 2))
    theta = rng.uniform(-np.deg2rad(theta_deg), np.deg2rad(theta_deg), size=n)
    return np.column_stack([xy, theta])


def parse_init_errors(value: str) -> tuple[str, float, float]:
    """Initial-error text → ("paper", 0, 0) or ("uniform", XY_M, THETA_DEG): 'paper' (the
    paper's Table 1) or 'uniform:XY_M,THETA_DEG' (uniform in ±XY_M per axis and ±THETA_DEG).
    Raises ValueError with a message that says what is accepted."""
    if value == "paper":
        return ("paper", 0.0, 0.0)
    if value.startswith("uniform:"):
        try:
            xy, theta = (float(v) for v in value[len("uniform:") :].split(","))
        except ValueError:
            pass
        else:
            if 0 <= xy <= MAX_RANGE_M and 0 <= theta <= 180:
                return ("uniform", xy, theta)
    raise ValueError(
        f"{value!r}; use 'paper' or 'uniform:XY_M,THETA_DEG' with XY_M in 0..{MAX_RANGE_M:g} "
        "and THETA_DEG in 0..180 (e.g. uniform:1.5,20)"
    )


def initial_errors(
    n: int, init_errors: tuple[str, float, float], rng: np.random.Generator
) -> np.ndarray:
    """Initial errors (n, 3: dx m, dy m, dtheta rad) of ``parse_init_errors``'s result: the
    paper's (``rng`` unused) or uniform draws from ``rng``."""
    mode, xy_m, theta_deg = init_errors
    if mode == "paper":
        return paper_initial_errors(n)
    return uniform_initial_errors(n, xy_m, theta_deg, rng)


def initial_guesses(true_poses: np.ndarray, errors: np.ndarray) -> np.ndarray:
    """Initial guesses (n, 3) = true − error, heading wrapped to [−π, π).

    ``true_poses`` and ``errors`` are (n, 3) arrays of x m, y m, theta rad, so
    that "surveyed minus guess" equals ``errors``.
    """
    true_poses = np.asarray(true_poses, dtype=float).reshape(-1, 3)
    errors = np.asarray(errors, dtype=float).reshape(-1, 3)
    guesses = true_poses - errors
    guesses[:, 2] = wrap_angle(guesses[:, 2])
    return guesses


@dataclass(frozen=True)
class OdometryDrift:
    """How far simulated wheel odometry strays on each step between two scans: its motion
    is off by a uniform draw within ±``distance_pct`` % of the step's length along each
    axis, and its turn by ±(``turn_pct`` % of the turn + ``deg_per_m`` degrees per metre of
    the step). The defaults are those of a differential-drive base never calibrated."""

    distance_pct: float = 2.0
    turn_pct: float = 2.0
    deg_per_m: float = 0.5

    @property
    def text(self) -> str:
        """The ``--odometry`` value that gives this drift (``parse_odometry``)."""
        return f"drift:{self.distance_pct:g},{self.turn_pct:g},{self.deg_per_m:g}"


_DRIFT_LIMITS = (100.0, 100.0, 45.0)


def parse_odometry(value: str) -> OdometryDrift:
    """``--odometry`` text → its drift: 'drift' (the defaults) or
    'drift:DISTANCE_PCT,TURN_PCT,DEG_PER_M'. Raises ValueError saying what is accepted."""
    if value == "drift":
        return OdometryDrift()
    if value.startswith("drift:"):
        try:
            numbers = [float(v) for v in value[len("drift:") :].split(",")]
        except ValueError:
            numbers = []
        if len(numbers) == 3 and all(
            0 <= n <= limit for n, limit in zip(numbers, _DRIFT_LIMITS, strict=True)
        ):
            return OdometryDrift(*numbers)
    default = OdometryDrift().text
    raise ValueError(
        f"{value!r}; use 'drift' ({default}) or 'drift:DISTANCE_PCT,TURN_PCT,DEG_PER_M' with "
        "the percentages in 0..100 and DEG_PER_M in 0..45"
    )


def drifting_odometry(
    true_poses: np.ndarray, drift: OdometryDrift, rng: np.random.Generator
) -> np.ndarray:
    """Wheel odometry (n, 3: x m, y m, theta rad) of a robot at ``true_poses`` (n, 3, world
    frame), in its own frame: the first pose at the origin, each step the true motion with
    ``drift``'s error added, so the error grows with the distance and the turns travelled.

    Draws 3 numbers per pose from ``rng`` (the first pose's go unused), as
    ``uniform_initial_errors`` does: a seed's scans are the same whichever of the two a log
    holds on /odom."""
    n = len(true_poses)
    unit_xy = rng.uniform(-1.0, 1.0, size=(n, 2))[1:]
    unit_turn = rng.uniform(-1.0, 1.0, size=n)[1:]
    motions = relative_motion(true_poses[:-1], true_poses[1:])
    length = np.hypot(motions[:, 0], motions[:, 1])
    motions[:, :2] += unit_xy * (drift.distance_pct / 100.0) * length[:, None]
    turn_bound = (
        drift.turn_pct / 100.0 * np.abs(motions[:, 2]) + np.deg2rad(drift.deg_per_m) * length
    )
    motions[:, 2] += unit_turn * turn_bound
    return chained_motions(np.zeros(3), motions)


# --- procedural worlds -----------------------------------------------------------------------


def _polygon_segments(vertices: np.ndarray) -> np.ndarray:
    """Closed polygon (K, 2) → its K edges (K, 4), consecutive edges sharing endpoints."""
    vertices = np.asarray(vertices, dtype=float)
    return np.hstack([vertices, np.roll(vertices, -1, axis=0)])


def _box(center_xy: np.ndarray, size_xy: tuple[float, float], theta_rad: float) -> np.ndarray:
    """Edges (4, 4) of a rectangle of ``size_xy`` metres centred at ``center_xy``, rotated."""
    hx, hy = size_xy[0] / 2.0, size_xy[1] / 2.0
    corners = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
    return _polygon_segments(corners @ rotation(theta_rad).T + center_xy)


def _closed_loop_mask(segments: np.ndarray) -> np.ndarray:
    """Mask (M,) of segments that belong to closed chains (walls of rooms, boxes, columns).

    Chains are found by exactly shared endpoints; segments with a free end
    (wall stubs, railings) are peeled off repeatedly until none is left.
    """
    ends = np.round(segments.reshape(-1, 2), 9)
    _, vertex = np.unique(ends, axis=0, return_inverse=True)
    vertex = vertex.reshape(-1, 2)
    keep = vertex[:, 0] != vertex[:, 1]
    while True:
        degree = np.bincount(vertex[keep].ravel(), minlength=int(vertex.max()) + 1)
        dangling = keep & ((degree[vertex[:, 0]] < 2) | (degree[vertex[:, 1]] < 2))
        if not dangling.any():
            return keep
        keep &= ~dangling


def _inside_count(points: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Crossings (P,) of a ray towards +x from each point with the segments (even-odd rule)."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    px, py = points[:, 0:1], points[:, 1:2]
    x1, y1, x2, y2 = (segments[None, :, k] for k in range(4))
    straddles = (y1 > py) != (y2 > py)
    dy = np.where(straddles, y2 - y1, 1.0)
    x_cross = x1 + (py - y1) * (x2 - x1) / dy
    return np.sum(straddles & (x_cross > px), axis=1)


def free_space_mask(world: World, points_xy: np.ndarray, clearance_m: float) -> np.ndarray:
    """Mask (P,) of points (P, 2) in the world's open floor, ``clearance_m`` from every segment.

    A point is on the floor when it lies inside an odd number of the world's
    closed chains of segments: inside the outer walls, outside every box and
    column. Open segments (stubs, railings) only count for clearance.
    """
    return _free_mask(as_segments(world.segments, "world segments"), points_xy, clearance_m)


def _free_mask(segments: np.ndarray, points_xy: np.ndarray, clearance_m: float) -> np.ndarray:
    points = np.asarray(points_xy, dtype=float).reshape(-1, 2)
    if segments.shape[0] == 0:
        return np.zeros(points.shape[0], dtype=bool)
    loops = segments[_closed_loop_mask(segments)]
    inside = _inside_count(points, loops) % 2 == 1
    clear = point_segment_distances(points, segments).min(axis=1) >= clearance_m
    return inside & clear


def _outer_wall(rng: np.random.Generator, width_m: float, height_m: float) -> np.ndarray:
    """Vertices (K, 2), counter-clockwise, of an irregular room around [0, W] × [0, H].

    A rectangle with one or two corners cut at random slants and, on each side,
    up to two alcoves (outwards) or notches (inwards), some with slanted sides.
    """
    corners = np.array([[0.0, 0.0], [width_m, 0.0], [width_m, height_m], [0.0, height_m]])
    short = min(width_m, height_m)
    cut = np.zeros((4, 2))  # per corner: cut length along the incoming and the outgoing side
    for corner in rng.choice(4, size=int(rng.integers(1, 3)), replace=False):
        cut[corner] = rng.uniform(0.1, 0.25, size=2) * short

    vertices: list[np.ndarray] = []
    for side in range(4):
        start, end = corners[side], corners[(side + 1) % 4]
        length = float(np.hypot(*(end - start)))
        along = (end - start) / length
        outward = np.array([along[1], -along[0]])
        # 1.5 m from a corner so notches on neighbouring sides cannot cross.
        lo, hi = cut[side, 1] + 1.5, length - cut[(side + 1) % 4, 0] - 1.5
        vertices.append(start + along * cut[side, 1])
        # Features are placed in separate slots of the free part of the side so they never overlap.
        n_features = int(rng.integers(0, 3))
        slots: np.ndarray | list[float] = np.linspace(lo, hi, n_features + 1) if n_features else []
        for k in range(n_features):
            slot_lo, slot_hi = slots[k], slots[k + 1]
            width = min(rng.uniform(1.0, 3.0), 0.8 * (slot_hi - slot_lo))
            if width < 0.8:
                continue
            a = rng.uniform(slot_lo, slot_hi - width)
            depth = rng.uniform(0.6, 2.0) if rng.random() < 0.6 else -rng.uniform(0.4, 1.0)
            slant: np.ndarray | tuple[float, float]
            slant = rng.uniform(0.0, 0.3, size=2) * width if rng.random() < 0.5 else (0.0, 0.0)
            vertices += [
                start + along * a,
                start + along * (a + slant[0]) + outward * depth,
                start + along * (a + width - slant[1]) + outward * depth,
                start + along * (a + width),
            ]
        if cut[(side + 1) % 4, 0] > 0.0:
            vertices.append(end - along * cut[(side + 1) % 4, 0])
    return np.array(vertices)


def _split_glass(
    outer_segments: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Turn the middle of one long outer wall into a glass pane; returns segments and materials."""
    lengths = np.hypot(
        outer_segments[:, 2] - outer_segments[:, 0], outer_segments[:, 3] - outer_segments[:, 1]
    )
    materials = np.full(outer_segments.shape[0], "wall", dtype=object)
    long_walls = np.flatnonzero(lengths > 4.0)
    if long_walls.size == 0:
        return outer_segments, materials
    k = int(rng.choice(long_walls))
    p, q = outer_segments[k, 0:2], outer_segments[k, 2:4]
    pane_m = rng.uniform(1.5, min(3.0, lengths[k] - 2.0))
    start = rng.uniform(1.0, lengths[k] - 1.0 - pane_m) / lengths[k]
    a, b = p + (q - p) * start, p + (q - p) * (start + pane_m / lengths[k])
    pieces = np.array([[*p, *a], [*a, *b], [*b, *q]])
    segments = np.vstack([outer_segments[:k], pieces, outer_segments[k + 1 :]])
    materials = np.concatenate([materials[:k], ["wall", "glass", "wall"], materials[k + 1 :]])
    return segments, materials


def random_world(rng: np.random.Generator, size_m: tuple[float, float] = (20.0, 14.0)) -> World:
    """A procedurally generated indoor world with no symmetry, about W × H metres.

    Outer walls of an irregular room (cut corners, alcoves, notches, maybe a
    glass pane), a few boxes and a column at random positions and orientations,
    and one to three free-standing wall stubs, some of glass. Interior objects are kept apart
    so that the room stays mostly open.
    """
    width_m, height_m = float(size_m[0]), float(size_m[1])
    outer = _polygon_segments(_outer_wall(rng, width_m, height_m))
    segments, materials = _split_glass(outer, rng)
    parts: list[np.ndarray] = [segments]
    labels: list[str] = list(materials)

    def place(radius_m: float) -> np.ndarray | None:
        # A spot whose circle of radius_m keeps 1 m of passage to everything placed so far.
        for _ in range(50):
            center = rng.uniform([0.0, 0.0], [width_m, height_m])
            if _free_mask(np.vstack(parts), center[None, :], radius_m + 1.0)[0]:
                return center
        return None

    def add(piece: np.ndarray, material: str = "wall") -> None:
        parts.append(piece)
        labels.extend([material] * piece.shape[0])

    for _ in range(int(rng.integers(2, 5))):
        size = (rng.uniform(0.5, 1.6), rng.uniform(0.4, 1.2))
        center = place(0.5 * float(np.hypot(*size)))
        if center is not None:
            add(_box(center, size, rng.uniform(0.0, np.pi)))
    radius = rng.uniform(0.15, 0.3)
    center = place(radius)
    if center is not None:
        sides = int(rng.integers(8, 13))
        phase = rng.uniform(0.0, TWO_PI)
        angles = phase + TWO_PI * np.arange(sides) / sides
        add(_polygon_segments(center + radius * np.column_stack([np.cos(angles), np.sin(angles)])))
    for _ in range(int(rng.integers(1, 4))):
        length = rng.uniform(1.0, 3.0)
        center = place(length / 2.0)
        if center is not None:
            direction = rotation(rng.uniform(0.0, np.pi))[:, 0] * length / 2.0
            stub = np.array([[*(center - direction), *(center + direction)]])
            add(stub, "glass" if rng.random() < 0.25 else "wall")

    return World(segments=np.vstack(parts), materials=np.array(labels, dtype=str), name="random")


def symmetric_room(rng: np.random.Generator) -> World:
    """A rectangular room of 8–16 m × 5–10 m that looks the same after a half turn about its
    centre: two to four boxes, each with its twin rotated 180° about the centre.

    Every pose has a twin (the half turn of it) from which a scanner sees the very same
    scan, so no scan alone can tell the two apart.
    """
    width, height = rng.uniform(8.0, 16.0), rng.uniform(5.0, 10.0)
    corners = np.array([[0.0, 0.0], [width, 0.0], [width, height], [0.0, height]])
    parts = [_polygon_segments(corners)]
    centre = np.array([width, height]) / 2.0
    for _ in range(int(rng.integers(2, 5))):
        size = (rng.uniform(0.4, 1.2), rng.uniform(0.4, 1.0))
        # In the lower half, clear of the walls and of the centre line, so twins never meet.
        spot = rng.uniform([1.5, 1.2], [width - 1.5, max(1.3, height / 2.0 - 1.2)])
        theta = rng.uniform(0.0, np.pi)
        parts += [_box(spot, size, theta), _box(2.0 * centre - spot, size, theta + np.pi)]
    segments = np.vstack(parts)
    return World(segments=segments, materials=np.full(len(segments), "wall"), name="symmetric")


def repeating_corridor(rng: np.random.Generator, length_m: float = 80.0) -> World:
    """A straight corridor 2–3 m wide and ``length_m`` long, closed at both ends, with a door
    recess every 4–6 m along both walls, the same period all along.

    Far from the ends (beyond the scanner's range) a scan looks the same one period further
    on, so it cannot tell neighbouring stretches apart.
    """
    width, period = rng.uniform(2.0, 3.0), rng.uniform(4.0, 6.0)
    door, depth = rng.uniform(0.9, 1.2), rng.uniform(0.2, 0.4)
    starts = np.arange(period / 2.0, length_m - period / 2.0, period)
    parts = [np.array([[0.0, 0.0, 0.0, width], [length_m, 0.0, length_m, width]])]
    for y, out in ((0.0, -depth), (width, depth)):
        gaps = np.ravel(np.column_stack([starts, starts + door]))
        edges = np.concatenate([[0.0], gaps, [length_m]])
        parts.append(np.column_stack([edges[0::2], np.full(edges.size // 2, y),
                                      edges[1::2], np.full(edges.size // 2, y)]))  # fmt: skip
        for x in starts:  # the recess: two jambs and its back
            parts.append(np.array([[x, y, x, y + out], [x, y + out, x + door, y + out],
                                   [x + door, y + out, x + door, y]]))  # fmt: skip
    segments = np.vstack(parts)
    return World(segments=segments, materials=np.full(len(segments), "wall"), name="corridor")


def random_free_poses(
    world: World, n: int, rng: np.random.Generator, clearance_m: float = 0.6
) -> np.ndarray:
    """Poses (n, 3) x m, y m, theta rad on the world's open floor.

    Positions lie inside the outer walls, outside every closed obstacle and at
    least ``clearance_m`` from every segment; headings are uniform in [−π, π).
    """
    segments = as_segments(world.segments, "world segments")
    if segments.shape[0] == 0:
        raise ValueError(f"world {world.name!r} has no segments")
    lo = np.minimum(segments[:, 0:2], segments[:, 2:4]).min(axis=0)
    hi = np.maximum(segments[:, 0:2], segments[:, 2:4]).max(axis=0)
    found: list[np.ndarray] = []
    count = 0
    for _ in range(100):
        candidates = rng.uniform(lo, hi, size=(max(4 * n, 64), 2))
        free = candidates[free_space_mask(world, candidates, clearance_m)]
        found.append(free)
        count += free.shape[0]
        if count >= n:
            break
    else:
        raise ValueError(
            f"world {world.name!r}: found only {count} of {n} free poses "
            f"with {clearance_m} m clearance"
        )
    xy = np.vstack(found)[:n]
    return np.column_stack([xy, rng.uniform(-np.pi, np.pi, size=n)])
