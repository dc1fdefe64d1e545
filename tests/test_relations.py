"""Relative-pose error on hand-made trajectories: exact values, matching, files and formats."""

from __future__ import annotations

import csv
import io
import json
import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from precision import assert_at_precision, assert_within_precision

from segloc_cli.errors import InputError
from segloc_cli.estimates import ESTIMATE_COLUMNS, Relations
from segloc_cli.geometry import Pose2, relative_motion
from segloc_cli.io.relations import read_relations
from segloc_cli.numbers import unit_of
from segloc_cli.scoring.relations import (
    CSV_COLUMNS,
    PUBLISHED,
    PUBLISHED_SQUARED,
    format_relations,
    relation_errors,
    trajectory_from_estimates,
)

# A square-ish walk with turns, one pose a second (x m, y m, theta rad, world frame).
TIMES_S = np.arange(6, dtype=float)
TRUTH = np.array(
    [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [2.0, 0.5, np.pi / 4],
        [2.5, 1.5, np.pi / 2],
        [2.0, 3.0, 3.0],
        [0.5, 3.0, -3.0],
    ]
)
PAIRS = [(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (0, 3), (1, 5)]


def make_relations(truth: np.ndarray, pairs=PAIRS, times_s=TIMES_S) -> Relations:
    """Reference relations between the given pose pairs, computed with ``Pose2``."""
    deltas = []
    for i, j in pairs:
        motion = Pose2(*truth[i]).inverse().compose(Pose2(*truth[j]))
        deltas.append(motion.as_array())
    return Relations(
        t1_s=np.array([times_s[i] for i, _ in pairs], dtype=float),
        t2_s=np.array([times_s[j] for _, j in pairs], dtype=float),
        delta=np.array(deltas),
    )


def rigid(poses: np.ndarray, x_m: float, y_m: float, theta_rad: float) -> np.ndarray:
    """Every pose moved by the same world-frame rigid transform."""
    moved = [Pose2(x_m, y_m, theta_rad).compose(Pose2(*p)).as_array() for p in poses]
    return np.array(moved)


def md_rows(text: str) -> list[list[str]]:
    lines = [line for line in text.splitlines() if line.startswith("|")]
    return [[cell.strip() for cell in line.strip("|").split("|")] for line in lines]


# --- the metric ----------------------------------------------------------------------------


def test_relative_motion_matches_pose2():
    rng = np.random.default_rng(3)
    a = np.column_stack([rng.uniform(-5, 5, (20, 2)), rng.uniform(-np.pi, np.pi, 20)])
    b = np.column_stack([rng.uniform(-5, 5, (20, 2)), rng.uniform(-np.pi, np.pi, 20)])
    got = relative_motion(a, b)
    for row, p, q in zip(got, a, b, strict=True):
        want = Pose2(*p).inverse().compose(Pose2(*q)).as_array()
        np.testing.assert_allclose(row[:2], want[:2], atol=1e-12)
        assert math.isclose(math.remainder(row[2] - want[2], 2 * math.pi), 0.0, abs_tol=1e-12)


def test_perfect_trajectory_has_zero_error():
    errors = relation_errors(TIMES_S, TRUTH, make_relations(TRUTH))
    assert errors.used == len(PAIRS) and errors.skipped == 0
    np.testing.assert_allclose(errors.trans_m, 0.0, atol=1e-12)
    np.testing.assert_allclose(errors.rot_deg, 0.0, atol=1e-10)
    assert errors.index.tolist() == list(range(len(PAIRS)))


def test_constant_heading_offset_about_the_origin_gives_zero_error():
    # A heading offset alone (poses' headings + 0.3 rad, positions unchanged) is NOT a rigid
    # transform and does change relative motions; rotating the whole trajectory is one.
    relations = make_relations(TRUTH)
    rotated = rigid(TRUTH, 0.0, 0.0, 0.3)
    errors = relation_errors(TIMES_S, rotated, relations)
    np.testing.assert_allclose(errors.trans_m, 0.0, atol=1e-12)
    np.testing.assert_allclose(errors.rot_deg, 0.0, atol=1e-10)

    headings_only = TRUTH + np.array([0.0, 0.0, 0.3])
    skewed = relation_errors(TIMES_S, headings_only, relations)
    np.testing.assert_allclose(skewed.rot_deg, 0.0, atol=1e-10)
    # Pose 0 → 1 is 1 m straight ahead; seen from a heading 0.3 rad off it is a 1 m chord
    # of a 0.3 rad arc away from the reference motion.
    assert skewed.trans_m[PAIRS.index((0, 1))] == pytest.approx(2 * math.sin(0.15))


@settings(max_examples=50, deadline=None)
@given(
    x_m=st.floats(-100, 100),
    y_m=st.floats(-100, 100),
    theta_rad=st.floats(-math.pi, math.pi),
    noise_seed=st.integers(0, 2**32 - 1),
)
def test_errors_are_invariant_to_a_global_rigid_transform(x_m, y_m, theta_rad, noise_seed):
    rng = np.random.default_rng(noise_seed)
    noisy = TRUTH + rng.normal(0.0, [0.05, 0.05, 0.02], TRUTH.shape)
    relations = make_relations(TRUTH)
    before = relation_errors(TIMES_S, noisy, relations)
    after = relation_errors(TIMES_S, rigid(noisy, x_m, y_m, theta_rad), relations)
    np.testing.assert_allclose(after.trans_m, before.trans_m, atol=1e-9)
    np.testing.assert_allclose(after.rot_deg, before.rot_deg, atol=1e-7)


def test_one_pose_displaced_by_10_cm_gives_0_1_m_on_its_relations_only():
    relations = make_relations(TRUTH)
    moved = TRUTH.copy()
    moved[3, :2] += 0.1 * np.array([0.6, -0.8])  # 10 cm, in a direction unrelated to the frames
    errors = relation_errors(TIMES_S, moved, relations)
    touching = np.array([3 in pair for pair in PAIRS])
    np.testing.assert_allclose(errors.trans_m[touching], 0.1, rtol=0, atol=1e-12)
    np.testing.assert_allclose(errors.trans_m[~touching], 0.0, atol=1e-12)
    np.testing.assert_allclose(errors.rot_deg, 0.0, atol=1e-10)


def test_heading_error_of_one_pose_shows_as_rotation_error_on_its_relations():
    relations = make_relations(TRUTH)
    turned = TRUTH.copy()
    turned[0, 2] += np.deg2rad(2.0)
    errors = relation_errors(TIMES_S, turned, relations)
    touching = np.array([0 in pair for pair in PAIRS])
    np.testing.assert_allclose(errors.rot_deg[touching], 2.0, atol=1e-9)
    np.testing.assert_allclose(errors.rot_deg[~touching], 0.0, atol=1e-9)
    # Pose 1 lies 1 m ahead of pose 0: a 2° turn of pose 0 misplaces it by 2·sin(1°) m.
    assert errors.trans_m[PAIRS.index((0, 1))] == pytest.approx(2 * math.sin(math.radians(1.0)))


def test_rotation_error_wraps_at_180_degrees():
    times_s = np.array([0.0, 1.0])
    # Reference turn +179°, estimated −179° (+181°): 2° apart, not 358°.
    relations = Relations(
        t1_s=np.array([0.0]), t2_s=np.array([1.0]), delta=np.array([[0.0, 0.0, np.deg2rad(179)]])
    )
    poses = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, np.deg2rad(-179)]])
    errors = relation_errors(times_s, poses, relations)
    assert errors.rot_deg[0] == pytest.approx(2.0)
    # Exactly opposite headings: 180°, never negative.
    poses[1, 2] = np.deg2rad(-1.0)
    assert relation_errors(times_s, poses, relations).rot_deg[0] == pytest.approx(180.0)


