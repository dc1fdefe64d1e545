"""Write datasets/hall/mapping_poses.csv: the path of the hall's mapping run.

The hall's map is built from a run of its own, not from the ten scans it is
tested on. The robot drives the route below (world frame, metres) at a steady
0.5 m/s and scans every metre of it, facing the way it drives: along the south
side and round the reception desk, up the east side with a visit to the east
corridor, back along the north wall with visits to the elevator alcove and the
north corridor, down the cut north-west corner, then three rows across the
middle of the hall between the columns, benches and the stair.

Every scan is at least ``CLEARANCE_M`` from every segment of the world, and a
scan that would fall within ``TEST_EXCLUSION_M`` of one of the ten test poses
of ``poses.csv`` (at any heading) is left out, so no scan of the map is taken
where a test scan is.

Run ``.venv/bin/python datasets/hall/make_mapping_poses.py`` from the
repository root.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from segloc_cli.io.maps import read_world
from segloc_cli.sim import free_space_mask

HERE = Path(__file__).resolve().parent
OUT = HERE / "mapping_poses.csv"

SPACING_M = 1.0
"""Distance driven between two scans of the mapping run (m)."""
SPEED_M_S = 0.5
"""Speed of the mapping robot (m/s); sets the scans' times."""
CLEARANCE_M = 0.5
"""Least distance from a mapping pose to any segment of the world (m)."""
TEST_EXCLUSION_M = 0.5
"""A mapping pose this close to a test pose of ``poses.csv`` is left out (m)."""

# The route, as waypoints x, y (m). A leg that goes out and comes back (a dead
# end) is written as its far waypoint followed by the near one again.
ROUTE: list[tuple[float, float]] = [
    # south side, round the reception desk
    (1.5, 3.0),
    (14.2, 3.0),
    (14.2, 1.0),
    (23.2, 1.0),
    # east side, into the east corridor and back
    (23.2, 5.8),
    (26.3, 5.8),
    (23.2, 5.8),
    (23.2, 15.4),
    # north side: the elevator alcove, the north corridor, the cut corner
    (17.5, 15.4),
    (17.5, 16.8),
    (17.5, 15.4),
    (6.7, 15.4),
    (6.7, 17.7),
    (6.7, 15.4),
    (4.2, 15.4),
    (1.6, 12.2),
    # rows across the middle of the hall
    (17.8, 12.2),
    (17.8, 9.6),
    (4.0, 9.6),
    (4.0, 6.8),
    (19.5, 6.8),
]


def sample_route(route: np.ndarray, spacing_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Poses every ``spacing_m`` along the polyline ``route`` (K, 2), metres.

    Returns the arc length (N,) in metres of each pose from the route's start
    and the poses (N, 3) x m, y m, theta rad in the world frame, each facing
    along the leg it lies on (a pose on a waypoint faces along the next leg).
    """
    legs = np.diff(route, axis=0)
    lengths = np.hypot(legs[:, 0], legs[:, 1])
    starts = np.concatenate([[0.0], np.cumsum(lengths)])
    arc = np.arange(0.0, starts[-1] + 1e-9, spacing_m)
    leg = np.clip(np.searchsorted(starts, arc, side="right") - 1, 0, len(legs) - 1)
    along = (arc - starts[leg]) / lengths[leg]
    xy = route[leg] + along[:, None] * legs[leg]
    theta = np.arctan2(legs[leg, 1], legs[leg, 0])
    return arc, np.column_stack([xy, theta])


def main() -> None:
    world = read_world(HERE / "world.json")
    tests = np.loadtxt(HERE / "poses.csv", delimiter=",", skiprows=1, ndmin=2)[:, 2:4]
    arc, poses = sample_route(np.array(ROUTE), SPACING_M)
    gaps = np.linalg.norm(poses[:, None, :2] - tests[None, :, :], axis=2).min(axis=1)
    keep = gaps >= TEST_EXCLUSION_M
    arc, poses = arc[keep], poses[keep]
    blocked = np.flatnonzero(~free_space_mask(world, poses[:, :2], CLEARANCE_M))
    if blocked.size:
        x, y = poses[blocked[0], :2]
        sys.exit(f"mapping pose at ({x:.2f}, {y:.2f}) is within {CLEARANCE_M} m of the world")
    lines = ["pose_id,time_s,x_m,y_m,theta_deg"]
    for k, (s, (x, y, theta)) in enumerate(zip(arc, poses, strict=True), start=1):
        heading = float(np.degrees(theta)) + 0.0
        lines.append(f"{k},{s / SPEED_M_S:.1f},{x:.3f},{y:.3f},{heading:.1f}")
    OUT.write_text("\n".join(lines) + "\n", encoding="utf-8")
    print(f"wrote {OUT} ({len(poses)} poses, {int((~keep).sum())} left out near test poses)")


if __name__ == "__main__":
    main()
