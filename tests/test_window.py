"""Windows: a scan's neighbours chosen by odometry, fitted to each other and localized as one."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from segloc_cli.config import MIN_HOLD_POINTS, TrackParams, WindowParams
from segloc_cli.estimates import STATUS_OK
from segloc_cli.geometry import Pose2, transform_points
from segloc_cli.method.extract import extract_segments
from segloc_cli.method.localize import Localizer, localize_scan, localize_scans
from segloc_cli.method.refine import nearest_segments
from segloc_cli.method.window import (
    Neighbour,
    Windows,
    neighbour_indices,
    relative_pose,
    window_map,
)
from segloc_cli.sim import NOISE_FREE, SensorModel, simulate_scan
from segloc_cli.world import World


def _straight(n: int, step_m: float = 0.125, dt_s: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
    """Odometry (n, 3) of a robot driving along x, ``step_m`` per scan, and the scans' times."""
    odometry = np.column_stack([np.arange(n) * step_m, np.zeros(n), np.zeros(n)])
    return odometry, np.arange(n) * dt_s


def test_neighbours_are_spaced_by_travel_and_nearest_first():
    odometry, times = _straight(41)
    # From scan 20: every second scan (0.25 m apart) out to 1 m each way, alternating sides.
    got = neighbour_indices(odometry, times, 20, WindowParams())
    assert got == [18, 22, 16, 24, 14, 26, 12, 28]
    assert neighbour_indices(odometry, times, 20, WindowParams(max_scans=5)) == [18, 22, 16, 24]
    # At the start of the log only the later side has scans.
    assert neighbour_indices(odometry, times, 0, WindowParams()) == [2, 4, 6, 8]


def test_the_walk_stops_at_the_travel_time_and_odometry_limits():
    odometry, times = _straight(41)
    assert neighbour_indices(odometry, times, 20, WindowParams(travel_m=0.5)) == [18, 22, 16, 24]
    # 0.2 s per scan: within 0.5 s, two scans each way, of which one is far enough.
    assert neighbour_indices(odometry, times, 20, WindowParams(max_time_s=0.5)) == [18, 22]
    gap = odometry.copy()
    gap[17] = np.nan  # no odometry at scan 17: the walk back ends there
    assert neighbour_indices(gap, times, 20, WindowParams()) == [18, 22, 24, 26, 28]
    assert neighbour_indices(odometry, times, 20, WindowParams(travel_m=0.0)) == []


def test_a_robot_turning_in_place_takes_a_neighbour_per_spacing_angle():
    n = 21
    odometry = np.column_stack([np.zeros(n), np.zeros(n), np.deg2rad(np.arange(n) * 4.0)])
    times = np.arange(n) * 0.2
    # 4° per scan, a neighbour every 12° (the first scan at or beyond 10°), no travel at all.
    assert neighbour_indices(odometry, times, 10, WindowParams()) == [7, 13, 4, 16, 1, 19]


def test_relative_pose_is_the_other_scan_in_this_ones_frame():
    odometry = np.array([[1.0, 2.0, np.pi / 2], [1.0, 3.0, np.pi / 2]])
    rel = relative_pose(odometry, 0, 1)
    assert (rel.x, rel.y, rel.theta) == pytest.approx((1.0, 0.0, 0.0))


# A corridor 2 m wide ending in a wall at x = 8.5 m: a scanner reaching 3 m sees two bare walls
# from x = 5 (where the robot is), and the end wall from x = 5.75 on.
CORRIDOR = World(
    np.array([[0.0, 0.0, 8.5, 0.0], [0.0, 2.0, 8.5, 2.0], [8.5, 0.0, 8.5, 2.0],
              [0.0, 0.0, 0.0, 2.0]])
)  # fmt: skip
SHORT_RANGE = SensorModel(
    readings=1024, noise_cm=0.0, resolution_m=0.0, range_max_m=3.0, dropout_prob=0.0,
    glass_return_prob=0.0, clutter_clusters=0.0,
)  # fmt: skip
TRUTH = Pose2(5.0, 1.0, 0.0)


def _corridor_window(slip: Pose2 | None = None) -> tuple:
    """The scan at ``TRUTH`` and its neighbours 0.25–1 m ahead and behind, placed by exact
    odometry (the one 1 m ahead by odometry that slipped by ``slip``)."""
    rng = np.random.default_rng(3)
    scan = simulate_scan(CORRIDOR, TRUTH, SHORT_RANGE, rng, 0.0)
    neighbours = []
    for step in (0.25, -0.25, 0.5, -0.5, 0.75, -0.75, 1.0, -1.0):
        motion = Pose2(step, 0.0, 0.0)
        other = simulate_scan(CORRIDOR, TRUTH.compose(motion), SHORT_RANGE, rng, step)
        measured = motion if (slip is None or step != 1.0) else motion.compose(slip)
        neighbours.append((other, measured))
    return scan, neighbours