def test_reference_motion_is_in_the_frame_of_the_first_pose():
    # Robot at (1, 1) facing +y moves 2 m along world +y: forward 2 m in its own frame.
    times_s = np.array([0.0, 1.0])
    poses = np.array([[1.0, 1.0, np.pi / 2], [1.0, 3.0, np.pi / 2]])
    forward = Relations(np.array([0.0]), np.array([1.0]), np.array([[2.0, 0.0, 0.0]]))
    sideways = Relations(np.array([0.0]), np.array([1.0]), np.array([[0.0, 2.0, 0.0]]))
    assert relation_errors(times_s, poses, forward).trans_m[0] == pytest.approx(0.0, abs=1e-12)
    assert relation_errors(times_s, poses, sideways).trans_m[0] == pytest.approx(2 * math.sqrt(2))


# --- matching ------------------------------------------------------------------------------


def test_matching_within_and_outside_the_tolerance():
    relations = make_relations(TRUTH)
    # Estimates 40 ms late everywhere except pose 5, which is 60 ms late.
    late_s = np.full(len(TIMES_S), 0.04)
    late_s[5] = 0.06
    errors = relation_errors(TIMES_S + late_s, TRUTH, relations, tolerance_s=0.05)
    uses_5 = np.array([5 in pair for pair in PAIRS])
    assert errors.used == int(np.count_nonzero(~uses_5))
    assert errors.skipped == int(np.count_nonzero(uses_5))
    assert errors.index.tolist() == np.flatnonzero(~uses_5).tolist()
    np.testing.assert_allclose(errors.trans_m, 0.0, atol=1e-12)

    wider = relation_errors(TIMES_S + late_s, TRUTH, relations, tolerance_s=0.06)
    assert (wider.used, wider.skipped) == (len(PAIRS), 0)


