"""Pose tables, TUM trajectories, estimates CSV and time matching."""

from __future__ import annotations

import errno
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from precision import (
    BINARY_NOISE,
    assert_at_precision,
    assert_frame_within_precision,
    assert_within_precision,
)
from test_campaign_runs import needs_tmpfs
from test_cli import run_cli

from segloc_cli.errors import InputError
from segloc_cli.estimates import ESTIMATE_COLUMNS, PoseTable
from segloc_cli.geometry import heading_to_quaternion, quaternion_to_heading, wrap_angle
from segloc_cli.io.files import OutputError
from segloc_cli.io.tables import (
    EstimatesWriter,
    HypothesesWriter,
    TumWriter,
    read_estimates,
    read_pose_table,
    write_estimates,
    write_pose_table,
    write_pose_table_tum,
    write_tum,
)
from segloc_cli.timing import nearest_by_time, pair_by_time

# --- survey CSV ------------------------------------------------------------------


def test_survey_csv_columns_by_name(tmp_path):
    path = tmp_path / "survey.csv"
    path.write_text(
        "note,theta_deg,y_m,x_m,time_s,pose_id\na,90,2.5,1.0,10.0,7\n\nb,-45,0,-3.25,10.5,3\n"
    )
    table = read_pose_table(path)
    np.testing.assert_array_equal(table.pose_id, [7, 3])
    assert table.pose_id.dtype == np.int64
    np.testing.assert_array_equal(table.time_s, [10.0, 10.5])
    np.testing.assert_array_equal(table.poses[:, :2], [[1.0, 2.5], [-3.25, 0.0]])
    np.testing.assert_allclose(table.poses[:, 2], [np.pi / 2, -np.pi / 4], rtol=0, atol=1e-15)
    assert len(table) == 2


def test_survey_without_pose_id_numbers_rows(tmp_path):
    path = tmp_path / "survey.csv"
    path.write_text("time_s,x_m,y_m,theta_deg\n1,0,0,0\n2,1,1,180\n3,2,2,270\n")
    table = read_pose_table(path)
    np.testing.assert_array_equal(table.pose_id, [1, 2, 3])


def test_time_optional_only_when_not_required(tmp_path):
    path = tmp_path / "initial.csv"
    path.write_text("pose_id,x_m,y_m,theta_deg\n4,1,2,30\n")
    table = read_pose_table(path, require_time=False)
    assert np.isnan(table.time_s).all()
    np.testing.assert_array_equal(table.pose_id, [4])
    with pytest.raises(InputError, match=r"initial\.csv: missing column 'time_s'"):
        read_pose_table(path)


def test_pose_table_round_trip(tmp_path):
    rng = np.random.default_rng(3)
    table = PoseTable(
        pose_id=np.array([5, 1, 9], dtype=np.int64),
        time_s=np.array([0.1, 1234567.123456789, 2.0 / 3.0]),
        poses=np.column_stack(
            [rng.normal(size=3) * 100, rng.normal(size=3), [np.pi - 1e-7, -np.pi, 1e-12]]
        ),
    )
    path = tmp_path / "survey.csv"
    write_pose_table(path, table)
    back = read_pose_table(path)
    np.testing.assert_array_equal(back.pose_id, table.pose_id)
    assert_within_precision(back.time_s, table.time_s, "s")
    assert_within_precision(back.poses[:, :2], table.poses[:, :2], "m")
    turned = np.rad2deg(wrap_angle(back.poses[:, 2] - table.poses[:, 2]))
    assert_within_precision(turned, np.zeros(3), "deg")
    lines = path.read_text().splitlines()
    assert lines[0] == "pose_id,time_s,x_m,y_m,theta_deg"
    assert not BINARY_NOISE.search(path.read_text())
    for line in lines[1:]:
        for text, unit in zip(line.split(",")[1:], ("s", "m", "m", "deg"), strict=True):
            assert_at_precision(text, unit)


def test_survey_headings_through_radians_are_written_as_given(tmp_path):
    """125° and 30° read into radians and written back are 125.0 and 30.0, not
    125.00000000000001 and 29.999999999999996 (the hall's survey once held both)."""
    source = tmp_path / "poses.csv"
    source.write_text("pose_id,time_s,x_m,y_m,theta_deg\n2,2.0,10.2,3.6,125\n4,4,9,10,30\n")
    write_pose_table(tmp_path / "survey.csv", read_pose_table(source))
    assert (tmp_path / "survey.csv").read_text().splitlines()[1:] == [
        "2,2.0,10.2,3.6,125.0",
        "4,4.0,9.0,10.0,30.0",
    ]


