"""Part of a log (``--start``, ``--end``, ``--every``, ``--scans``) and a track seeded in one
option (``--initial X,Y,THETA_DEG``), on a walk through the hall with drifting odometry in
its own frame, as an imported log has it."""

from __future__ import annotations

import json
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path

import numpy as np
import pytest
from conftest import HALL, HALL_WORLD
from test_cli import assert_one_line_error, read_csv_rows, run_cli

from segloc_cli.geometry import Pose2, wrap_angle
from segloc_cli.io.maps import read_map, read_world
from segloc_cli.io.mcap_log import LogWriter
from segloc_cli.sim import SensorModel, simulate_scan

STEP_M = 0.3
PERIOD_S = 0.2
T0_S = 1000.0
"""The first scan's time: seconds from the log's first scan and the log's own differ."""
FIRST_NUMBER = 101
"""The first scan's number in its source: pose ids are numbers, not places in the log."""
SURVEY_HEADER = "pose_id,time_s,x_m,y_m,theta_deg"


@dataclass(frozen=True)
class Walk:
    dir: Path
    log: Path
    truth: np.ndarray
    """(S, 3) x m, y m, theta rad: the robot's true poses, map frame."""
    odometry: np.ndarray
    """(S, 3): the odometry at each scan, in the odometry's frame (its start at 0, 0, 0)."""
    times_s: np.ndarray
    numbers: np.ndarray


def _walk_poses() -> np.ndarray:
    """Poses every STEP_M along the hall's first surveyed legs, the heading turning along."""
    waypoints = np.loadtxt(HALL / "poses.csv", delimiter=",", skiprows=1)[:4, 2:5]
    waypoints[:, 2] = np.deg2rad(waypoints[:, 2])
    poses = []
    for a, b in pairwise(waypoints):
        n = max(1, int(np.hypot(*(b[:2] - a[:2])) / STEP_M))
        for k in range(n):
            f = k / n
            poses.append([*(a[:2] + f * (b[:2] - a[:2])), a[2] + f * wrap_angle(b[2] - a[2])])
    return np.array(poses)


def _odometry(truth: np.ndarray, rng) -> np.ndarray:
    """Dead reckoning from (0, 0, 0): the true increments, 3 % long and turning 0.5° more
    each step, with noise."""
    odom = [Pose2(0.0, 0.0, 0.0)]
    for a, b in pairwise(truth):
        step = Pose2(*a).inverse().compose(Pose2(*b))
        noisy = Pose2(
            step.x * 1.03 + rng.normal(0, 0.003),
            step.y * 1.03 + rng.normal(0, 0.003),
            step.theta + np.deg2rad(0.5),
        )
        odom.append(odom[-1].compose(noisy))
    return np.array([p.as_array() for p in odom])


@pytest.fixture(scope="module")
def walk(tmp_path_factory) -> Walk:
    folder = tmp_path_factory.mktemp("walk")
    world = read_world(HALL_WORLD)
    truth = _walk_poses()
    odometry = _odometry(truth, np.random.default_rng(5))
    times = T0_S + PERIOD_S * np.arange(len(truth))
    numbers = FIRST_NUMBER + np.arange(len(truth))
    rng = np.random.default_rng(6)
    log = folder / "walk.mcap"
    with LogWriter(log, {"range_max_m": repr(SensorModel().range_max_m)}) as writer:
        for t, pose, odom, number in zip(times, truth, odometry, numbers, strict=True):
            writer.add_odom(float(t), Pose2(*odom))
            scan = simulate_scan(world, Pose2(*pose), SensorModel(), rng, float(t))
            writer.add_scan(scan, number=int(number))
    return Walk(folder, log, truth, odometry, times, numbers)


def _chosen(walk: Walk, start_s: float, end_s: float | None = None, every: int = 1) -> np.ndarray:
    """Indices of the scans from ``start_s`` to ``end_s`` after the first, every ``every``-th."""
    after = walk.times_s - walk.times_s[0]
    inside = (after >= start_s - 1e-9) & (after <= (np.inf if end_s is None else end_s) + 1e-9)
    return np.flatnonzero(inside)[::every]


def _pose_text(pose: np.ndarray) -> str:
    return f"{pose[0]:.6f},{pose[1]:.6f},{np.rad2deg(pose[2]):.6f}"


def _write_guesses(path: Path, walk: Walk, rng) -> Path:
    """A guess per scan, the truth 20 cm per axis and 4° off at most, under the scans' numbers."""
    lines = [SURVEY_HEADER]
    for number, t, (x, y, th) in zip(walk.numbers, walk.times_s, walk.truth, strict=True):
        dx, dy, dth = rng.uniform(-1, 1, 3) * (0.2, 0.2, 4.0)
        lines.append(f"{number},{t:.6f},{x + dx:.6f},{y + dy:.6f},{np.rad2deg(th) + dth:.6f}")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _rows(path: Path) -> list[dict[str, str]]:
    return read_csv_rows(path)[1]