def test_nearest_estimate_is_used_and_unsorted_estimates_are_fine():
    relations = make_relations(TRUTH)
    # Extra wrong estimates 30 ms from every true one must lose to the exact ones.
    decoys = TRUTH + np.array([5.0, 5.0, 1.0])
    times_s = np.concatenate([TIMES_S + 0.03, TIMES_S])[::-1]
    poses = np.concatenate([decoys, TRUTH])[::-1]
    errors = relation_errors(times_s, poses, relations)
    assert errors.used == len(PAIRS)
    np.testing.assert_allclose(errors.trans_m, 0.0, atol=1e-12)


def test_nan_poses_are_skipped_not_matched_elsewhere():
    relations = make_relations(TRUTH)
    failed = TRUTH.copy()
    failed[2] = np.nan
    errors = relation_errors(TIMES_S, failed, relations)
    uses_2 = np.array([2 in pair for pair in PAIRS])
    assert errors.skipped == int(np.count_nonzero(uses_2))
    assert errors.used == int(np.count_nonzero(~uses_2))
    assert np.all(np.isfinite(errors.trans_m)) and np.all(np.isfinite(errors.rot_deg))


def test_no_match_at_all_gives_empty_errors_and_nan_summary():
    errors = relation_errors(TIMES_S + 100.0, TRUTH, make_relations(TRUTH))
    assert (errors.used, errors.skipped) == (0, len(PAIRS))
    summary = errors.summary()
    assert summary["used"] == 0 and math.isnan(summary["trans_m"]["mean"])
    assert math.isnan(summary["rot_sq_deg2"]["std"])


def test_shape_mismatch_is_rejected():
    with pytest.raises(ValueError, match="poses must be"):
        relation_errors(TIMES_S, TRUTH[:, :2], make_relations(TRUTH))


def test_trajectory_from_estimates_blanks_poses_that_are_not_ok():
    frame = pd.DataFrame(
        {
            "pose_id": [1, 2, 3],
            "time_s": [0.0, 1.0, 2.0],
            "x_m": [0.0, 1.0, 2.0],
            "y_m": [0.0, 0.0, 0.5],
            "theta_deg": [0.0, 0.0, 45.0],
            "status": ["ok", "failed", "ok"],
        }
    ).reindex(columns=ESTIMATE_COLUMNS)
    times_s, poses = trajectory_from_estimates(frame)
    np.testing.assert_array_equal(times_s, [0.0, 1.0, 2.0])
    np.testing.assert_allclose(poses[2], [2.0, 0.5, np.pi / 4])
    assert np.all(np.isnan(poses[1]))
    errors = relation_errors(times_s, poses, make_relations(TRUTH, pairs=[(0, 1), (0, 2)]))
    assert (errors.used, errors.skipped) == (1, 1)
    assert errors.trans_m[0] == pytest.approx(0.0, abs=1e-12)


