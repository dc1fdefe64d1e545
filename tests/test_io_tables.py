"""Pose tables, TUM trajectories, estimates CSV and time matching."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from segloc_cli.errors import InputError
from segloc_cli.geometry import heading_to_quaternion, quaternion_to_heading
from segloc_cli.io.tables import (
    ESTIMATE_COLUMNS,
    PoseTable,
    nearest_by_time,
    read_estimates,
    read_pose_table,
    write_estimates,
    write_pose_table,
    write_tum,
)

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
    np.testing.assert_array_equal(back.time_s, table.time_s)
    np.testing.assert_array_equal(back.poses[:, :2], table.poses[:, :2])
    np.testing.assert_allclose(back.poses[:, 2], table.poses[:, 2], rtol=0, atol=1e-12)
    assert path.read_text().splitlines()[0] == "pose_id,time_s,x_m,y_m,theta_deg"


def test_pose_table_without_times_round_trip(tmp_path):
    table = PoseTable(np.array([1, 2]), np.full(2, np.nan), np.array([[0.0, 1, 0.5], [2, 3, -1]]))
    path = tmp_path / "poses.csv"
    write_pose_table(path, table)
    assert path.read_text().splitlines()[0] == "pose_id,x_m,y_m,theta_deg"
    back = read_pose_table(path, require_time=False)
    np.testing.assert_array_equal(back.pose_id, [1, 2])
    assert np.isnan(back.time_s).all()
    np.testing.assert_allclose(back.poses, table.poses, rtol=0, atol=1e-15)


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


def test_csv_without_x_m_header_gets_a_hint(tmp_path):
    path = tmp_path / "survey.csv"
    path.write_text("id,t,x,y,theta\n1,0,0,0,0\n")
    with pytest.raises(InputError, match=r"row 1: .*header pose_id,time_s,x_m,y_m,theta_deg"):
        read_pose_table(path)


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
            "overlap": [12.3456789012345, 0.0, np.nan],
            "inlier_ratio": [0.875, 1.0 / 3.0, np.nan],
            "runner_up_x_m": [3.5, np.nan, np.nan],
            "runner_up_y_m": [-1.25, np.nan, np.nan],
            "runner_up_theta_deg": [-90.5, np.nan, np.nan],
            "runner_up_ratio": [0.5, 0.0, np.nan],
            "n_local_segments": [14, 3, 0],
            "runtime_ms": [2.5, 3.75, 0.125],
            "status": ["ok", "ok, weak", "no_segments"],
        }
    )


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
    pd.testing.assert_frame_equal(back, frame, check_exact=True, check_dtype=False)
    assert back["status"].tolist() == ["ok", "ok, weak", "no_segments"]


def test_estimates_extra_columns_not_written_and_order_fixed(tmp_path):
    frame = estimates_frame()[list(reversed(ESTIMATE_COLUMNS))].assign(debug=[1, 2, 3])
    path = tmp_path / "est.csv"
    write_estimates(path, frame)
    assert path.read_text().splitlines()[0] == ",".join(ESTIMATE_COLUMNS)


def test_write_estimates_checks_columns(tmp_path):
    with pytest.raises(ValueError, match="overlap"):
        write_estimates(tmp_path / "e.csv", estimates_frame().drop(columns=["overlap"]))
    frame = estimates_frame()
    frame.loc[1, "time_s"] = np.nan
    with pytest.raises(ValueError, match="time_s"):
        write_estimates(tmp_path / "e.csv", frame)


HEADER = ",".join(ESTIMATE_COLUMNS)


def estimates_line(**fields: str) -> str:
    """One estimates CSV line: the given fields, every other column empty."""
    return ",".join(fields.get(c, "") for c in ESTIMATE_COLUMNS)


GOOD = {"pose_id": "1", "time_s": "1", "n_local_segments": "3", "runtime_ms": "1", "status": "ok"}


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
    np.testing.assert_array_equal(table.time_s, frame["time_s"][:2])
    np.testing.assert_array_equal(table.poses[:, :2], frame[["x_m", "y_m"]].to_numpy()[:2])
    np.testing.assert_allclose(
        np.rad2deg(table.poses[:, 2]), frame["theta_deg"][:2], rtol=0, atol=1e-12
    )
    # evo reads TUM files as plain numeric matrices with '#' comments.
    matrix = np.loadtxt(path, comments="#")
    assert matrix.shape == (2, 8)
    np.testing.assert_allclose(np.linalg.norm(matrix[:, 4:], axis=1), 1.0)
