"""Segment SLAM (``maps/slam.py``) and ``map build`` without a survey.

A hand-made building: a ring corridor 2 m wide around a 8 m × 4 m block, with alcoves
and pillars so that no stretch of it is a bare corridor. The robot goes round it twice,
its odometry drifting (a heading bias and noise growing with the distance travelled),
so that only the scans can keep the poses, and only a loop can close the ring.
"""

from __future__ import annotations

import itertools
import re

import numpy as np
import pandas as pd
import pytest
from conftest import HALL
from test_cli import run_in_process

from segloc_cli.config import LocalizeParams
from segloc_cli.geometry import (
    Pose2,
    chained_motions,
    point_segment_distances,
    relative_motion,
    wrap_angle,
)
from segloc_cli.maps.loop_search import LoopQuery, LoopSearcher
from segloc_cli.maps.slam import (
    _Graph,
    _graph_travel,
    _Submap,
    fit_information,
    odometry_at,
    run_slam,
)
from segloc_cli.method.extract import extract_segments
from segloc_cli.sim import SensorModel, simulate_scan
from segloc_cli.world import World

STEP_M = 0.2
SENSOR = SensorModel(readings=361, clutter_clusters=0.0, dropout_prob=0.0)


def _box(x0, y0, x1, y1):
    return [[x0, y0, x1, y0], [x1, y0, x1, y1], [x1, y1, x0, y1], [x0, y1, x0, y0]]


def ring_building() -> World:
    """Outer walls 12 m × 8 m, the inner block from (2, 2) to (10, 6), pillars and an
    alcove breaking up the corridors."""
    walls = _box(0.0, 0.0, 12.0, 8.0) + _box(2.0, 2.0, 10.0, 6.0)
    walls += _box(4.0, 0.0, 4.4, 0.4) + _box(7.5, 7.6, 8.1, 8.0) + _box(11.6, 3.0, 12.0, 3.3)
    walls += _box(0.0, 5.0, 0.3, 5.6) + _box(6.0, 1.7, 6.8, 2.0) + _box(2.0, 6.0, 2.5, 6.4)
    return World(np.array(walls, dtype=float), name="ring")


def ring_path(laps: int = 2) -> np.ndarray:
    """Poses (N, 3) round the corridor's centre line, ``STEP_M`` apart, turning in place."""
    corners = [(1.0, 1.0), (11.0, 1.0), (11.0, 7.0), (1.0, 7.0)]
    poses = []
    for _ in range(laps):
        for (x0, y0), (x1, y1) in zip(corners, corners[1:] + corners[:1], strict=True):
            heading = np.arctan2(y1 - y0, x1 - x0)
            steps = round(np.hypot(x1 - x0, y1 - y0) / STEP_M)
            poses += [(x0 + (x1 - x0) * t, y0 + (y1 - y0) * t, heading)
                      for t in np.arange(steps) / steps]  # fmt: skip
    return np.array(poses)