def test_trajectory_keeps_every_pose_unless_only_ok():
    frame = pd.DataFrame(
        {
            "pose_id": [1, 2, 3],
            "time_s": [0.0, 1.0, 2.0],
            "x_m": [0.0, 1.1, np.nan],
            "y_m": [0.0, 0.0, np.nan],
            "theta_deg": [0.0, 0.0, np.nan],
            "status": ["ok", "ambiguous", "too_few_segments"],
        }
    ).reindex(columns=ESTIMATE_COLUMNS)
    times_s, poses = trajectory_from_estimates(frame, only_ok=False)
    np.testing.assert_array_equal(poses[1], [1.1, 0.0, 0.0])
    assert np.all(np.isnan(poses[2]))
    errors = relation_errors(times_s, poses, make_relations(TRUTH, pairs=[(0, 1), (1, 2)]))
    assert (errors.used, errors.skipped) == (1, 1)
    assert errors.trans_m[0] == pytest.approx(0.1)
    _, only_ok = trajectory_from_estimates(frame, only_ok=True)
    assert np.all(np.isnan(only_ok[1]))


def test_estimates_sharing_a_relation_time_are_refused():
    times_s = np.array([0.0, 1.0, 1.0, 2.0])
    poses = TRUTH[[0, 1, 1, 2]]
    with pytest.raises(InputError) as caught:
        relation_errors(
            times_s, poses, make_relations(TRUTH, pairs=[(0, 1)]), estimates_path="est.csv"
        )
    assert str(caught.value) == (
        "est.csv, rows 2 and 3: both have time 1.000 s, so a relation time at 1.000 s matches "
        "more than one row; give every row a distinct time"
    )


def test_relations_may_share_their_times():
    # Many relations start at one pose: that is no collision.
    errors = relation_errors(TIMES_S, TRUTH, make_relations(TRUTH, pairs=[(0, 1), (0, 2), (0, 3)]))
    assert (errors.used, errors.skipped) == (3, 0)
    np.testing.assert_allclose(errors.trans_m, 0.0, atol=1e-12)


# --- summary -------------------------------------------------------------------------------


def test_summary_values_by_hand():
    # Three relations from (0, 0, 0) at t=0; estimate ends at (1, 0, 0) at t=1.
    # References (1, 0.3, 0), (1.4, 0, 4°) and (1, 0, −2°) give trans 0.3, 0.4, 0 m and
    # rot 0, 4, 2 degrees.
    times_s = np.array([0.0, 1.0])
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    relations = Relations(
        t1_s=np.zeros(3),
        t2_s=np.ones(3),
        delta=np.array([[1.0, 0.3, 0.0], [1.4, 0.0, np.deg2rad(4)], [1.0, 0.0, np.deg2rad(-2)]]),
    )
    errors = relation_errors(times_s, poses, relations)
    np.testing.assert_allclose(errors.trans_m, [0.3, 0.4, 0.0], atol=1e-12)
    np.testing.assert_allclose(errors.rot_deg, [0.0, 4.0, 2.0], atol=1e-9)

    s = errors.summary()
    assert (s["used"], s["skipped"]) == (3, 0)
    # Sample standard deviation (divisor U − 1 = 2) around the mean 0.7/3 m.
    t_mean = 0.7 / 3
    t_std = math.sqrt(((0.3 - t_mean) ** 2 + (0.4 - t_mean) ** 2 + t_mean**2) / 2)
    assert s["trans_m"]["mean"] == pytest.approx(0.2333333333333)
    assert s["trans_m"]["std"] == pytest.approx(t_std)
    assert s["trans_m"]["std"] == pytest.approx(0.2081665999466)
    assert s["trans_m"]["rms"] == pytest.approx(math.sqrt(0.25 / 3))
    assert s["rot_deg"]["mean"] == pytest.approx(2.0)
    assert s["rot_deg"]["std"] == pytest.approx(2.0)  # deviations −2, 2, 0 → √(8/2)
    assert s["rot_deg"]["rms"] == pytest.approx(math.sqrt(20 / 3))
    assert s["trans_sq_m2"]["mean"] == pytest.approx(0.25 / 3)
    sq = np.array([0.09, 0.16, 0.0])
    assert s["trans_sq_m2"]["std"] == pytest.approx(np.std(sq, ddof=1))
    assert s["rot_sq_deg2"]["mean"] == pytest.approx(20 / 3)
    assert s["rot_sq_deg2"]["std"] == pytest.approx(np.std([0.0, 16.0, 4.0], ddof=1))


