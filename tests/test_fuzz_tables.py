"""Pose tables, estimates and relations of arbitrary and mangled text: sound tables or one line.

Every outcome of ``read_pose_table`` (survey CSV, TUM trajectory, initial
guesses: one reader), ``read_estimates`` and ``read_relations`` must be either
a table whose poses are finite and whose ids are unique, or an ``InputError``
of one line that names the file; nothing else may escape.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from fuzzing import ODD_TOKENS, fuzz_settings, outcome
from hypothesis import given
from hypothesis import strategies as st

from segloc_cli.errors import InputError
from segloc_cli.estimates import ESTIMATE_COLUMNS, ESTIMATE_INT_COLUMNS, PoseTable, Relations
from segloc_cli.io.relations import read_relations
from segloc_cli.io.tables import MAX_COORDINATE_M, read_estimates, read_pose_table

GOOD_NUMBERS = st.one_of(
    st.floats(min_value=-1e3, max_value=1e3, allow_nan=False).map(repr),
    st.integers(min_value=-5, max_value=50).map(str),
)

# Share of odd tokens among a file's numbers: most files are nearly valid, so that the
# readers' success paths are fuzzed as well as their refusals.
ODD_SHARE = st.sampled_from([0.0, 0.0, 0.02, 0.3])


def number(odd_share: float = 0.3) -> st.SearchStrategy[str]:
    return st.floats(min_value=0.0, max_value=1.0).flatmap(
        lambda u: st.sampled_from(ODD_TOKENS) if u < odd_share else GOOD_NUMBERS
    )


def mangle(draw, text: str) -> bytes:
    """``text`` as UTF-8, maybe with a byte-order mark, a few bytes overwritten or a cut."""
    data = bytearray(draw(st.sampled_from([b"", b"\xef\xbb\xbf"])) + text.encode("utf-8"))
    if draw(st.booleans()):
        return bytes(data)
    for _ in range(draw(st.integers(min_value=0, max_value=3))):
        if data:
            at = draw(st.integers(min_value=0, max_value=len(data) - 1))
            data[at] = draw(st.sampled_from([0x00, 0x0A, 0x0D, 0x2C, 0x20, 0x23, 0xFF, 0x22]))
    if draw(st.booleans()):
        data = data[: draw(st.integers(min_value=0, max_value=len(data)))]
    return bytes(data)


def check_pose_table(result, require_time: bool) -> None:
    if isinstance(result, InputError):
        return
    assert isinstance(result, PoseTable)
    n = len(result)
    assert n > 0
    assert result.pose_id.shape == result.time_s.shape == (n,)
    assert result.pose_id.dtype == np.int64
    assert len(set(result.pose_id.tolist())) == n
    assert result.poses.shape == (n, 3)
    assert np.all(np.isfinite(result.poses))
    assert np.all(np.abs(result.poses[:, :2]) <= MAX_COORDINATE_M)
    if require_time:
        assert np.all(np.isfinite(result.time_s))
    else:
        assert np.all(np.isfinite(result.time_s) | np.isnan(result.time_s))


def read_table(tmp_path, data: bytes, require_time: bool = True, name: str = "table.csv"):
    path = tmp_path / name
    path.write_bytes(data)
    result = outcome(lambda p: read_pose_table(p, require_time=require_time), path)
    check_pose_table(result, require_time)
    return result


def check_estimates(result) -> None:
    if isinstance(result, InputError):
        return
    assert isinstance(result, pd.DataFrame)
    assert list(result.columns) == ESTIMATE_COLUMNS
    assert np.all(np.isfinite(result["time_s"].to_numpy(dtype=float)))
    for column in ESTIMATE_INT_COLUMNS:
        assert result[column].dtype == np.int64
    floats = [c for c in ESTIMATE_COLUMNS if c not in (*ESTIMATE_INT_COLUMNS, "status")]
    values = result[floats].to_numpy(dtype=float)
    # Empty fields are NaN; nothing infinite gets through.
    assert not np.any(np.isinf(values))


def read_est(tmp_path, data: bytes):
    path = tmp_path / "est.csv"
    path.write_bytes(data)
    result = outcome(read_estimates, path)
    check_estimates(result)
    return result


def check_relations(result) -> None:
    if isinstance(result, InputError):
        return
    assert isinstance(result, Relations)
    assert len(result) > 0
    for array in (result.t1_s, result.t2_s, result.delta):
        assert np.all(np.isfinite(array))
    assert result.delta.shape == (len(result), 3)


def read_rel(tmp_path, data: bytes):
    path = tmp_path / "ref.relations"
    path.write_bytes(data)
    result = outcome(read_relations, path)
    check_relations(result)
    return result


# --- arbitrary text ---------------------------------------------------------------------


@given(st.binary(max_size=2000), st.booleans())
@fuzz_settings
def test_arbitrary_bytes_as_a_pose_table(tmp_path, data, require_time):
    read_table(tmp_path, data, require_time)


@given(st.text(max_size=600))
@fuzz_settings
def test_arbitrary_text_in_every_reader(tmp_path, text):
    data = text.encode("utf-8", "surrogatepass")
    read_table(tmp_path, data)
    read_est(tmp_path, data)
    read_rel(tmp_path, data)


# --- survey CSV and initial guesses ---------------------------------------------------------


@st.composite
def survey_csv(draw) -> bytes:
    names = ["pose_id", "time_s", "x_m", "y_m", "theta_deg"]
    header = draw(st.permutations(names))
    if draw(st.integers(0, 4)) == 0:
        header = header[: draw(st.integers(min_value=1, max_value=len(header)))]
    if draw(st.booleans()):
        header = [*header, draw(st.sampled_from(["note", "original_time_s", "x_m"]))]
    odd = draw(ODD_SHARE)
    rows = []
    for k in range(draw(st.integers(min_value=0, max_value=8))):
        width = len(header) + draw(st.sampled_from([0] * 12 + [-1, 1]))
        cells = draw(st.lists(number(odd), min_size=max(width, 0), max_size=max(width, 0)))
        if "pose_id" in header and len(cells) == len(header) and draw(st.integers(0, 5)):
            cells[header.index("pose_id")] = str(k)
        rows.append(",".join(cells))
    comments = draw(st.sampled_from(["", "# survey\n", "\n\n"]))
    text = comments + ",".join(header) + "\n" + "\n".join(rows)
    return mangle(draw, text + draw(st.sampled_from(["\n", "", "\r\n"])))


@given(survey_csv(), st.booleans())
@fuzz_settings
def test_mangled_survey_csv(tmp_path, data, require_time):
    read_table(tmp_path, data, require_time)


@given(st.lists(st.sampled_from(["1", "1.0", "2", str(2**53), str(2**53 + 1), "-0", "1e0"])))
@fuzz_settings
def test_pose_ids_are_unique_or_refused(tmp_path, ids):
    lines = ["pose_id,time_s,x_m,y_m,theta_deg"]
    lines += [f"{pid},{k},0,0,0" for k, pid in enumerate(ids)]
    result = read_table(tmp_path, ("\n".join(lines) + "\n").encode())
    exact = [int(float(pid)) if "." in pid or "e" in pid else int(pid) for pid in ids]
    if ids and len(set(exact)) == len(exact):
        assert isinstance(result, PoseTable)
        assert result.pose_id.tolist() == exact
    else:
        assert isinstance(result, InputError)


# --- TUM ------------------------------------------------------------------------------------


@st.composite
def tum_text(draw) -> bytes:
    odd = draw(ODD_SHARE)
    lines = []
    for _ in range(draw(st.integers(min_value=0, max_value=8))):
        width = draw(st.sampled_from([8] * 12 + [7, 9, 1]))
        fields = draw(st.lists(number(odd), min_size=width, max_size=width))
        # Quaternions from tiny to huge, and all zeros.
        if width == 8 and draw(st.booleans()):
            scale = draw(st.sampled_from([1e-300, 1e-30, 1.0, 1e30, 1e300, 0.0]))
            fields[4:] = [repr(scale * v) for v in draw(st.lists(st.floats(-1, 1), min_size=4,
                                                                 max_size=4))]  # fmt: skip
        separator = draw(st.sampled_from([" ", "\t", "  "]))
        lines.append(separator.join(fields))
        if draw(st.booleans()):
            lines.append(draw(st.sampled_from(["# comment", "", "   "])))
    return mangle(draw, "\n".join(lines) + "\n")


@given(tum_text())
@fuzz_settings
def test_mangled_tum(tmp_path, data):
    read_table(tmp_path, data, name="traj.tum")


# --- estimates CSV --------------------------------------------------------------------------


@st.composite
def estimates_csv(draw) -> bytes:
    header = list(ESTIMATE_COLUMNS)
    if draw(st.integers(0, 4)) == 0:
        header.remove(draw(st.sampled_from(ESTIMATE_COLUMNS)))
    if draw(st.booleans()):
        header = draw(st.permutations(header))
    odd = draw(ODD_SHARE)
    rows = []
    for _ in range(draw(st.integers(min_value=0, max_value=5))):
        cells = []
        for column in header:
            if column == "status":
                cells.append(draw(st.sampled_from(["ok", "ambiguous", "lost", "", "x,y"])))
            elif column in ("time_s", *ESTIMATE_INT_COLUMNS):
                cells.append(draw(st.one_of(st.integers(0, 100).map(str), number(odd))))
            else:
                cells.append(draw(st.one_of(st.just(""), number(odd))))
        if draw(st.integers(0, 6)) == 0:
            cells = cells[:-1]
        rows.append(",".join(cells))
    return mangle(draw, ",".join(header) + "\n" + "\n".join(rows) + "\n")


@given(estimates_csv())
@fuzz_settings
def test_mangled_estimates(tmp_path, data):
    read_est(tmp_path, data)


# --- relations -------------------------------------------------------------------------------


@st.composite
def relations_text(draw) -> bytes:
    odd = draw(ODD_SHARE)
    lines = []
    for _ in range(draw(st.integers(min_value=0, max_value=8))):
        width = draw(st.sampled_from([8] * 12 + [7, 9]))
        lines.append(" ".join(draw(st.lists(number(odd), min_size=width, max_size=width))))
        if draw(st.booleans()):
            lines.append(draw(st.sampled_from(["# t1 t2 dx dy dz droll dpitch dyaw", ""])))
    return mangle(draw, "\n".join(lines) + "\n")


@given(relations_text())
@fuzz_settings
def test_mangled_relations(tmp_path, data):
    read_rel(tmp_path, data)


# --- very long lines ---------------------------------------------------------------------------


@given(st.sampled_from(["1", "x", ",", " ", "\x00"]), st.integers(min_value=1, max_value=300_000))
@fuzz_settings
def test_very_long_lines(tmp_path, unit, length):
    line = (unit * math.ceil(length / len(unit)))[:length]
    for text in (
        f"pose_id,time_s,x_m,y_m,theta_deg\n1,0,{line},0,0\n",
        f"{line}\n",
        f"1 2 3 {line} 5 6 7 8\n",
    ):
        read_table(tmp_path, text.encode())
        read_est(tmp_path, text.encode())
        read_rel(tmp_path, text.encode())