def drifting_odometry(truth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The motions of ``truth`` with a heading bias of 2° per metre and noise."""
    motions = relative_motion(truth[:-1], truth[1:])
    travel = np.hypot(motions[:, 0], motions[:, 1])
    motions[:, :2] += rng.normal(0.0, 0.01, motions[:, :2].shape) * travel[:, None]
    motions[:, 2] += np.deg2rad(2.0) * travel + rng.normal(0.0, np.deg2rad(0.3), travel.size)
    return chained_motions(truth[0], motions)


@pytest.fixture(scope="module")
def ring_run():
    rng = np.random.default_rng(44)
    world = ring_building()
    truth = ring_path()
    scans = [simulate_scan(world, Pose2(*p), SENSOR, rng, 0.1 * i) for i, p in enumerate(truth)]
    odometry = drifting_odometry(truth, rng)
    return world, truth, run_slam(scans, odometry, initial=Pose2(*truth[0]))


def _errors(poses: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return (
        np.hypot(*(poses[:, :2] - truth[:, :2]).T),
        np.rad2deg(np.abs(wrap_angle(poses[:, 2] - truth[:, 2]))),
    )


def test_slam_keeps_every_pose_where_the_odometry_drifts_away(ring_run):
    _, truth, result = ring_run
    odom_m, _ = _errors(result.odometry, truth)
    slam_m, slam_deg = _errors(result.poses, truth)
    assert odom_m.max() > 1.0  # the odometry alone is metres off by the second lap
    assert slam_m.max() < 0.1 and slam_deg.max() < 1.0, (slam_m.max(), slam_deg.max())
    assert result.loops_accepted >= 1
    assert all(loop.correction_m < 0.5 for loop in result.accepted_loops)
    assert 0 < result.keyframes.size < truth.shape[0]


def test_loop_searches_in_a_worker_process_give_the_same_poses(ring_run):
    """The ring run with its loop searches in a worker process (as a long log's are): the
    same loops and poses to the bit as searched in the mapping process."""
    world, truth, here = ring_run
    rng = np.random.default_rng(44)
    scans = [simulate_scan(world, Pose2(*p), SENSOR, rng, 0.1 * i) for i, p in enumerate(truth)]
    odometry = drifting_odometry(truth, rng)
    beside = run_slam(scans, odometry, initial=Pose2(*truth[0]), parallel=True)

    def said(result):
        return [(loop.keyframe, loop.anchor, loop.status, loop.accepted) for loop in result.loops]

    assert said(beside) == said(here) and beside.loops_accepted >= 1
    motions = [np.array([loop.motion for loop in r.loops]) for r in (beside, here)]
    np.testing.assert_array_equal(*motions)  # NaN where nothing was found, in both
    np.testing.assert_array_equal(beside.poses, here.poses)


def test_the_loop_worker_leaves_ctrl_c_to_the_mapping_process():
    """Ctrl-C reaches the whole process group; the worker goes on (no traceback of its own)
    until the mapping process, which handles it, stops it."""
    import os
    import signal

    from segloc_cli.config import LocalizeParams
    from segloc_cli.maps.loop_search import LoopQuery, LoopSearcher

    searcher = LoopSearcher(parallel=True)
    try:
        searcher.add_submap(0, np.array(_box(0.0, 0.0, 4.0, 3.0), dtype=float))
        os.kill(searcher._worker.pid, signal.SIGINT)
        searcher.submit(np.zeros((0, 4)), np.zeros((0, 2)),
                        [LoopQuery(0, np.array([2.0, 1.5, 0.0]), LocalizeParams())])  # fmt: skip
        (find,) = searcher.collect()
        assert find.status == "too_few_segments"
    finally:
        searcher.close()
    assert not searcher._worker.is_alive()


def test_the_map_of_the_solved_poses_lies_on_the_walls(ring_run):
    from segloc_cli.maps.fusion import build_global_map

    world, _, result = ring_run
    poses = [Pose2(*result.keyframe_poses[k]) for k in range(result.keyframes.size)]
    segments = build_global_map(result.local_maps, poses)
    ends = segments.reshape(-1, 2)
    assert point_segment_distances(ends, world.segments).min(axis=1).max() < 0.05


def test_the_fits_information_weighs_what_the_walls_pin():
    """Points on one wall along x pin y only: no information along x; on two walls at
    right angles, both. The heading is pinned by points spread along a wall."""
    wall_x = np.array([[-5.0, 1.0, 5.0, 1.0]])
    points = np.column_stack([np.linspace(-3, 3, 61), np.full(61, 1.0)])
    info = fit_information(points, wall_x, np.zeros(3), 0.05, 0.02)
    assert info[0, 0] == pytest.approx(0.0, abs=1e-9)
    assert info[1, 1] == pytest.approx(61 / 0.02**2)
    assert info[2, 2] > 0
    corner = np.vstack([wall_x, [[1.0, -5.0, 1.0, 5.0]]])
    both = np.vstack([points, np.column_stack([np.full(61, 1.0), np.linspace(-3, 3, 61)])])
    info = fit_information(both, corner, np.zeros(3), 0.05, 0.02)
    assert np.linalg.eigvalsh(info[:2, :2]).min() > 10 / 0.02**2


def test_odometry_is_interpolated_to_the_scans_across_the_wrap():
    times = np.array([0.0, 1.0])
    poses = np.array([[0.0, 0.0, np.deg2rad(179.0)], [1.0, 2.0, np.deg2rad(-179.0)]])
    at = odometry_at(np.array([0.5, -1.0, 3.0]), times, poses)
    np.testing.assert_allclose(at[:, :2], [[0.5, 1.0], [0.0, 0.0], [1.0, 2.0]])
    np.testing.assert_allclose(np.abs(np.rad2deg(at[0, 2])), 180.0)


def test_map_build_without_survey_writes_the_poses_that_rebuild_its_map(tmp_path):
    """The first 13 scans of the hall's mapping run, written without its odometry: their
    poses found from the scans alone; the poses given back as a survey fuse the same map.
    (README.md maps the whole run, odometry and all.)"""
    from segloc_cli.io.mcap_log import read_log, write_log

    log = tmp_path / "scans.mcap"
    write_log(log, read_log(HALL / "mapping" / "log.mcap").scans[:13], [])
    first = run_in_process(
        "map", "build", log, "--initial", "1.5,3,0",
        "--out", tmp_path / "slam.json", "--poses-out", tmp_path / "poses.csv",
    )  # fmt: skip
    assert first.code == 0, first.err
    assert "no odometry" in first.err
    found = pd.read_csv(tmp_path / "poses.csv")
    survey = pd.read_csv(HALL / "mapping" / "survey.csv").set_index("pose_id")
    truth = survey.loc[found.pose_id]
    assert np.hypot(found.x_m - truth.x_m.values, found.y_m - truth.y_m.values).max() < 0.05
    again = run_in_process(
        "map", "build", log, "--survey", tmp_path / "poses.csv", "--out", tmp_path / "again.json"
    )
    assert again.code == 0, again.err
    maps = [
        pd.read_json(tmp_path / name, typ="series")["segments"]
        for name in ("slam.json", "again.json")
    ]
    np.testing.assert_allclose(np.array(maps[0]), np.array(maps[1]), atol=1e-5)


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["--survey", HALL / "mapping" / "survey.csv", "--initial", "0,0,0"], "--initial is for"),
        (["--survey", HALL / "mapping" / "survey.csv", "--loops-out", "l.csv"], "--loops-out is"),
        (["--scans", "1"], "at least two scans"),
        (["--initial", "0,nan,0"], "finite"),
    ],
)
def test_map_build_without_survey_refuses_what_it_cannot_do(tmp_path, args, said):
    run = run_in_process(
        "map", "build", HALL / "mapping" / "log.mcap", *args, "--out", tmp_path / "m.json"
    )
    assert run.code == 2
    assert said in run.err
    assert len(run.err.strip().splitlines()) == 1, run.err


def test_map_build_keeps_an_existing_poses_file_without_force(tmp_path):
    taken = tmp_path / "poses.csv"
    taken.write_text("kept\n")
    run = run_in_process(
        "map", "build", HALL / "mapping" / "log.mcap", "--out", tmp_path / "m.json",
        "--poses-out", taken,
    )  # fmt: skip
    assert run.code == 2
    assert "--poses-out" in run.err and "--force" in run.err, run.err
    assert taken.read_text() == "kept\n"
    assert not (tmp_path / "m.json").exists()


def test_a_jump_of_the_odometry_is_placed_by_the_scans(ring_run):
    """The odometry of the ring run reset to the origin halfway: the scans after it are
    still placed where they were taken, and the jump is reported."""
    world, truth, _ = ring_run
    rng = np.random.default_rng(45)
    scans = [simulate_scan(world, Pose2(*p), SENSOR, rng, 0.1 * i) for i, p in enumerate(truth)]
    odometry = drifting_odometry(truth, rng)
    half = truth.shape[0] // 2
    odometry[half:] = [
        *relative_motion(
            np.repeat(odometry[half : half + 1], truth.shape[0] - half, 0), odometry[half:]
        )
    ]
    jumped = run_slam(scans, odometry, initial=Pose2(*truth[0]))
    assert jumped.odometry_jumps == [half]
    slam_m, slam_deg = _errors(jumped.poses, truth)
    assert slam_m.max() < 0.1 and slam_deg.max() < 1.0, (slam_m.max(), slam_deg.max())


def twin_rooms() -> World:
    """Two rooms alike, 6 m square with the same pillars, 8 m apart, a corridor between
    their doorways (each room has one on either side, the outer one closed by a niche)."""
    walls = []
    for dx in (0.0, 8.0):
        walls += [[dx, 0, dx + 6, 0], [dx + 6, 6, dx, 6]]  # south and north walls
        for x in (dx, dx + 6):  # west and east walls, with a doorway from y 2.5 to 3.5
            walls += [[x, 0, x, 2.5], [x, 3.5, x, 6]]
        walls += _box(dx + 1.8, 1.8, dx + 2.2, 2.2) + _box(dx + 3.5, 4.0, dx + 4.1, 4.3)
    walls += [[6, 2.5, 8, 2.5], [6, 3.5, 8, 3.5]]  # the corridor
    walls += [[-1, 2.5, 0, 2.5], [-1, 2.5, -1, 3.5], [-1, 3.5, 0, 3.5]]  # west niche
    walls += [[14, 2.5, 15, 2.5], [15, 2.5, 15, 3.5], [14, 3.5, 15, 3.5]]  # east niche
    return World(np.array(walls, dtype=float), name="twins")


def _walk(points: list[tuple[float, float]]) -> np.ndarray:
    """Poses ``STEP_M`` apart along the polyline ``points``, turning in place at corners."""
    poses = []
    for (x0, y0), (x1, y1) in itertools.pairwise(points):
        heading = np.arctan2(y1 - y0, x1 - x0)
        steps = round(np.hypot(x1 - x0, y1 - y0) / STEP_M)
        poses += [(x0 + (x1 - x0) * t, y0 + (y1 - y0) * t, heading)
                  for t in np.arange(steps) / steps]  # fmt: skip
    return np.array(poses)


def test_a_room_like_one_seen_before_closes_no_loop():
    """Twice round the first room, along the corridor, and twice round its twin: the scans
    in the twin look like those of the first room, but the odometry puts them 8 m away,
    beyond where a keyframe is searched for: every loop taken joins true places (the first
    room's submaps see down the corridor, so some loops from it are true)."""
    rng = np.random.default_rng(46)
    world = twin_rooms()
    square = [(1.2, 1.2), (4.8, 1.2), (4.8, 4.8), (1.2, 4.8)]
    route = square * 2 + [(1.2, 3.0), (9.2, 3.0)]
    route += [(x + 8.0, y) for x, y in square * 2 + [(1.2, 1.2)]]
    truth = _walk(route)
    scans = [simulate_scan(world, Pose2(*p), SENSOR, rng, 0.1 * i) for i, p in enumerate(truth)]
    result = run_slam(scans, drifting_odometry(truth, rng), initial=Pose2(*truth[0]))
    at = truth[result.keyframes]
    in_twin = [
        loop for loop in result.loops if at[loop.keyframe, 0] > 8.0 and at[loop.anchor, 0] < 6.0
    ]
    assert in_twin, "the twin's keyframes were never searched for in the first room"
    # Every loop taken joins the places where the scans were truly taken.
    for loop in result.accepted_loops:
        true = relative_motion(at[loop.anchor], at[loop.keyframe])[0]
        off = relative_motion(true, np.array(loop.motion))[0]
        assert np.hypot(off[0], off[1]) < 0.1 and abs(off[2]) < np.deg2rad(1.0), loop
    slam_m, _ = _errors(result.poses, truth)
    assert slam_m.max() < 0.1


def test_a_log_with_odometry_maps_with_its_loops_in_the_view(tmp_path):
    """The ring run written as a segloc log with its drifting odometry: map build with no
    survey finds its poses, and its Foxglove view draws the loops and, as each scan's
    guess, where the odometry alone put it."""
    from test_foxglove import validated_messages

    from segloc_cli.io.mcap_log import write_log

    rng = np.random.default_rng(44)
    world, truth = ring_building(), ring_path()
    scans = [simulate_scan(world, Pose2(*p), SENSOR, rng, 0.1 * i) for i, p in enumerate(truth)]
    odometry = drifting_odometry(truth, rng)
    log = tmp_path / "ring.mcap"
    write_log(log, scans, [(s.time_s, Pose2(*o)) for s, o in zip(scans, odometry, strict=True)])
    run = run_in_process(
        "map", "build", log, "--initial", "1,1,0", "--out", tmp_path / "map.json",
        "--poses-out", tmp_path / "poses.csv", "--mcap", tmp_path / "view.mcap",
        "--loops-out", tmp_path / "loops.csv",
    )  # fmt: skip
    assert run.code == 0, run.err
    found = pd.read_csv(tmp_path / "poses.csv")
    assert np.hypot(found.x_m - truth[:, 0], found.y_m - truth[:, 1]).max() < 0.1
    accepted = int(re.search(r"(\d+) loops? accepted", run.err).group(1))
    assert accepted >= 1
    # Every loop accepted joins two scans where they truly lie, and the solution holds it.
    loops = pd.read_csv(tmp_path / "loops.csv")
    taken = loops[loops.accepted]
    assert len(taken) == accepted and set(loops.status) <= {"ok", "ambiguous", "lost"}
    at = truth[taken.anchor_pose_id - 1], truth[taken.pose_id - 1]
    true = relative_motion(*at)
    np.testing.assert_allclose(taken[["x_m", "y_m"]], true[:, :2], atol=0.1)
    assert (taken.solved_off_m < 0.1).all() and (taken.solved_off_deg < 1.0).all()
    shown = validated_messages(tmp_path / "view.mcap")
    ((_, loops),) = shown["/loops"]
    assert len(loops.entities[0].lines[0].points) == 2 * accepted
    guesses = [(g.pose.position.x, g.pose.position.y) for _, g in shown["/guess"]]
    np.testing.assert_allclose(guesses, odometry[:, :2], atol=1e-6)


def test_the_travel_between_a_keyframe_and_a_submap_takes_the_loops_as_short_cuts():
    travel = list(np.arange(41.0))  # a keyframe every metre
    submaps = [
        _Submap(first, first + 8, np.zeros((0, 4)), np.zeros((9, 3))) for first in (0, 8, 16, 24)
    ]
    # Keyframe 40 ends the fifth submap, begun at keyframe 32: the anchors (the submaps'
    # first keyframes) lie 40, 32, 24 and 16 m back.
    np.testing.assert_array_equal(_graph_travel(travel, submaps, [], 40), [40, 32, 24, 16])
    # A loop from the fifth submap into the first: its anchor is the two submaps' travel
    # away, the second's three, the third's as far by either way.
    np.testing.assert_array_equal(_graph_travel(travel, submaps, [(0, 4)], 40), [16, 24, 24, 16])
    # A loop between the second and the fourth shortens the way to the first and second.
    np.testing.assert_array_equal(_graph_travel(travel, submaps, [(1, 3)], 40), [32, 24, 24, 16])


def _contradicted_graph() -> _Graph:
    """Four keyframes a metre apart along x, each edge pinned to a centimetre; a loop from
    the first to the last that agrees (0), and one that puts the last 2 m aside (1)."""
    graph = _Graph(np.zeros(3), 0.01, 0.2)
    tight = np.diag([1e4, 1e4, 1e4])
    for k in range(1, 4):
        graph.add_edge(k - 1, k, np.array([1.0, 0.0, 0.0]), tight, guess=np.array([k, 0.0, 0.0]))
    graph.add_edge(0, 3, np.array([3.0, 0.01, 0.0]), tight, cauchy=1.0, loop=0)
    graph.add_edge(0, 3, np.array([3.0, 2.0, 0.0]), tight, cauchy=1.0, loop=1)
    return graph


def test_the_final_solve_drops_a_loop_the_others_contradict():
    graph = _contradicted_graph()
    poses, dropped = graph.solved(11.34)
    assert dropped == {1}
    # The loop that agreed stays: the last pose is where the edges and it put it.
    np.testing.assert_allclose(poses[3], [3.0, 0.005, 0.0], atol=0.01)
    # With no bound to fail, nothing is dropped.
    assert graph.solved(np.inf)[1] == set()
    # With no solve left after it, no loop is dropped: a dropped loop is never in the poses.
    assert _contradicted_graph().solved(11.34, rounds=0)[1] == set()


@pytest.mark.parametrize("parallel", [False, True], ids=["here", "worker"])
def test_a_submap_fused_again_is_searched_as_it_is_now(parallel):
    world = ring_building()
    truth = Pose2(1.0, 1.0, 0.3)
    scan = simulate_scan(world, truth, SENSOR, np.random.default_rng(5), 0.0)
    local_map = extract_segments(scan)
    searcher = LoopSearcher(parallel)
    try:
        query = LoopQuery(0, truth.as_array(), LocalizeParams())
        searcher.add_submap(0, world.segments)
        searcher.submit(local_map, scan.points(), [query])
        (first,) = searcher.collect()
        # The submap fused again half a metre along x: the same search finds the scan there.
        searcher.add_submap(0, world.segments + np.array([0.5, 0.0, 0.5, 0.0]))
        searcher.submit(local_map, scan.points(), [query])
        (again,) = searcher.collect()
    finally:
        searcher.close()
    assert first.status == again.status == "ok"
    np.testing.assert_allclose(first.pose, truth.as_array(), atol=0.02)
    np.testing.assert_allclose(again.pose - first.pose, [0.5, 0.0, 0.0], atol=0.02)