def test_pose_table_as_tum_round_trip(tmp_path):
    """A reference written as TUM reads back with the same times and positions to their
    precision and the same headings to rounding (through a quaternion), ids 1..N; a time
    missing is refused before anything is written."""
    rng = np.random.default_rng(4)
    headings = np.concatenate([[np.pi - 1e-7, -np.pi, 1e-12, 0.0], rng.uniform(-np.pi, np.pi, 6)])
    table = PoseTable(
        pose_id=np.arange(7, 17),
        time_s=np.concatenate([[0.1, 1234567.123456789, 2.0 / 3.0], rng.uniform(0, 1e4, 7)]),
        poses=np.column_stack([rng.normal(size=10) * 100, rng.normal(size=10), headings]),
    )
    path = tmp_path / "reference.tum"
    write_pose_table_tum(path, table)
    back = read_pose_table(path)
    np.testing.assert_array_equal(back.pose_id, np.arange(1, 11))
    assert_within_precision(back.time_s, table.time_s, "s")
    assert_within_precision(back.poses[:, :2], table.poses[:, :2], "m")
    # A quaternion's components to 1e-9 hold the heading to about 2e-9 rad.
    turned = np.abs(wrap_angle(back.poses[:, 2] - table.poses[:, 2]))
    np.testing.assert_allclose(turned, 0.0, rtol=0, atol=1e-8)
    assert not BINARY_NOISE.search(path.read_text())
    fields = path.read_text().splitlines()[1].split()
    assert len(fields) == 8 and float(fields[3]) == 0.0  # t x y z qx qy qz qw, on the floor
    missing = PoseTable(table.pose_id[:2], np.array([0.0, np.nan]), table.poses[:2])
    with pytest.raises(ValueError, match="finite time"):
        write_pose_table_tum(tmp_path / "missing.tum", missing)
    assert not (tmp_path / "missing.tum").exists()


def test_pose_table_without_times_round_trip(tmp_path):
    table = PoseTable(np.array([1, 2]), np.full(2, np.nan), np.array([[0.0, 1, 0.5], [2, 3, -1]]))
    path = tmp_path / "poses.csv"
    write_pose_table(path, table)
    assert path.read_text().splitlines()[0] == "pose_id,x_m,y_m,theta_deg"
    back = read_pose_table(path, require_time=False)
    np.testing.assert_array_equal(back.pose_id, [1, 2])
    assert np.isnan(back.time_s).all()
    np.testing.assert_array_equal(back.poses[:, :2], table.poses[:, :2])
    assert_within_precision(np.rad2deg(back.poses[:, 2]), np.rad2deg(table.poses[:, 2]), "deg")


def test_pose_table_extra_columns_follow_and_are_ignored_by_the_reader(tmp_path):
    table = PoseTable(np.array([1, 2]), np.array([0.5, 0.75]), np.array([[1.0, 2, 0], [3, 4, 0]]))
    path = tmp_path / "survey.csv"
    write_pose_table(
        path,
        table,
        extra_columns={"original_time_s": np.array([0.0, np.nan]), "source": ["a", "b,c"]},
    )
    assert path.read_text().splitlines() == [
        "pose_id,time_s,x_m,y_m,theta_deg,original_time_s,source",
        "1,0.5,1.0,2.0,0.0,0.0,a",
        '2,0.75,3.0,4.0,0.0,,"b,c"',
    ]
    back = read_pose_table(path)
    np.testing.assert_array_equal(back.time_s, table.time_s)
    np.testing.assert_array_equal(back.poses, table.poses)
    with pytest.raises(ValueError, match="extra column 'x_m' clashes"):
        write_pose_table(path, table, extra_columns={"x_m": np.zeros(2)})
    with pytest.raises(ValueError, match="extra column 'e' has 3 values for 2 poses"):
        write_pose_table(path, table, extra_columns={"e": np.zeros(3)})


def test_writers_refuse_a_missing_folder_with_one_line(tmp_path):
    table = PoseTable(np.array([1]), np.array([0.0]), np.zeros((1, 3)))
    target = tmp_path / "no" / "survey.csv"
    for write in (
        lambda: write_pose_table(target, table),
        lambda: write_estimates(target, estimates_frame()),
        lambda: write_tum(target, estimates_frame()),
    ):
        with pytest.raises(OutputError, match=r"no/survey\.csv: cannot write file"):
            write()


def test_a_failed_write_keeps_the_old_file(tmp_path):
    path = tmp_path / "est.csv"
    path.write_text("old\n")
    frame = estimates_frame()
    frame.loc[0, "pose_id"] = np.nan
    with pytest.raises(ValueError, match="pose_id"):
        write_estimates(path, frame)
    assert path.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["est.csv"]


def test_write_refuses_some_missing_times(tmp_path):
    table = PoseTable(np.array([1, 2]), np.array([1.0, np.nan]), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="time_s"):
        write_pose_table(tmp_path / "x.csv", table)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("pose_id,time_s,x_m,theta_deg\n1,0,0,0\n", r"survey\.csv: missing column 'y_m'"),
        ("pose_id,time_s,x_m,y_m,theta_deg\n", r"survey\.csv: table has no data rows"),
        (
            "pose_id,time_s,x_m,y_m,theta_deg\n1,0,0,0,0\n2,1,abc,0,0\n",
            r"survey\.csv, row 2: column x_m is 'abc'",
        ),
        (
            "pose_id,time_s,x_m,y_m,theta_deg\n1,0,0,nan,0\n",
            r"survey\.csv, row 1: column y_m is 'nan'",
        ),
        (
            "pose_id,time_s,x_m,y_m,theta_deg\n1,0,0,0,\n",
            r"survey\.csv, row 1: column theta_deg is empty",
        ),
        (
            "pose_id,time_s,x_m,y_m,theta_deg\n1.5,0,0,0,0\n",
            r"survey\.csv, row 1: column pose_id is '1\.5'",
        ),
        (
            "pose_id,time_s,x_m,y_m,theta_deg\n3,0,0,0,0\n4,1,0,0,0\n3,2,0,0,0\n",
            r"survey\.csv, row 3: pose_id 3 repeats row 1",
        ),
        (
            "pose_id,time_s,x_m,y_m,theta_deg\n1,0,0,0\n",
            r"survey\.csv, row 1: has 4 fields but the header has 5",
        ),
    ],
)
def test_survey_errors(tmp_path, text, message):
    path = tmp_path / "survey.csv"
    path.write_text(text)
    with pytest.raises(InputError, match=message):
        read_pose_table(path)


