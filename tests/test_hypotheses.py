"""Places that look alike: every distinct pose that explains a scan is listed, and the answer
is not trusted when another fits as well."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest
from precision import assert_within_precision
from test_cli import run_cli
from test_foxglove import validated_messages

from segloc_cli.config import LocalizeParams, SearchParams
from segloc_cli.estimates import HYPOTHESIS_COLUMNS, STATUS_AMBIGUOUS, PoseTable
from segloc_cli.geometry import Pose2, wrap_angle
from segloc_cli.io.maps import write_world
from segloc_cli.io.tables import HypothesesWriter, write_pose_table
from segloc_cli.method.extract import extract_segments
from segloc_cli.method.localize import Localizer
from segloc_cli.method.search import distinct
from segloc_cli.sim import (
    SensorModel,
    random_free_poses,
    repeating_corridor,
    simulate_scan,
    symmetric_room,
)

SENSOR = SensorModel(readings=256)
RIGHT_M, RIGHT_DEG = 0.3, 3.0


def _right(pose: Pose2, truth: Pose2) -> bool:
    position = math.hypot(pose.x - truth.x, pose.y - truth.y)
    heading = abs(math.degrees(wrap_angle(pose.theta - truth.theta)))
    return position <= RIGHT_M and heading <= RIGHT_DEG


def _globally(world, truths, rng, sensor=SENSOR, params=None):
    localizer = Localizer.on_map(world.segments, params, global_search=True)
    for truth in truths:
        scan = simulate_scan(world, truth, sensor, rng, 0.0)
        yield localizer.localize_global(extract_segments(scan), scan.points()), truth


def _check_listing(est) -> None:
    """The listing's own rules: the answer first, the runner-up second, all pairwise
    distinct, best score first, each with a probability."""
    listed = est.hypotheses
    assert listed[0].pose == est.pose and listed[0].confidence == est.confidence
    if len(listed) > 1:
        assert listed[1].pose == est.runner_up
    for k, h in enumerate(listed):
        assert distinct([o.pose for o in listed[:k]], h.pose, 0.3, 3.0)
        assert 0.0 <= h.confidence <= 1.0
    assert [h.score for h in listed] == sorted((h.score for h in listed), reverse=True)


@pytest.mark.parametrize("seed", [11, 12])
def test_in_a_symmetric_room_the_truth_and_its_twin_are_listed_and_the_answer_is_ambiguous(seed):
    rng = np.random.default_rng(seed)
    world = symmetric_room(rng)
    centre = np.array([world.segments[:, 0::2].max(), world.segments[:, 1::2].max()]) / 2.0
    for est, truth in _globally(world, [Pose2(*p) for p in random_free_poses(world, 3, rng)], rng):
        _check_listing(est)
        assert est.status == STATUS_AMBIGUOUS
        twin = Pose2(2 * centre[0] - truth.x, 2 * centre[1] - truth.y, truth.theta + math.pi)
        for expected in (truth, twin):
            assert any(_right(h.pose, expected) for h in est.hypotheses)


def test_along_a_corridor_of_repeating_doors_the_truth_is_listed_and_the_answer_ambiguous():
    """An 8 m scanner in an 80 m corridor of doors at one period, on both walls alike: some
    thirty poses (each stretch, facing either way) give the same scan, so the search must
    hand on enough of them for the truth to be among those listed."""
    rng = np.random.default_rng(21)
    world = repeating_corridor(rng, length_m=80.0)
    sensor = SensorModel(readings=256, range_max_m=8.0)
    params = LocalizeParams(search=SearchParams(hypotheses=40))
    truths = [Pose2(x, 1.1, rng.uniform(-0.3, 0.3)) for x in (37.0, 41.5)]
    for est, truth in _globally(world, truths, rng, sensor, params):
        _check_listing(est)
        assert est.status == STATUS_AMBIGUOUS
        assert len(est.hypotheses) > 20
        assert any(_right(h.pose, truth) for h in est.hypotheses)


def test_the_hypotheses_file_has_a_row_per_listed_pose_ranked_from_the_answer(tmp_path):
    row = {
        "pose_id": 7, "time_s": 1.5,
        "hypotheses": [
            {"x_m": 1.0, "y_m": 2.0, "theta_deg": 30.0, "inlier_ratio": 0.9, "score": 0.8,
             "confidence": 0.6},
            {"x_m": -1.0, "y_m": 2.5, "theta_deg": -150.0, "inlier_ratio": 0.88, "score": 0.79,
             "confidence": 0.3},
            {"x_m": 4.0, "y_m": 0.0, "theta_deg": 0.0, "inlier_ratio": 0.5, "score": 0.4,
             "confidence": float("nan")},
        ],
    }  # fmt: skip
    with HypothesesWriter(tmp_path / "h.csv", limit=2) as writer:
        writer.write_row(row)
        writer.write_row({"pose_id": 8, "time_s": 2.0})  # a row with none writes nothing
    with (tmp_path / "h.csv").open(encoding="utf-8") as stream:
        lines = list(csv.reader(stream))
    assert lines[0] == HYPOTHESIS_COLUMNS
    assert lines[1:] == [
        ["7", "1.5", "1", "1.0", "2.0", "30.0", "0.9", "0.8", "0.6"],
        ["7", "1.5", "2", "-1.0", "2.5", "-150.0", "0.88", "0.79", "0.3"],
    ]


def test_localize_writes_the_hypotheses_beside_the_estimates(tmp_path, capsys):
    rng = np.random.default_rng(31)
    world = symmetric_room(rng)
    write_world(tmp_path / "room.json", world)
    truths = random_free_poses(world, 3, rng)
    write_pose_table(
        tmp_path / "truth.csv", PoseTable(np.arange(1, 4), np.arange(1.0, 4.0), truths)
    )
    sim = [
        "simulate",
        tmp_path / "room.json",
        "--poses",
        tmp_path / "truth.csv",
        "--out",
        tmp_path / "sim",
        "--readings",
        "256",
        "--init-errors",
        "uniform:0.5,5",
    ]
    assert run_cli(capsys, *sim).code == 0
    out, view = tmp_path / "est.csv", tmp_path / "run.mcap"
    args = ["localize", tmp_path / "sim" / "log.mcap", "--map", tmp_path / "room.json", "--global",
            "--out", out, "--hypotheses", "2", "--mcap", view]  # fmt: skip
    result = run_cli(capsys, *args)
    assert result.code == 0, result.err
    assert "est.hypotheses.csv: up to 2 distinct poses per scan" in result.err
    estimates = list(csv.DictReader(out.open(encoding="utf-8")))
    listed = list(csv.DictReader((tmp_path / "est.hypotheses.csv").open(encoding="utf-8")))
    assert [h["rank"] for h in listed] == ["1", "2"] * len(estimates)
    for row, first, second in zip(estimates, listed[0::2], listed[1::2], strict=True):
        assert row["status"] == "ambiguous"
        for key in ("pose_id", "time_s", "x_m", "y_m", "theta_deg", "inlier_ratio", "confidence"):
            assert first[key] == row[key]
        for key in ("x_m", "y_m", "theta_deg"):
            assert second[key] == row[f"runner_up_{key}"]
    assert "hypotheses = 2" in (tmp_path / "est.run.toml").read_text(encoding="utf-8")

    # The run view shows every hypothesis besides the answer, all of them, not only K.
    shown = validated_messages(view)["/hypotheses"]
    assert len(shown) == len(estimates)
    for (_, poses), row in zip(shown, estimates, strict=True):
        assert poses.frame_id == "world" and len(poses.poses) >= 1
        first = poses.poses[0].position
        # The view holds the pose as made, the CSV to the micrometre.
        csv_xy = [float(row["runner_up_x_m"]), float(row["runner_up_y_m"])]
        assert_within_precision(csv_xy, [first.x, first.y], "m")
