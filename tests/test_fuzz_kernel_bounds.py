"""The compiled kernels on hostile input, with numba's bounds checks on.

A scan or a map no one tuned segloc for must end in a status, never in a read
outside an array (which, unchecked, corrupts memory and kills the process with
no message). One subprocess runs the localizer's every path with
``NUMBA_BOUNDSCHECK=1`` over a corpus of bad scans and maps, hand-made and drawn
at random; an out-of-bounds index there raises instead of corrupting memory, and
fails. It starts from every kernel compiled with the checks on by ``warmup --all``
into an empty temporary folder (numba keys a cached kernel on its signature and
source, not on the checks, so the checked code must never reach the cache a normal
run loads), and compiles what the corpus's argument types add.

Compiling every kernel takes about 80 s of CPU, the run itself a few: ``make fuzz``
runs it (``SEGLOC_FUZZ_EXAMPLES`` set), ``make test`` skips it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from kernel_caches import WARM_UP, cache_env, run

from segloc_cli.estimates import (
    STATUS_AMBIGUOUS,
    STATUS_LOST,
    STATUS_NO_OVERLAP,
    STATUS_OK,
    STATUS_RECOVERED,
    STATUS_TOO_FEW_SEGMENTS,
)

STATUSES = {
    STATUS_OK,
    STATUS_AMBIGUOUS,
    STATUS_LOST,
    STATUS_TOO_FEW_SEGMENTS,
    STATUS_NO_OVERLAP,
    STATUS_RECOVERED,
}

CORPUS = textwrap.dedent(
    r'''
    import json
    from dataclasses import replace

    import numpy as np

    from segloc_cli.method.extract import extract_segments
    from segloc_cli.method.score_raster import score_raster
    from segloc_cli.geometry import Pose2
    from segloc_cli.method.localize import Localizer
    from segloc_cli.method.overlap import candidate_pairs, coarse_to_fine, overlap_at_poses
    from segloc_cli.method.refine import nearest_segments, refine_pose
    from segloc_cli.scan import Scan
    from segloc_cli.method.search import HypothesisSearch
    from segloc_cli.sim import NOISE_FREE, random_free_poses, random_world, simulate_scan
    from segloc_cli.method.spatial import SegmentGrid
    from segloc_cli.method.tracking import track_scans

    np.seterr(all="ignore")
    rng = np.random.default_rng(11)
    world = random_world(rng)
    truth = Pose2(*random_free_poses(world, 1, rng)[0])
    good = simulate_scan(world, truth, NOISE_FREE, rng, 0.0)


    def raw_scan(angles, ranges):
        """A Scan built without its checks: what a reader with a bug could hand on."""
        scan = object.__new__(Scan)
        for name, value in (("time_s", 0.0), ("angles_rad", np.asarray(angles, float)),
                            ("ranges_m", np.asarray(ranges, float)),
                            ("range_max_m", float("inf")), ("intensities", np.zeros(0))):
            object.__setattr__(scan, name, value)
        return scan


    a, r = good.angles_rad, good.ranges_m
    nan_angles = a.copy(); nan_angles[::3] = np.nan
    inf_angles = a.copy(); inf_angles[::5] = np.inf
    huge = r.copy(); huge[::4] = 1e30
    far = r.copy(); far[::2] = 1e6
    scans = {
        "good": good,
        "nan_angles": raw_scan(nan_angles, r),
        "inf_angles": raw_scan(inf_angles, r),
        "all_nan": raw_scan(np.full(a.size, np.nan), r),
        "ranges_1e30": raw_scan(a, huge),
        "ranges_1e6": raw_scan(a, far),
        "inf_ranges": raw_scan(a, np.full(a.size, np.inf)),
        "empty": raw_scan(np.zeros(0), np.zeros(0)),
        "one_point": raw_scan([0.3], [2.0]),
        "two_points": raw_scan([0.3, 1.2], [2.0, 3.0]),
        "one_ray": raw_scan(np.zeros(a.size), r),
    }
    segments_for = {name: extract_segments(scan) for name, scan in scans.items()}
    # Local maps that extraction would not make but a caller could pass.
    hostile_local = {
        "nan_segment": np.array([[np.nan, 0.0, 1.0, 1.0], [0.0, 0.0, 1.0, 0.0],
                                 [0.0, 0.0, 0.0, 1.0]]),
        "huge_segment": np.array([[1e30, 0.0, 1e30, 1.0], [0.0, 0.0, 1.0, 0.0],
                                  [0.0, 0.0, 0.0, 1.0]]),
        "zero_segment": np.array([[1.0, 1.0, 1.0, 1.0], [0.0, 0.0, 1.0, 0.0],
                                  [0.0, 0.0, 0.0, 1.0]]),
    }
    maps = {
        "room": world.segments,
        "one_segment": np.array([[0.0, 0.0, 4.0, 0.0]]),
        "two_segments": np.array([[0.0, 0.0, 4.0, 0.0], [0.0, 0.0, 0.0, 3.0]]),
        "tiny": np.array([[0.0, 0.0, 0.01, 0.0], [0.0, 0.0, 0.0, 0.01], [0.01, 0.0, 0.0, 0.01]]),
        # As wide as a map may be (2 km), so its raster takes coarser cells.
        "huge_legal": np.vstack([world.segments, [[1990.0, 1990.0, 2000.0, 2000.0]]]),
    }
    guesses = {
        "near": Pose2(truth.x + 0.3, truth.y - 0.2, truth.theta + 0.05),
        "nan": Pose2(float("nan"), float("nan"), float("nan")),
        "far": Pose2(1e30, -1e30, 1e30),
    }


    def emit(**row):
        print(json.dumps(row), flush=True)


    rows = 0
    for map_name, segments in maps.items():
        localizer = Localizer.on_map(segments, global_search=True)
        two_stage = localizer.with_params(replace(localizer.params, refine=None))
        small = map_name != "huge_legal"
        for scan_name, scan in scans.items():
            local, points = segments_for[scan_name], scan.points()
            for guess_name, guess in guesses.items():
                if not small and guess_name != "near":
                    continue
                for how, matcher in (("robust", localizer), ("two_stage", two_stage)):
                    est = matcher.localize(local, guess, points)
                    emit(map=map_name, scan=scan_name, guess=guess_name, how=how,
                         status=est.status)
                    rows += 1
            if small or scan_name == "one_point":  # a global search of 2 km takes long
                est = localizer.localize_global(local, points)
                emit(map=map_name, scan=scan_name, how="global", status=est.status)
                rows += 1
        if small:
            for local_name, local in hostile_local.items():
                est = localizer.localize(local, guesses["near"], good.points())
                emit(map=map_name, scan=local_name, how="robust", status=est.status)
                rows += 1
                p = localizer.params
                result = coarse_to_fine(segments, local, guesses["near"], grid_m=p.grid_m,
                                        dtheta_deg=p.dtheta_deg, iterations=p.iterations,
                                        ratio=p.ratio, recentres=p.recentres)
                overlap_at_poses(segments, local, np.array([[0.0, 0.0, 0.0]]), 0.1)
                candidate_pairs(segments, local, guesses["near"], 1.0, 0.1, 0.1)
                assert result.track.shape[1] == 3
            order = ["good", "ranges_1e30", "empty", "one_point", "good", "all_nan", "good"]
            track = [scans[name] for name in order]
            odometry = [truth] * len(track)
            for row in track_scans(track, odometry, guesses["near"], range(len(track)),
                                   localizer):
                emit(map=map_name, scan="track", how="track", status=row["status"])
                rows += 1

    # A seeded random corpus, as the fuzz suites draw theirs: every kind of value mixed in.
    odd = np.array([np.nan, np.inf, -np.inf, 1e30, -1e30, 1e6, 0.0, -1.0, 1e-300])
    room = Localizer.on_map(world.segments)
    room_two_stage = room.with_params(replace(room.params, refine=None))
    for k in range(150):
        n = int(rng.integers(0, 400))
        angles = np.sort(rng.uniform(-np.pi, np.pi, n))
        ranges = rng.uniform(0.1, 15.0, n)
        for values in (angles, ranges):
            hit = rng.random(n) < rng.choice([0.0, 0.05, 0.5])
            values[hit] = rng.choice(odd, int(hit.sum()))
        scan = raw_scan(angles, ranges)
        local = extract_segments(scan)
        for how, matcher in (("random", room), ("random_two_stage", room_two_stage)):
            est = matcher.localize(local, guesses["near"], scan.points())
            emit(map="room", scan=f"random{k}", guess="near", how=how, status=est.status)
            rows += 1

    # The kernels called directly with points no Scan would give.
    bad_points = np.array([[np.nan, 0.0], [np.inf, -np.inf], [1e30, -1e30], [1e6, 3.0],
                           [0.5, 0.5], [-1e300, 1e-300]])
    search = HypothesisSearch(world.segments)
    for heading in (0.0, np.nan, np.inf):
        search.search(bad_points, np.array([heading]), np.array([truth.x, truth.y]), 2.0)
    search.search(bad_points, np.array([0.0]), np.array([np.nan, 1e300]), 2.0, 30.0)
    search.search(bad_points, np.array([0.0]), np.array([1e18, -1e18]), 2.0)
    search.fine.lookup(bad_points)
    refine_pose(bad_points, world.segments, guesses["near"])
    refine_pose(bad_points, world.segments, guesses["nan"])
    nearest_segments(bad_points, world.segments)
    raster = score_raster(np.array([[0.0, 0.0, 1.0, 0.0]]), 0.05, 0.1, 0.1)
    raster.lookup(bad_points)
    grid = SegmentGrid(world.segments)
    for centre, radius in (((np.nan, 0.0), 1.0), ((0.0, 0.0), np.inf), ((1e30, 1e30), 5.0),
                           ((0.0, 0.0), np.nan), ((0.0, 0.0), 1e300)):
        grid.near(centre, radius)
    print(json.dumps({"done": rows}), flush=True)
    '''
)


def checked_env(cache_dir: Path) -> dict[str, str]:
    """This environment, with numba's bounds checks on and its cache in ``cache_dir``."""
    return dict(cache_env(cache_dir), NUMBA_BOUNDSCHECK="1")