def test_missing_and_empty_files(tmp_path):
    with pytest.raises(InputError, match=r"gone\.csv: file not found"):
        read_pose_table(tmp_path / "gone.csv")
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    with pytest.raises(InputError, match=r"empty\.csv: table has no data rows"):
        read_pose_table(empty)


# --- TUM ---------------------------------------------------------------------------


def test_tum_known_quaternions(tmp_path):
    s = math.sqrt(0.5)
    path = tmp_path / "traj.txt"
    path.write_text(
        "# timestamp tx ty tz qx qy qz qw\n"
        "1.5 1.0 2.0 0.0 0 0 0 1\n"
        "2.5 3.0 4.0 0.3 0 0 " + f"{s!r} {s!r}\n"  # yaw +90°
        "   \n"
        "3.5 -1 -2 0 0 0 1 0\n"  # yaw 180°
        "4.5 0 0 0 0 0 -0.5 0.5\n"  # not normalised, yaw -90°
    )
    table = read_pose_table(path)
    np.testing.assert_array_equal(table.pose_id, [1, 2, 3, 4])
    np.testing.assert_array_equal(table.time_s, [1.5, 2.5, 3.5, 4.5])
    np.testing.assert_array_equal(table.poses[:, :2], [[1, 2], [3, 4], [-1, -2], [0, 0]])
    np.testing.assert_allclose(
        table.poses[:, 2], [0.0, np.pi / 2, np.pi, -np.pi / 2], rtol=0, atol=1e-15
    )


def test_tum_errors(tmp_path):
    path = tmp_path / "traj.txt"
    path.write_text("1 2 3 4 5 6 7 8\n1 2 3\n")
    with pytest.raises(InputError, match=r"traj\.txt, row 2: expected 8 whitespace-separated"):
        read_pose_table(path)
    path.write_text("# only a comment\n")
    with pytest.raises(InputError, match=r"traj\.txt: table has no data rows"):
        read_pose_table(path)
    path.write_text("1 0 0 0 0 0 0 0\n")
    with pytest.raises(InputError, match=r"row 1: quaternion is all zeros"):
        read_pose_table(path)
    path.write_text("1 0 0 0 0 0 x 1\n")
    with pytest.raises(InputError, match=r"row 1: column qz is 'x'"):
        read_pose_table(path)


def test_csv_without_x_m_is_a_csv_error_not_a_tum_one(tmp_path):
    path = tmp_path / "survey.csv"
    path.write_text("id,t,x,y,theta\n1,0,0,0,0\n")
    with pytest.raises(InputError) as caught:
        read_pose_table(path)
    assert str(caught.value) == (
        f"{path}: missing column 'x_m'; a survey CSV needs the header "
        "pose_id,time_s,x_m,y_m,theta_deg (pose_id optional)"
    )
    # A header of one word is a CSV header too (not numeric); the message mentions TUM.
    path.write_text("timestamp tx ty tz qx qy qz qw\n1 0 0 0 0 0 0 1\n")
    with pytest.raises(InputError, match=r"missing column 'x_m'.*TUM trajectory has 8 numbers"):
        read_pose_table(path)


def test_numeric_first_line_is_tum_and_its_errors_say_so(tmp_path):
    path = tmp_path / "traj.txt"
    path.write_text("# t x y z qx qy qz qw\n1.5 0 0 0 0 0 0 1\n2.5 0 0\n")
    with pytest.raises(InputError) as caught:
        read_pose_table(path)
    assert str(caught.value).startswith(
        f"{path}, row 2: expected 8 whitespace-separated values 't x y z qx qy qz qw' (TUM), got 3"
    )


def test_comment_lines_before_a_csv_header(tmp_path):
    path = tmp_path / "survey.csv"
    path.write_text("# surveyed 2024-05-01\n\npose_id,time_s,x_m,y_m,theta_deg\n4,1.5,1,2,90\n")
    table = read_pose_table(path)
    np.testing.assert_array_equal(table.pose_id, [4])
    np.testing.assert_array_equal(table.poses[:, :2], [[1.0, 2.0]])