def _errors(rows, walk: Walk) -> tuple[np.ndarray, np.ndarray]:
    """Position (m) and heading (°) errors of estimates rows against the truth by pose id."""
    index = np.array([int(r["pose_id"]) for r in rows]) - FIRST_NUMBER
    est = np.array([[float(r[k]) for k in ("x_m", "y_m", "theta_deg")] for r in rows])
    true = walk.truth[index]
    position = np.hypot(*(est[:, :2] - true[:, :2]).T)
    heading = np.abs(np.rad2deg(wrap_angle(np.deg2rad(est[:, 2]) - true[:, 2])))
    return position, heading


def _localize(capsys, walk: Walk, out: Path, *args) -> list[dict[str, str]]:
    result = run_cli(capsys, "localize", walk.log, "--map", HALL_WORLD, "--out", out, *args)
    assert result.code == 0, result.err
    return _rows(out)


# --------------------------------------------------------------------------- part of a log


def test_a_selected_scan_keeps_its_number_and_the_row_of_the_whole_run(walk, tmp_path, capsys):
    """Selected scans are localized as in a run of the whole log: their windows take the
    neighbours the whole log gives them, and their rows their own numbers."""
    guesses = _write_guesses(tmp_path / "guesses.csv", walk, np.random.default_rng(8))
    whole = _localize(capsys, walk, tmp_path / "whole.csv", "--initial", guesses)
    part = _localize(
        capsys, walk, tmp_path / "part.csv", "--initial", guesses,
        "--start", "1.5", "--end", "4.5", "--every", "3",
    )  # fmt: skip
    chosen = _chosen(walk, 1.5, 4.5, every=3)
    assert [int(r["pose_id"]) for r in part] == list(walk.numbers[chosen])
    assert int(part[0]["window_scans"]) > 1, "the log has odometry: scans get windows"
    by_id = {r["pose_id"]: r for r in whole}
    for row in part:
        assert {**row, "runtime_ms": ""} == {**by_id[row["pose_id"]], "runtime_ms": ""}
    capped = _localize(
        capsys, walk, tmp_path / "capped.csv", "--initial", guesses, "--start", "1.5",
        "--scans", "4",
    )  # fmt: skip
    assert [int(r["pose_id"]) for r in capped] == list(walk.numbers[_chosen(walk, 1.5)[:4]])


def test_a_run_file_repeats_the_selection_and_the_initial_pose(walk, tmp_path, capsys):
    chosen = _chosen(walk, 2.0, every=2)[:5]
    seed = _pose_text(walk.truth[chosen[0]])
    first = _localize(
        capsys, walk, tmp_path / "first.csv", "--track", "--initial", seed,
        "--start", "2", "--every", "2", "--scans", "5",
    )  # fmt: skip
    again = run_cli(
        capsys, "localize", walk.log, "--config", tmp_path / "first.run.toml",
        "--out", tmp_path / "again.csv",
    )  # fmt: skip
    assert again.code == 0, again.err
    assert [int(r["pose_id"]) for r in first] == list(walk.numbers[chosen])
    strip = [{**r, "runtime_ms": ""} for r in first]
    assert [{**r, "runtime_ms": ""} for r in _rows(tmp_path / "again.csv")] == strip


def test_map_build_of_a_selection_is_the_map_of_those_scans(walk, tmp_path, capsys):
    survey = tmp_path / "survey.csv"
    lines = [SURVEY_HEADER]
    for number, t, (x, y, th) in zip(walk.numbers, walk.times_s, walk.truth, strict=True):
        lines.append(f"{number},{t:.6f},{x:.6f},{y:.6f},{np.rad2deg(th):.6f}")
    survey.write_text("\n".join(lines) + "\n", encoding="utf-8")
    chosen = _chosen(walk, 0.0, 3.0, every=2)
    part = tmp_path / "part-survey.csv"
    part.write_text("\n".join([lines[0], *(lines[1 + i] for i in chosen)]) + "\n")
    selected, expected = tmp_path / "selected.json", tmp_path / "expected.json"
    args = ("map", "build", walk.log, "--out")
    result = run_cli(capsys, *args, selected, "--survey", survey, "--end", "3", "--every", "2")
    assert result.code == 0, result.err
    assert run_cli(capsys, *args, expected, "--survey", part).code == 0
    np.testing.assert_array_equal(read_map(selected), read_map(expected))
    assert json.loads(selected.read_text())["source"]["scans_used"] == chosen.size


def test_info_says_how_long_the_log_is_and_what_a_selection_holds(walk, capsys):
    result = run_cli(capsys, "info", walk.log)
    assert result.code == 0, result.err
    length = walk.times_s[-1] - walk.times_s[0]
    assert f"length:    {length:.3f} s from the first scan at {T0_S:.3f} s" in result.out
    assert "selected:" not in result.out
    result = run_cli(capsys, "info", walk.log, "--start", "1", "--end", "3", "--every", "2")
    chosen = _chosen(walk, 1.0, 3.0, every=2)
    line = next(ln for ln in result.out.splitlines() if ln.startswith("selected:"))
    assert line.startswith(f"selected:  {chosen.size} scans"), line
    numbers = walk.numbers[chosen]
    assert f"numbers {numbers[0]}–{numbers[-1]}" in line, line