def test_a_window_fixes_the_place_along_a_corridor_that_the_scan_alone_cannot():
    scan, neighbours = _corridor_window()
    localizer = Localizer.on_map(CORRIDOR.segments)
    guess = Pose2(5.6, 1.1, np.deg2rad(4.0))
    alone, held_alone = localize_scan(localizer, scan, guess)
    assert held_alone == 1
    assert alone.status != STATUS_OK  # two bare walls: nothing fixes x
    assert alone.evidence.hold_points < MIN_HOLD_POINTS
    windows = Windows([neighbours], WindowParams(), TrackParams())
    together, held = localize_scan(localizer, scan, guess, None, neighbours, windows)
    assert held == 9
    assert together.evidence.hold_points > 5 * MIN_HOLD_POINTS
    # The verdict's shares are of the window; whether it is lost, of the scan's own points.
    assert together.evidence.points > scan.points().shape[0]
    assert together.evidence.scan_inlier_ratio == pytest.approx(1.0)
    assert alone.evidence.scan_inlier_ratio is None
    assert np.hypot(together.pose.x - TRUTH.x, together.pose.y - TRUTH.y) < 0.02
    assert abs(together.pose.theta - TRUTH.theta) < np.deg2rad(0.2)


def test_a_neighbour_whose_odometry_slipped_is_refitted_or_left_out():
    params = WindowParams()
    for slip, kept in ((Pose2(0.0, 0.03, np.deg2rad(1.5)), 9), (Pose2(0.0, 0.6, 0.4), 8)):
        scan, neighbours = _corridor_window(slip)
        placed = [Neighbour(s.points(), extract_segments(s), pose) for s, pose in neighbours]
        window = window_map(scan.points(), extract_segments(scan), placed, params)
        assert window.scans == kept
        # Every point of the window, placed at the scan's true pose, lies on the corridor.
        _, dist = nearest_segments(transform_points(window.points, TRUTH), CORRIDOR.segments)
        assert np.max(dist) < 0.01


def test_a_neighbour_that_sees_other_walls_than_the_scan_is_left_out():
    """Placed 0.25 m ahead, a scan of a 4 m × 4 m room holds little the corridor's walls
    explain; the fit cannot move it far, so only its disagreement gives it away."""
    scan, neighbours = _corridor_window()
    room = World(np.array([[0, 0, 4, 0], [4, 0, 4, 4], [4, 4, 0, 4], [0, 4, 0, 0.0]]))
    stranger = simulate_scan(room, Pose2(2.0, 2.0, 0.0), SHORT_RANGE, np.random.default_rng(8), 0.1)
    placed = [Neighbour(s.points(), extract_segments(s), pose) for s, pose in neighbours[:2]]
    odd = Neighbour(stranger.points(), extract_segments(stranger), Pose2(0.25, 0.0, 0.0))
    segments = extract_segments(scan)
    assert window_map(scan.points(), segments, placed, WindowParams()).scans == 3
    assert window_map(scan.points(), segments, [odd, *placed], WindowParams()).scans == 3
    agreeing = WindowParams(min_agreement=0.0)
    assert window_map(scan.points(), segments, [odd, *placed], agreeing).scans == 4


def test_a_neighbour_that_mostly_sees_what_the_scan_did_not_is_kept():
    """Agreement is judged where the neighbour overlaps the window: points it sees beyond
    every wall the window holds (here a wall 3 m past the corridor's end, twice as many
    points as it has on the corridor) neither keep it nor leave it out."""
    scan, neighbours = _corridor_window()
    other, pose = neighbours[0]
    beyond = np.column_stack([np.full(800, 6.5), np.linspace(-2.0, 4.0, 800)])  # x = 11.5 m
    points = np.vstack([other.points(), transform_points(beyond, pose.inverse())])
    seeing_more = Neighbour(points, extract_segments(other), pose)
    window = window_map(scan.points(), extract_segments(scan), [seeing_more], WindowParams())
    assert window.scans == 2
    assert window.points.shape[0] > scan.points().shape[0] + 600


def test_windowed_rows_say_how_many_scans_they_hold_and_match_on_two_processes():
    from segloc_cli.runs.parallel import localize_scans_parallel

    scan, neighbours = _corridor_window()
    windows = Windows([neighbours, [], neighbours[:2]], WindowParams(), TrackParams())
    scans, guesses = [scan] * 3, [Pose2(5.3, 1.0, 0.0)] * 3
    localizer = Localizer.on_map(CORRIDOR.segments)
    rows = list(localize_scans(scans, guesses, [1, 2, 3], localizer, None, windows))
    assert [r["window_scans"] for r in rows] == [9, 1, 3]
    two = list(localize_scans_parallel(scans, guesses, [1, 2, 3], localizer, 2, windows=windows))

    def table(made):
        return pd.DataFrame(made).drop(columns=["runtime_ms", "hypotheses"])

    pd.testing.assert_frame_equal(table(two), table(rows))