def test_pose_ids_are_exact_int64(tmp_path):
    path = tmp_path / "survey.csv"
    big = 2**53 + 1  # not a float64
    path.write_text(f"pose_id,time_s,x_m,y_m,theta_deg\n{big},0,0,0,0\n{big - 1},1,0,0,0\n")
    np.testing.assert_array_equal(read_pose_table(path).pose_id, [big, big - 1])
    path.write_text(f"pose_id,time_s,x_m,y_m,theta_deg\n{2**63},0,0,0,0\n")
    with pytest.raises(InputError) as caught:
        read_pose_table(path)
    assert str(caught.value) == (
        f"{path}, row 1: column pose_id is '9223372036854775808'; "
        "expected an integer within ±9223372036854775807"
    )


def test_long_fields_are_cut_in_messages(tmp_path):
    path = tmp_path / "survey.csv"
    path.write_text("pose_id,time_s,x_m,y_m,theta_deg\n1,0," + "9" * 500 + "x,0,0\n")
    with pytest.raises(InputError) as caught:
        read_pose_table(path)
    assert str(caught.value) == (
        f"{path}, row 1: column x_m is '{'9' * 40}'…; expected a finite number"
    )


def test_positions_beyond_the_bound_are_refused(tmp_path):
    path = tmp_path / "survey.csv"
    path.write_text("pose_id,time_s,x_m,y_m,theta_deg\n1,0,500000,5000000,0\n2,1,0,1e9,0\n")
    with pytest.raises(InputError) as caught:
        read_pose_table(path)
    assert str(caught.value) == (
        f"{path}, row 2: position (0, 1e+09) m is beyond ±1e+07 m; expected coordinates in metres"
    )


@pytest.mark.parametrize("scale", [1e-300, 1.0, 1e300])
def test_tum_quaternions_at_any_scale(tmp_path, scale):
    path = tmp_path / "traj.txt"
    path.write_text(f"1 0 0 0 0 0 {scale!r} {scale!r}\n2 0 0 0 0 0 {-scale!r} {scale!r}\n")
    np.testing.assert_allclose(
        read_pose_table(path).poses[:, 2], [np.pi / 2, -np.pi / 2], rtol=0, atol=1e-15
    )


def test_quaternion_helpers_agree():
    theta = np.array([-np.pi, -1.0, 0.0, 0.7, 3.0])
    q = heading_to_quaternion(theta)
    assert q.shape == (5, 4)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0)
    back = quaternion_to_heading(q[:, 0], q[:, 1], q[:, 2], q[:, 3])
    np.testing.assert_allclose(np.cos(back - theta), 1.0, atol=1e-15)


# --- nearest_by_time ----------------------------------------------------------------


def test_nearest_exact_indices_unsorted_ref():
    ref = np.array([3.0, 1.0, 2.0, 10.0])
    query = np.array([0.9, 1.0, 2.2, 2.9, 9.0, 11.0, 6.5])
    got = nearest_by_time(query, ref, tolerance_s=0.5)
    np.testing.assert_array_equal(got, [1, 1, 2, 0, -1, -1, -1])
    assert got.dtype == np.int64


def test_nearest_tolerance_is_inclusive():
    ref = np.array([1.0, 2.0])
    np.testing.assert_array_equal(
        nearest_by_time([1.25, 1.2500001, 0.75, 2.25], ref, 0.25), [0, -1, 0, 1]
    )


def test_nearest_ties_go_to_earlier_time():
    ref = np.array([2.0, 1.0])
    # 1.5 is equally far from both: the earlier time (1.0, index 1) wins.
    np.testing.assert_array_equal(nearest_by_time([1.5], ref, 1.0), [1])


def test_nearest_duplicate_ref_times_take_first_index():
    ref = np.array([5.0, 1.0, 5.0, 1.0])
    np.testing.assert_array_equal(nearest_by_time([1.1, 4.9, 5.0, 0.9], ref, 0.5), [1, 0, 0, 1])


def brute_force_nearest(query, ref, tolerance_s):
    """Reference: scan every ref time; ties to the earlier time, then the lower index."""
    out = []
    for q in query:
        best = -1
        for j, r in enumerate(ref):
            d = abs(q - r)
            if d > tolerance_s:
                continue
            if best < 0:
                best = j
                continue
            d_best = abs(q - ref[best])
            if d < d_best or (d == d_best and (r < ref[best] or (r == ref[best] and j < best))):
                best = j
        out.append(best)
    return out


times = st.lists(st.integers(0, 40).map(lambda k: k * 0.25), max_size=12)


@settings(max_examples=200, deadline=None)
@given(query=times, ref=times, tolerance_steps=st.integers(0, 8))
def test_nearest_matches_brute_force(query, ref, tolerance_steps):
    tolerance_s = tolerance_steps * 0.25
    got = nearest_by_time(np.array(query), np.array(ref), tolerance_s)
    assert got.tolist() == brute_force_nearest(query, ref, tolerance_s)


def test_nearest_empty_and_nan():
    np.testing.assert_array_equal(nearest_by_time([1.0, 2.0], [], 1.0), [-1, -1])
    np.testing.assert_array_equal(nearest_by_time([np.nan, 1.0], [1.0, np.nan], 0.1), [-1, 0])
    assert nearest_by_time([], [1.0], 1.0).shape == (0,)