@pytest.mark.skipif(
    "SEGLOC_FUZZ_EXAMPLES" not in os.environ,
    reason="compiles every kernel with bounds checks (about 80 s of CPU): make fuzz runs it",
)
def test_every_path_on_hostile_input_stays_inside_its_arrays(tmp_path):
    env = checked_env(tmp_path / "numba")
    run([*WARM_UP, "--all"], env)
    script = tmp_path / "corpus.py"
    script.write_text(CORPUS)
    done = subprocess.run(
        [sys.executable, str(script)], env=env, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr[-4000:]
    lines = [json.loads(line) for line in done.stdout.splitlines()]
    rows, (last,) = lines[:-1], lines[-1:]
    assert last == {"done": len(rows)}
    assert len(rows) > 550
    assert {row["status"] for row in rows} <= STATUSES
    by_case = {(row["map"], row["scan"], row.get("guess"), row["how"]): row for row in rows}
    # The scans that cannot pin a pose are never trusted, whatever the map.
    for scan in ("empty", "one_point", "two_points", "one_ray", "all_nan"):
        for how in ("robust", "global"):
            assert (
                by_case[("room", scan, "near" if how == "robust" else None, how)]["status"]
                == STATUS_TOO_FEW_SEGMENTS
            ), (scan, how)
    # A good scan through it all still localizes.
    assert by_case[("room", "good", "near", "robust")]["status"] == STATUS_OK
    assert by_case[("room", "good", None, "global")]["status"] == STATUS_OK
    tracked = [row["status"] for row in rows if row["map"] == "room" and row["how"] == "track"]
    assert tracked[2:4] == [STATUS_TOO_FEW_SEGMENTS] * 2
    assert tracked[5] == STATUS_TOO_FEW_SEGMENTS
    assert tracked[6] == STATUS_OK