def test_single_relation_has_no_standard_deviation():
    errors = relation_errors(TIMES_S, TRUTH, make_relations(TRUTH, pairs=[(0, 1)]))
    s = errors.summary()
    assert s["used"] == 1 and s["trans_m"]["mean"] == pytest.approx(0.0, abs=1e-12)
    assert math.isnan(s["trans_m"]["std"])


# --- the relations file --------------------------------------------------------------------

GOOD_FILE = """\
# reference relations for a test: t1 t2 dx dy dz droll dpitch dyaw
10.0 10.5 0.42 -0.01 0.0 0.0 0.0 0.017

10.5 11.25 0.213430 -0.014750 0.000000 0.000000 0.000000 -0.405780  # a trailing comment
   12.0\t13.0  1e-1 2E-2 0 0 0 3.0
"""


def test_read_relations(tmp_path):
    path = tmp_path / "small.relations"
    path.write_text(GOOD_FILE, encoding="utf-8")
    relations = read_relations(path)
    assert len(relations) == 3
    np.testing.assert_array_equal(relations.t1_s, [10.0, 10.5, 12.0])
    np.testing.assert_array_equal(relations.t2_s, [10.5, 11.25, 13.0])
    np.testing.assert_array_equal(
        relations.delta, [[0.42, -0.01, 0.017], [0.21343, -0.01475, -0.40578], [0.1, 0.02, 3.0]]
    )


@pytest.mark.parametrize(
    ("bad_line", "message"),
    [
        ("1.0 2.0 0.1 0.2 0 0 0", "expected 8"),
        ("1.0 2.0 0.1 0.2 0 0 0 0.3 9", "expected 8"),
        ("1.0 2.0 0.1 abc 0 0 0 0.3", "dy is 'abc'"),
        ("1.0 2.0 0.1 0.2 0 0 0 nan", "dyaw is 'nan'"),
    ],
)
def test_malformed_line_names_file_and_line(tmp_path, bad_line, message):
    path = tmp_path / "broken.relations"
    lines = GOOD_FILE.splitlines()
    lines.insert(3, bad_line)  # becomes line 4 of the file
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(InputError) as info:
        read_relations(path)
    text = str(info.value)
    assert str(path) in text and "line 4" in text and message in text


def test_missing_or_empty_file_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_relations(tmp_path / "absent.relations")
    empty = tmp_path / "empty.relations"
    empty.write_text("# only a comment\n\n", encoding="utf-8")
    with pytest.raises(InputError, match="no relations"):
        read_relations(empty)


# --- formats -------------------------------------------------------------------------------


def hand_summary() -> dict:
    times_s = np.array([0.0, 1.0])
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    relations = Relations(
        t1_s=np.array([0.0, 0.0, 5.0]),
        t2_s=np.array([1.0, 1.0, 6.0]),
        delta=np.array([[1.0, 0.3, 0.0], [1.4, 0.0, np.deg2rad(4)], [1.0, 0.0, 0.0]]),
    )
    return relation_errors(times_s, poses, relations).summary()


def test_md_parses_back():
    summary = hand_summary()
    text = format_relations(summary, "md", published=PUBLISHED["intel"])
    rows = md_rows(text)
    assert rows[0] == [
        "trajectory",
        "relations used",
        "skipped",
        "trans. error (m)",
        "rot. error (°)",
    ]
    assert rows[2] == ["segloc", "2", "1", "0.350 ± 0.071", "2.00 ± 2.83"]
    assert rows[3] == ["GraphMapping (published)", "—", "—", "0.031 ± 0.026", "1.3 ± 4.7"]
    assert len(rows) == 4
    assert "Kümmerle" in text