# --- pair_by_time ------------------------------------------------------------------


def pair(query, ref, tolerance_s=0.05, **options):
    return pair_by_time(
        query, ref, tolerance_s, query_path="log.mcap", ref_path="survey.csv", **options
    )


def test_pairing_40_hz_scans_with_a_table_at_their_times():
    # Neighbours 25 ms away lie within 50 ms of every scan; the nearest is unique, so no refusal.
    scans_s = 1_700_000_000.0 + np.arange(400) * 0.025
    np.testing.assert_array_equal(
        pair(scans_s, scans_s[::-1], query_label="scan"), np.arange(400)[::-1]
    )
    # Distinct scans may share one row of a sparser table.
    np.testing.assert_array_equal(pair([0.975, 1.0, 1.025], [1.0, 2.0]), [0, 0, 0])


def test_pairing_refuses_rows_sharing_the_nearest_time():
    ref = [12.0, 12.5, 12.5, 13.0]
    with pytest.raises(InputError) as caught:
        pair([12.0, 12.5], ref, query_label="scan")
    assert str(caught.value) == (
        "survey.csv, rows 2 and 3: both have time 12.500 s, so a scan at 12.500 s matches more "
        "than one row; give every row a distinct time"
    )
    assert caught.value.path == "survey.csv"
    with pytest.raises(InputError) as caught:
        pair([12.52], ref, query_label="scan")
    assert str(caught.value) == (
        "survey.csv, rows 2 and 3: both have time 12.500 s, so a scan at 12.520 s matches more "
        "than one row; give every row a distinct time (or lower --tolerance-ms)"
    )
    with pytest.raises(InputError, match=r"^survey\.csv, rows 1, 2, 3 and 2 more: all have time 0"):
        pair(np.zeros(3), np.zeros(5))


def test_pairing_refuses_a_query_halfway_between_two_rows():
    with pytest.raises(InputError) as caught:
        pair([1.0, 2.25], [3.0, 2.5, 1.0, 2.0], 0.5, query_label="scan")
    assert str(caught.value) == (
        "survey.csv, rows 2 and 4: their times 2.000 and 2.500 s are equally near a scan at "
        "2.250 s, so it matches either; give times that are not halfway between two rows "
        "(or lower --tolerance-ms)"
    )
    assert caught.value.path == "survey.csv"
    # Whether or not queries must be distinct (relations share times).
    with pytest.raises(InputError, match="equally near"):
        pair([0.5], [0.0, 1.0], tolerance_s=1.0, distinct_queries=False)
    # A row at the query's own time, or a nearer one, settles it.
    np.testing.assert_array_equal(pair([2.0, 2.26], [1.5, 2.0, 2.5], 1.0), [1, 2])
    # Halfway but out of reach: unpaired, nothing to refuse.
    np.testing.assert_array_equal(pair([2.25], [2.0, 2.5], 0.2), [-1])


def test_pairing_ignores_shared_times_that_are_not_nearest():
    # 12.5 twice lies within the tolerance of 12.52, but 12.52 itself is nearer.
    np.testing.assert_array_equal(pair([12.52, 20.0], [12.5, 12.5, 12.52]), [2, -1])


def test_pairing_refuses_queries_sharing_a_time():
    with pytest.raises(InputError) as caught:
        pair([1.0, 2.0, 2.0, 2.0], [1.0, 2.0], query_label="scan")
    assert str(caught.value) == (
        "log.mcap, scans 2, 3 and 4: all have time 2.000 s, so all would be paired with row 2 "
        "of survey.csv; give every scan a distinct time"
    )
    assert caught.value.path == "log.mcap"
    # Unmatched queries may share a time; so may any when asked (relations share times).
    np.testing.assert_array_equal(pair([5.0, 5.0, 1.0], [1.0, 2.0]), [-1, -1, 0])
    np.testing.assert_array_equal(pair([2.0, 2.0], [1.0, 2.0], distinct_queries=False), [1, 1])


times_with_repeats = st.lists(st.integers(0, 12).map(lambda k: k * 0.25), max_size=10)


@settings(max_examples=100, deadline=None)
@given(query=times_with_repeats, ref=times_with_repeats, tolerance_steps=st.integers(0, 4))
def test_pairing_is_nearest_or_refused(query, ref, tolerance_steps):
    tolerance_s = tolerance_steps * 0.25
    nearest = nearest_by_time(query, ref, tolerance_s)
    hit = nearest >= 0
    matched_ref = np.asarray(ref)[nearest[hit]] if ref else np.zeros(0)
    ambiguous = any(ref.count(t) > 1 for t in matched_ref)
    ambiguous |= len(set(np.asarray(query)[hit])) < int(np.count_nonzero(hit))
    gaps = np.abs(np.asarray(query)[hit] - matched_ref)
    ambiguous |= any(
        gap > 0 and q - gap in ref and q + gap in ref
        for q, gap in zip(np.asarray(query)[hit], gaps, strict=True)
    )
    try:
        got = pair(query, ref, tolerance_s)
    except InputError:
        assert ambiguous
    else:
        assert not ambiguous
        np.testing.assert_array_equal(got, nearest)