@pytest.mark.parametrize(
    ("args", "fragments"),
    [
        (("--start", "30"), ("--start 30 selects no scan", "span 0 to")),
        (("--start", "3", "--end", "1"), ("--end", "before --start 3")),
        (("--every", "0"), ("--every", "x>=1")),
    ],
)
def test_a_selection_that_holds_no_scan_is_one_line(walk, tmp_path, capsys, args, fragments):
    out = tmp_path / "est.csv"
    result = run_cli(capsys, "localize", walk.log, "--map", HALL_WORLD, "--out", out, *args)
    assert_one_line_error(result, *fragments)
    assert not out.exists()


# --------------------------------------------------------------------------- one-option seed


def test_a_track_of_every_other_scan_starts_at_the_pose_given(walk, tmp_path, capsys):
    """--initial X,Y,THETA_DEG seeds the first selected scan; the track takes the odometry
    from each selected scan to the next, two scans apart, whose frame is not the map's."""
    chosen = _chosen(walk, 1.0, every=2)
    seed = walk.truth[chosen[0]] + (0.15, -0.1, np.deg2rad(4.0))
    rows = _localize(
        capsys, walk, tmp_path / "track.csv", "--track", "--initial", _pose_text(seed),
        "--start", "1", "--every", "2",
    )  # fmt: skip
    assert [int(r["pose_id"]) for r in rows] == list(walk.numbers[chosen])
    assert float(rows[0]["init_x_m"]) == pytest.approx(seed[0], abs=1e-6)
    assert {r["status"] for r in rows} == {"ok"}
    position, heading = _errors(rows, walk)
    assert position.max() < 0.03 and heading.max() < 0.5, (position.max(), heading.max())


def test_an_initial_pose_without_track_is_carried_by_the_odometry(walk, tmp_path, capsys):
    """Without --track, each selected scan's guess is the pose given moved by the odometry
    from the first selected scan to it."""
    chosen = _chosen(walk, 2.0, 5.0)
    seed = walk.truth[chosen[0]]
    rows = _localize(
        capsys, walk, tmp_path / "est.csv", "--initial", _pose_text(seed), "--start", "2",
        "--end", "5",
    )  # fmt: skip
    assert [int(r["pose_id"]) for r in rows] == list(walk.numbers[chosen])
    start = Pose2(*seed).compose(Pose2(*walk.odometry[chosen[0]]).inverse())
    for row, i in zip(rows, chosen, strict=True):
        expected = start.compose(Pose2(*walk.odometry[i]))
        guess = [float(row[k]) for k in ("init_x_m", "init_y_m", "init_theta_deg")]
        np.testing.assert_allclose(guess[:2], [expected.x, expected.y], atol=1e-5)
        assert wrap_angle(np.deg2rad(guess[2]) - expected.theta) == pytest.approx(0, abs=1e-6)
    position, _ = _errors(rows, walk)
    assert position.max() < 0.03


@pytest.mark.parametrize(
    ("args", "fragment"), [(("--global",), "--global"), (("LOG",), "not of 2 logs")]
)
def test_an_initial_pose_is_refused_where_it_means_nothing(walk, tmp_path, capsys, args, fragment):
    args = [walk.log if arg == "LOG" else arg for arg in args]
    result = run_cli(
        capsys, "localize", walk.log, *args, "--map", HALL_WORLD, "--out", tmp_path / "e.csv",
        "--initial", "11,1.6,90",
    )  # fmt: skip
    assert_one_line_error(result, "--initial X,Y,THETA_DEG", fragment)


def test_an_initial_pose_out_of_bounds_is_one_line(walk, tmp_path, capsys):
    result = run_cli(
        capsys, "localize", walk.log, "--map", HALL_WORLD, "--out", tmp_path / "e.csv",
        "--initial", "1e9,0,90",
    )  # fmt: skip
    assert_one_line_error(result, "--initial", "X_M,Y_M,THETA_DEG")


@pytest.mark.parametrize("pose", ["0,0", "1,2,3,4"])
def test_an_initial_pose_of_other_than_three_numbers_is_one_line(walk, tmp_path, capsys, pose):
    result = run_cli(
        capsys, "localize", walk.log, "--map", HALL_WORLD, "--out", tmp_path / "e.csv",
        "--track", "--initial", pose,
    )  # fmt: skip
    assert_one_line_error(result, f"'{pose}' is", "X_M,Y_M,THETA_DEG")


def test_no_guess_near_any_scan_names_the_first_scan_and_the_tolerance(walk, tmp_path, capsys):
    late = tmp_path / "late.csv"
    late.write_text(f"{SURVEY_HEADER}\n1,{T0_S + 500:.3f},11.0,1.6,90\n", encoding="utf-8")
    result = run_cli(
        capsys, "localize", walk.log, "--map", HALL_WORLD, "--out", tmp_path / "e.csv",
        "--initial", late, "--tolerance-ms", "20",
    )  # fmt: skip
    assert_one_line_error(
        result, f"first scan is at {T0_S:.3f} s", "within 20 ms", "--initial X,Y,THETA_DEG"
    )