def test_md_without_published_and_with_nothing_used():
    empty = relation_errors(TIMES_S + 100.0, TRUTH, make_relations(TRUTH)).summary()
    rows = md_rows(format_relations(empty, "md"))
    assert rows[2] == ["segloc", "0", str(len(PAIRS)), "— ± —", "— ± —"]
    assert len(rows) == 3


def test_csv_parses_back_to_the_precision_of_each_unit():
    summary = hand_summary()
    text = format_relations(summary, "csv", published=PUBLISHED["fr079"], label="run 7")
    records = list(csv.DictReader(io.StringIO(text)))
    assert list(records[0]) == list(CSV_COLUMNS)
    ours, theirs = records
    assert ours["trajectory"] == "run 7" and ours["used"] == "2" and ours["skipped"] == "1"
    assert_within_precision(float(ours["trans_mean_m"]), summary["trans_m"]["mean"], "m")
    assert_within_precision(float(ours["rot_std_deg"]), summary["rot_deg"]["std"], "deg")
    assert_within_precision(float(ours["rot_sq_std_deg2"]), summary["rot_sq_deg2"]["std"], "deg2")
    for column in CSV_COLUMNS[3:]:
        if ours[column]:
            assert_at_precision(ours[column], unit_of(column))
    assert theirs["trajectory"] == "GraphMapping (published)"
    assert (float(theirs["trans_mean_m"]), float(theirs["trans_std_m"])) == (0.056, 0.042)
    assert (float(theirs["rot_mean_deg"]), float(theirs["rot_std_deg"])) == (0.6, 0.6)
    assert theirs["used"] == "" and theirs["trans_rms_m"] == ""


def test_json_parses_back():
    summary = hand_summary()
    document = json.loads(format_relations(summary, "json", published=PUBLISHED["aces"]))
    assert document["summary"].keys() == summary.keys()
    for name, unit in (("trans_m", "m"), ("rot_deg", "deg"), ("trans_sq_m2", "m2")):
        for statistic, value in summary[name].items():
            assert_within_precision(document["summary"][name][statistic], value, unit)
    assert document["published"] == {
        "GraphMapping": {
            "trans_m": {"mean": 0.044, "std": 0.044},
            "rot_deg": {"mean": 0.4, "std": 0.4},
        }
    }
    assert "Kümmerle" in document["published_source"]
    one = relation_errors(TIMES_S, TRUTH, make_relations(TRUTH, pairs=[(0, 1)])).summary()
    assert json.loads(format_relations(one, "json"))["summary"]["trans_m"]["std"] is None


def test_latex_parses_back():
    summary = hand_summary()
    text = format_relations(summary, "latex", published=PUBLISHED["mit-csail"], label="a_b & c")
    lines = text.splitlines()
    assert lines[:2] == [r"% needs \usepackage{booktabs}", r"\begin{tabular}{lrrrr}"]
    assert lines[-1] == r"\end{tabular}"
    body = lines[lines.index(r"\midrule") + 1 : lines.index(r"\bottomrule")]
    cells = [[c.strip() for c in line.removesuffix(r"\\").split(" & ")] for line in body]
    assert cells[0] == [r"a\_b \& c", "2", "1", r"$0.350 \pm 0.071$", r"$2.00 \pm 2.83$"]
    assert cells[1] == [
        "GraphMapping (published)",
        "--",
        "--",
        r"$0.004 \pm 0.009$",
        r"$0.05 \pm 0.08$",
    ]


def test_unknown_format_is_rejected():
    with pytest.raises(ValueError, match="unknown relations format"):
        format_relations(hand_summary(), "html")


# --- published numbers ---------------------------------------------------------------------


def test_published_table_is_well_formed():
    assert set(PUBLISHED) >= {"intel", "aces", "mit-csail", "fr079"}
    assert set(PUBLISHED_SQUARED) == set(PUBLISHED)
    for dataset, methods in PUBLISHED.items():
        assert set(PUBLISHED_SQUARED[dataset]) == set(methods)
        for values in methods.values():
            assert set(values) == {"trans_m", "rot_deg"}
            for mean, std in values.values():
                assert mean > 0 and std > 0