# --- estimates ---------------------------------------------------------------------


def estimates_frame() -> pd.DataFrame:
    return pd.DataFrame(
        {
            "pose_id": [1, 2, 7],
            "time_s": [0.1, 1.0 / 3.0, 1234.5],
            "init_x_m": [1.0, np.nan, 2.0],
            "init_y_m": [-0.5, np.nan, 0.25],
            "init_theta_deg": [10.0, np.nan, -179.999],
            "align_theta_deg": [9.5, 181.25, np.nan],
            "stage2_x_m": [1.01, 2.0 / 7.0, np.nan],
            "stage2_y_m": [-0.5, 0.0, np.nan],
            "stage2_theta_deg": [9.5, 90.25, np.nan],
            "x_m": [1.0 + 1e-13, 2.0 / 7.0, np.nan],
            "y_m": [-0.49, 1e-300, np.nan],
            "theta_deg": [9.75, 90.0, np.nan],
            "overlap_m": [12.3456789012345, 0.0, np.nan],
            "inlier_ratio": [0.875, 1.0 / 3.0, np.nan],
            "runner_up_x_m": [3.5, np.nan, np.nan],
            "runner_up_y_m": [-1.25, np.nan, np.nan],
            "runner_up_theta_deg": [-90.5, np.nan, np.nan],
            "runner_up_ratio": [0.5, 0.0, np.nan],
            "n_local_segments": [14, 3, 0],
            "runtime_ms": [2.5, 3.75, 0.125],
            "confidence": [0.9987654321, 1.0 / 7.0, np.nan],
            "status": ["ok", "ok, weak", "no_segments"],
            "window_scans": [1, 7, 1],
        }
    )


def test_estimates_of_an_earlier_version_without_confidence_read_and_write(tmp_path):
    earlier = estimates_frame().drop(columns=["confidence", "window_scans"])
    path = tmp_path / "old.csv"
    earlier.to_csv(path, index=False)
    back = read_estimates(path)
    assert list(back.columns) == ESTIMATE_COLUMNS
    assert back["confidence"].isna().all()
    assert (back["window_scans"] == 0).all()  # not said: 0, never a made-up 1
    write_estimates(tmp_path / "again.csv", earlier)
    again = read_estimates(tmp_path / "again.csv")
    assert_frame_within_precision(again, back)


def test_estimates_round_trip(tmp_path):
    frame = estimates_frame()
    path = tmp_path / "est.csv"
    write_estimates(path, frame)
    assert path.read_text().splitlines()[0] == ",".join(ESTIMATE_COLUMNS)
    back = read_estimates(path)
    assert list(back.columns) == ESTIMATE_COLUMNS
    assert back["pose_id"].dtype == np.int64
    assert back["n_local_segments"].dtype == np.int64
    assert back["x_m"].dtype == np.float64
    assert_frame_within_precision(back, frame)
    assert back["status"].tolist() == ["ok", "ok, weak", "no_segments"]
    assert back["confidence"].iloc[1] == 0.142857143  # 1/7 to 1e-9
    assert not BINARY_NOISE.search(path.read_text())
    # What was written is written again unchanged.
    write_estimates(tmp_path / "again.csv", back)
    assert (tmp_path / "again.csv").read_bytes() == path.read_bytes()


def test_estimates_extra_columns_not_written_and_order_fixed(tmp_path):
    frame = estimates_frame()[list(reversed(ESTIMATE_COLUMNS))].assign(debug=[1, 2, 3])
    path = tmp_path / "est.csv"
    write_estimates(path, frame)
    assert path.read_text().splitlines()[0] == ",".join(ESTIMATE_COLUMNS)


def test_write_estimates_checks_columns(tmp_path):
    with pytest.raises(ValueError, match="overlap_m"):
        write_estimates(tmp_path / "e.csv", estimates_frame().drop(columns=["overlap_m"]))
    frame = estimates_frame()
    frame.loc[1, "time_s"] = np.nan
    with pytest.raises(ValueError, match="time_s"):
        write_estimates(tmp_path / "e.csv", frame)


HEADER = ",".join(ESTIMATE_COLUMNS)


def estimates_line(**fields: str) -> str:
    """One estimates CSV line: the given fields, every other column empty."""
    return ",".join(fields.get(c, "") for c in ESTIMATE_COLUMNS)


GOOD = {
    "pose_id": "1",
    "time_s": "1",
    "n_local_segments": "3",
    "runtime_ms": "1",
    "status": "ok",
    "window_scans": "1",
}


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ("pose_id,time_s\n1,2\n", r"est\.csv: missing column\(s\) init_x_m, init_y_m"),
        (
            f"{HEADER}\n{estimates_line(**{**GOOD, 'pose_id': 'x'})}\n",
            r"est\.csv, row 1: column pose_id is 'x'",
        ),
        (
            f"{HEADER}\n{estimates_line(**GOOD)}\n{estimates_line(**{**GOOD, 'time_s': ''})}\n",
            r"row 2: column time_s is empty",
        ),
        (
            f"{HEADER}\n{estimates_line(**{**GOOD, 'n_local_segments': ''})}\n",
            r"row 1: column n_local_segments is empty",
        ),
        (
            f"{HEADER}\n{estimates_line(**{**GOOD, 'x_m': '1.5.2'})}\n",
            r"row 1: column x_m is '1.5.2'",
        ),
    ],
)
def test_read_estimates_errors(tmp_path, body, message):
    path = tmp_path / "est.csv"
    path.write_text(body)
    with pytest.raises(InputError, match=message):
        read_estimates(path)