def test_a_noise_free_window_in_open_space_changes_nothing_but_the_evidence():
    rng = np.random.default_rng(11)
    room = World(np.array([[0, 0, 10, 0], [10, 0, 10, 6], [10, 6, 0, 6], [0, 6, 0, 0.0]]))
    truth = Pose2(3.0, 2.0, 0.3)
    scan = simulate_scan(room, truth, NOISE_FREE, rng, 0.0)
    motion = Pose2(0.5, 0.0, 0.1)
    other = simulate_scan(room, truth.compose(motion), NOISE_FREE, rng, 0.5)
    windows = Windows([[(other, motion)]], WindowParams(), TrackParams())
    localizer = Localizer.on_map(room.segments)
    est, held = localize_scan(
        localizer, scan, Pose2(3.4, 1.7, 0.5), None, [(other, motion)], windows
    )
    assert held == 2
    assert est.evidence.points > scan.points().shape[0]
    assert np.hypot(est.pose.x - truth.x, est.pose.y - truth.y) < 1e-6


def corridor_run(
    folder: Path, step_m: float, n_scans: int, guess: tuple[int, float, float]
) -> tuple[Path, Path, Path]:
    """A log of ``n_scans`` scans down the corridor from x = 3 m, ``step_m`` apart, one every
    0.5 s, with exact odometry; the corridor's map; a guess file of one row (pose id, time s,
    x m; y 1 m, heading 0). Their paths, in ``folder``."""
    from segloc_cli.estimates import PoseTable
    from segloc_cli.io.maps import write_map
    from segloc_cli.io.mcap_log import write_log
    from segloc_cli.io.tables import write_pose_table

    rng = np.random.default_rng(5)
    poses = [Pose2(3.0 + step_m * k, 1.0, 0.0) for k in range(n_scans)]
    scans = [simulate_scan(CORRIDOR, p, SHORT_RANGE, rng, 0.5 * k) for k, p in enumerate(poses)]
    log = folder / "log.mcap"
    write_log(
        log, scans, [(s.time_s, p) for s, p in zip(scans, poses, strict=True)],
        {"range_max_m": "3.0"},
    )  # fmt: skip
    map_path = folder / "map.json"
    write_map(map_path, CORRIDOR.segments)
    guesses = folder / "guesses.csv"
    pose_id, time_s, x_m = guess
    write_pose_table(
        guesses, PoseTable(np.array([pose_id]), np.array([time_s]), np.array([[x_m, 1.0, 0.0]]))
    )
    return log, map_path, guesses


def test_localize_uses_windows_where_the_log_has_odometry_and_says_so(tmp_path, capsys):
    from conftest import HALL
    from test_cli import run_cli

    from segloc_cli.io.tables import read_estimates

    # A robot driving down the corridor, 0.25 m per scan, its odometry exact; a guess for the
    # scan at x = 5 (the ninth), 0.4 m off along the corridor.
    log, map_path, guesses = corridor_run(tmp_path, 0.25, 17, (9, 4.0, 5.4))
    runs = {}
    for name, extra in (
        ("window", ()),
        ("alone", ("--window-m", "0")),
        ("paper", ("--no-refine",)),
    ):
        out = tmp_path / f"{name}.csv"
        result = run_cli(
            capsys, "localize", log, "--map", map_path, "--initial", guesses, "--out", out, *extra
        )
        assert result.code == 0, result.err
        runs[name] = (result.err.splitlines()[0], read_estimates(out).iloc[0])
    info = run_cli(capsys, "info", log).out
    assert "windows:  yes; localize places each scan's neighbours by /odom (--window-m)" in info
    simulated = run_cli(capsys, "info", HALL / "log.mcap").out
    assert "windows:  no; the log's /odom holds simulated initial guesses, not odometry" in (
        simulated
    )
    note, row = runs["window"]
    window_note = "each scan with its neighbours within 1 m of odometry travel (window of 9 scans"
    assert note == f"segloc: {log}: {window_note}, median)"
    assert row["window_scans"] == 9 and row["status"] == "ok"
    assert abs(row["x_m"] - 5.0) < 0.02
    note, row = runs["alone"]
    assert note == f"segloc: {log}: each scan alone (--window-m 0)"
    assert row["window_scans"] == 1 and row["status"] != "ok"
    note, row = runs["paper"]
    assert note == (
        f"segloc: {log}: each scan alone (--no-refine: the paper's method, one scan a local map)"
    )
    assert row["window_scans"] == 1


def test_a_window_of_one_scan_is_counted_in_the_singular(tmp_path, capsys):
    from test_cli import run_cli

    # Scans 2 m apart with exact odometry: none lies within 1 m of travel of another.
    log, map_path, guesses = corridor_run(tmp_path, 2.0, 3, (2, 0.5, 5.1))
    result = run_cli(
        capsys, "localize", log, "--map", map_path, "--initial", guesses,
        "--out", tmp_path / "est.csv",
    )  # fmt: skip
    assert result.code == 0, result.err
    assert result.err.splitlines()[0] == (
        f"segloc: {log}: each scan with its neighbours within 1 m of odometry travel "
        "(window of 1 scan, median)"
    )