def test_write_tum_finite_rows_read_back(tmp_path):
    frame = estimates_frame()
    path = tmp_path / "est.tum"
    write_tum(path, frame)
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]
    assert len(lines) == 2
    assert all(len(ln.split()) == 8 for ln in lines)
    table = read_pose_table(path)
    assert_within_precision(table.time_s, frame["time_s"][:2], "s")
    assert_within_precision(table.poses[:, :2], frame[["x_m", "y_m"]].to_numpy()[:2], "m")
    np.testing.assert_allclose(
        np.rad2deg(table.poses[:, 2]), frame["theta_deg"][:2], rtol=0, atol=1e-6
    )
    # evo reads TUM files as plain numeric matrices with '#' comments.
    matrix = np.loadtxt(path, comments="#")
    assert matrix.shape == (2, 8)
    np.testing.assert_allclose(np.linalg.norm(matrix[:, 4:], axis=1), 1.0)


# --- streamed estimates ------------------------------------------------------------


def frame_rows(frame: pd.DataFrame) -> list[dict]:
    return [dict(zip(frame.columns, values, strict=True)) for values in frame.to_numpy(object)]


def test_a_row_without_the_later_columns_leaves_confidence_empty_and_counts_zero_scans(tmp_path):
    row = {k: v for k, v in frame_rows(estimates_frame())[0].items()
           if k not in ("confidence", "window_scans")}  # fmt: skip
    path = tmp_path / "est.csv"
    with EstimatesWriter(path) as writer:
        writer.write_row(row)
    back = read_estimates(path)
    assert np.isnan(back["confidence"].iloc[0])
    assert back["window_scans"].iloc[0] == 0


def test_a_file_of_segloc_0_1_reads_its_overlap_column_as_overlap_m(tmp_path):
    frame = estimates_frame()
    current, former = tmp_path / "now.csv", tmp_path / "then.csv"
    write_estimates(current, frame)
    header, body = current.read_text().split("\n", 1)
    assert ",overlap_m," in header
    former.write_text(header.replace(",overlap_m,", ",overlap,") + "\n" + body)
    back = read_estimates(former)
    assert list(back.columns) == list(frame.columns)
    pd.testing.assert_frame_equal(back, read_estimates(current), check_exact=True)


def test_estimates_writer_writes_what_write_estimates_writes(tmp_path):
    frame = estimates_frame()
    whole, streamed = tmp_path / "whole.csv", tmp_path / "streamed.csv"
    write_estimates(whole, frame)
    with EstimatesWriter(streamed) as writer:
        assert streamed.read_text() == HEADER + "\n"  # the header is there at once
        for i, row in enumerate(frame_rows(frame), start=1):
            writer.write_row({**row, "debug": "not written"})
            # Every finished row is on disk before the writer is closed.
            pd.testing.assert_frame_equal(
                read_estimates(streamed), read_estimates(whole).iloc[:i], check_exact=True
            )
        assert writer.rows == 3
    assert streamed.read_bytes() == whole.read_bytes()
    writer.close()  # a second close does nothing


def test_estimates_writer_rejects_rows_without_required_values(tmp_path):
    path = tmp_path / "est.csv"
    row = frame_rows(estimates_frame())[0]
    with EstimatesWriter(path) as writer:
        with pytest.raises(ValueError, match="time_s must have a value"):
            writer.write_row({**row, "time_s": np.nan})
        with pytest.raises(ValueError, match=r"lacks columns \['status'\]"):
            writer.write_row({k: v for k, v in row.items() if k != "status"})
        writer.write_row(row)
    assert len(read_estimates(path)) == 1
    with pytest.raises(OutputError, match=r"missing/est\.csv: cannot write file"):
        EstimatesWriter(tmp_path / "missing" / "est.csv")


def test_tum_writer_writes_what_write_tum_writes(tmp_path):
    frame = estimates_frame()
    whole, streamed = tmp_path / "whole.tum", tmp_path / "streamed.tum"
    write_tum(whole, frame)
    with TumWriter(streamed) as writer:
        for row in frame_rows(frame):
            writer.write_row(row)
        assert writer.rows == 2  # the row without a pose has no line
    assert streamed.read_bytes() == whole.read_bytes()


def _disk_with_room(monkeypatch, room: int) -> None:
    """Make ``os.write`` behave as on a disk with ``room`` bytes left: a write past them
    takes what fits (a short write), the next one fails with ENOSPC."""
    real_write = os.write

    def write(fd: int, data) -> int:
        nonlocal room
        if room == 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        taken = real_write(fd, bytes(data[:room]))
        room -= taken
        return taken

    monkeypatch.setattr(os, "write", write)


@pytest.mark.parametrize("kind", ["csv", "tum", "hypotheses"])
def test_a_full_disk_leaves_whole_lines_and_an_error_naming_the_file(kind, tmp_path, monkeypatch):
    """Whatever byte the disk fills at (in the header, inside a line or between two), the
    streamed file ends at its last whole line and the error names it, the writer left as a
    context manager or not."""
    make = {
        "csv": EstimatesWriter,
        "tum": TumWriter,
        "hypotheses": lambda path: HypothesesWriter(path, 2),
    }[kind]
    rows = frame_rows(estimates_frame())
    for row in rows:
        row["hypotheses"] = [
            {
                "x_m": 1,
                "y_m": 2,
                "theta_deg": 3,
                "inlier_ratio": 0.25,
                "score": 0.5,
                "confidence": 1,
            }
        ] * 2
    whole = tmp_path / f"whole.{kind}"
    with make(whole) as writer:
        for row in rows:
            writer.write_row(row)
    written = whole.read_bytes()
    ends = [i + 1 for i, byte in enumerate(written) if byte == ord("\n")]
    for room in sorted({0, 5, *ends[:-1], *(end + 7 for end in ends[:-1])}):
        path = tmp_path / f"full-{room}.{kind}"
        with monkeypatch.context() as patch:
            _disk_with_room(patch, room)
            with pytest.raises(OutputError) as error:
                with make(path) as writer:
                    for row in rows:
                        writer.write_row(row)
                    pytest.fail("every line fitted")
        assert str(path) in str(error.value) and "No space left on device" in str(error.value)
        kept = max([0, *(end for end in ends if end <= room)])
        assert path.read_bytes() == written[:kept], room


FILL_A_DISK = """
import json, sys
from segloc_cli.io.files import OutputError
from segloc_cli.io.tables import EstimatesWriter
row = {c: 1.0 / 3.0 for c in json.loads(sys.argv[2])}
row.update(pose_id=1, n_local_segments=5, status="ok", window_scans=1)
try:
    with EstimatesWriter(sys.argv[1]) as writer:
        while True:
            writer.write_row(row)
except OutputError as error:
    with open(sys.argv[1], "rb") as stream:
        print(json.dumps([str(error), stream.read().decode()]))
"""


@needs_tmpfs
def test_a_full_tmpfs_leaves_the_estimates_whole_rows(tmp_path):
    """On a real full disk (a 4 KiB tmpfs) the estimates end at their last whole row."""
    small = tmp_path / "small"
    small.mkdir()
    path = small / "est.csv"
    mount = f'mount -t tmpfs -o size=4k tmpfs {small} && exec "$@"'
    result = subprocess.run(
        ["unshare", "-rm", "sh", "-c", mount, "sh", sys.executable, "-c", FILL_A_DISK,
         str(path), json.dumps(ESTIMATE_COLUMNS)],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    error, text = json.loads(result.stdout)
    assert error.startswith(f"{path}: cannot write file") and "No space left" in error
    assert text.endswith("\n") and len(text) > 4000 - 2 * len(text.splitlines()[1])
    assert len(read_estimates_text(tmp_path, text)) == text.count("\n") - 1


def read_estimates_text(tmp_path: Path, text: str) -> pd.DataFrame:
    path = tmp_path / "copy.csv"
    path.write_text(text)
    return read_estimates(path)


# --- pairing on the command line -------------------------------------------------------
# --- pairing on the command line -------------------------------------------------------

HALL = Path(__file__).resolve().parents[1] / "datasets" / "hall"


def hall_survey_with_row_3_at(tmp_path, time_s: float) -> Path:
    """The hall's survey (scans at 1, 2, ... 10 s) with row 3's time changed."""
    lines = (HALL / "survey.csv").read_text().splitlines()
    fields = lines[3].split(",")
    fields[1] = repr(time_s)
    lines[3] = ",".join(fields)
    path = tmp_path / "survey.csv"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_map_build_refuses_survey_rows_sharing_a_scan_time(tmp_path, capsys):
    survey = hall_survey_with_row_3_at(tmp_path, 2.0)
    out = tmp_path / "map.json"
    code, _, err = run_cli(
        capsys, "map", "build", HALL / "log.mcap", "--survey", survey, "--out", out
    )
    assert code == 2
    assert err == (
        f"segloc: error: {survey}, rows 2 and 3: both have time 2.000 s, so a scan at 2.000 s "
        "matches more than one row; give every row a distinct time\n"
    )
    assert not out.exists()


def test_localize_refuses_guess_rows_sharing_a_scan_time(tmp_path, capsys):
    guesses = hall_survey_with_row_3_at(tmp_path, 2.0)
    out = tmp_path / "est.csv"
    code, _, err = run_cli(
        capsys, "localize", HALL / "log.mcap", "--map", HALL / "map.json",
        "--initial", guesses, "--out", out,
    )  # fmt: skip
    assert code == 2
    assert err.startswith(f"segloc: error: {guesses}, rows 2 and 3: both have time 2.000 s")
    assert len(err.splitlines()) == 1
