"""Scoring localization estimates against surveyed ground truth: the paper's Table 1.

Errors are "surveyed minus computed" in the world frame, as in Reina & Gonzalez
(2000), section 5.2: positions in centimetres, headings in degrees wrapped to
[-180, 180). Every function here is pure; reading and writing files is the
command line's job.

Every pose that has an estimate (finite x, y and θ) is scored, whatever its
status, as trajectory tools such as evo score a trajectory: a summary that
changed with the localizer's own verdict would hide its confident mistakes.
The summary gives the counts by status beside the errors; ``only_ok`` gives
the view over accepted estimates alone.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict

import numpy as np
import pandas as pd

from segloc_cli.config import TIME_TOLERANCE_MS
from segloc_cli.errors import InputError
from segloc_cli.estimates import (
    COVARIANCE_COLUMNS,
    ESTIMATE_COLUMNS,
    ESTIMATED,
    STATUS_NO_ESTIMATE,
    PoseTable,
)
from segloc_cli.geometry import wrap_angle
from segloc_cli.latex import latex_text, with_needs
from segloc_cli.markdown import cell, pipe_table
from segloc_cli.method.confidence import RIGHT_PLACE_DEG, RIGHT_PLACE_M
from segloc_cli.numbers import json_text, rounded_frame
from segloc_cli.scoring.drift import travelled_m
from segloc_cli.scoring.gates import (
    Gates,
    beyond_mask,
    outcomes_json,
    pose_failures,
    survey_outcomes,
    unpaired_mask,
)
from segloc_cli.timing import pair_by_time
from segloc_cli.wording import counted, plural

ERROR_COLUMNS = (
    "ae_deg",
    "init_x_cm",
    "init_y_cm",
    "init_theta_deg",
    "err_x_cm",
    "err_y_cm",
    "err_theta_deg",
    "err_xy_cm",
)
"""Numeric columns of Table 1, in table order."""

FINAL_ERROR_COLUMNS = ("err_x_cm", "err_y_cm", "err_theta_deg", "err_xy_cm")
"""Errors of the final estimate; their summary covers the scored poses (``scored``)."""

TABLE_COLUMNS = ("pose_id", "time_s", "travelled_m", *ERROR_COLUMNS, "status")
"""Columns of Table 1: the survey's pose id and time (s), the distance travelled along the
surveyed poses up to it (m), the errors, the estimate's status."""

FORMATS = ("md", "csv", "latex", "json")

# Columns shown in the md and latex tables, with their decimals (the paper's: 0.1 cm, 0.01°)
# and headers: the paper's, and the position error's magnitude (XY) beside X and Y; a "|" in
# a header would split the Markdown cell.
_DISPLAY = (
    ("ae_deg", 2, "AE (°)", r"AE ($^\circ$)"),
    ("init_x_cm", 1, "init X (cm)", r"init $X$ (cm)"),
    ("init_y_cm", 1, "init Y (cm)", r"init $Y$ (cm)"),
    ("init_theta_deg", 2, "init θ (°)", r"init $\theta$ ($^\circ$)"),
    ("err_x_cm", 1, "X (cm)", r"$X$ (cm)"),
    ("err_y_cm", 1, "Y (cm)", r"$Y$ (cm)"),
    ("err_xy_cm", 1, "XY (cm)", r"$XY$ (cm)"),
    ("err_theta_deg", 2, "θ (°)", r"$\theta$ ($^\circ$)"),
)
_STAT_LABELS = {"RMS": "RMS", "max": "max abs"}
"""How the summary rows are labelled in the md and latex tables: ``max`` is of magnitudes."""
_MISSING_MD = "—"
_MISSING_LATEX = "--"


def _time_span(times_s: np.ndarray) -> str:
    finite = times_s[np.isfinite(times_s)]
    if finite.size == 0:
        return "no valid times"
    return f"{finite.min():.3f} to {finite.max():.3f} s ({counted(times_s.size, 'row')})"


def _wrapped_deg(diff_rad: np.ndarray) -> np.ndarray:
    return np.rad2deg(wrap_angle(diff_rad))


def _status_text(status: np.ndarray) -> np.ndarray:
    """Status words (N,) as str, "missing" where the estimate has none."""
    text = np.array([str(v) for v in status], dtype=object)
    return np.where(pd.isna(status) | (text == ""), "missing", text).astype(object)


def table1(
    estimates: pd.DataFrame,
    survey: PoseTable,
    tolerance_s: float = TIME_TOLERANCE_MS / 1e3,
    *,
    estimates_path: object = "estimates",
    survey_path: object = "survey",
) -> pd.DataFrame:
    """Per-pose errors of ``estimates`` against ``survey``, one row per survey pose.

    Each survey row is paired with the estimate nearest in time within
    ``tolerance_s`` seconds (``timing.pair_by_time``: two estimates with the
    time nearest a survey row, or two survey rows with one time, are refused
    with an ``InputError`` naming ``estimates_path`` or ``survey_path`` and the
    rows). Rows keep survey order; a survey row no estimate was paired with has status
    ``STATUS_NO_ESTIMATE`` and NaN in every column taken from an estimate, so a localizer
    that stopped answering shows as such instead of vanishing from the table.
    Columns (TABLE_COLUMNS): ``pose_id`` (the survey's id), ``time_s`` (the survey's time),
    ``travelled_m`` (the path length along every surveyed pose in time order, from the
    first, up to this one: a distance axis for errors that grow with travel), ``ae_deg``
    (surveyed heading minus the stage-1 heading; NaN when the row has no
    initial heading, as in a ``--global`` run, whose stage 1 has no window to
    search), ``init_x_cm``, ``init_y_cm``, ``init_theta_deg`` (surveyed minus
    initial guess), ``err_x_cm``, ``err_y_cm``, ``err_theta_deg`` (surveyed
    minus final estimate), ``err_xy_cm`` (Euclidean position error) and the
    estimate's ``status``; then the estimates' ``COVARIANCE_COLUMNS`` where they have
    them. World frame; cm and degrees, headings wrapped to
    [-180, 180). ``survey`` is a PoseTable or any object with its ``pose_id``
    (N,), ``time_s`` (N,) and ``poses`` (N, 3: x m, y m, θ rad) arrays. Errors
    are NaN where the estimate holds NaN (e.g. a failed pose).
    ``attrs["tolerance_s"]`` is the tolerance, for ``summary`` and the gates.

    Raises InputError when ``estimates`` lacks a column, a pairing is
    ambiguous, or no survey row has a match.
    """
    missing = [c for c in ESTIMATE_COLUMNS if c not in estimates.columns]
    if missing:
        raise InputError(f"estimates lack the column(s) {', '.join(missing)}")

    survey_times_s = np.asarray(survey.time_s, dtype=float).reshape(-1)
    survey_ids = np.asarray(survey.pose_id).reshape(-1)
    survey_poses = np.asarray(survey.poses, dtype=float).reshape(-1, 3)
    est_times_s = estimates["time_s"].to_numpy(dtype=float)

    match = pair_by_time(
        survey_times_s,
        est_times_s,
        tolerance_s,
        query_path=survey_path,
        ref_path=estimates_path,
        query_label="row",
        ref_label="row",
    )
    matched = match >= 0
    if not matched.any():
        raise InputError(
            f"no estimate lies within {tolerance_s:g} s of any survey time: "
            f"estimates span {_time_span(est_times_s)}, "
            f"survey spans {_time_span(survey_times_s)}; are they of the same log? "
            "(--tolerance-ms widens the pairing)"
        )
    est = estimates.iloc[match[matched]]

    def col(name: str) -> np.ndarray:
        """The estimates' column, one value per survey row (NaN where none was paired)."""
        values = np.full(survey_times_s.size, np.nan)
        values[matched] = est[name].to_numpy(dtype=float)
        return values

    truth_x_m, truth_y_m, truth_theta_rad = survey_poses.T
    final = final_errors(survey_poses, col("x_m"), col("y_m"), col("theta_deg"))
    # Stage 1 searched a window around the initial heading; without one its peak is not an answer.
    align_theta_deg = np.where(np.isfinite(col("init_theta_deg")), col("align_theta_deg"), np.nan)
    status = np.full(survey_times_s.size, STATUS_NO_ESTIMATE, dtype=object)
    status[matched] = _status_text(est["status"].to_numpy(dtype=object))
    table = pd.DataFrame(
        {
            "pose_id": survey_ids.astype(np.int64),
            "time_s": survey_times_s,
            "travelled_m": _travelled_m(survey_times_s, survey_poses),
            "ae_deg": _wrapped_deg(truth_theta_rad - np.deg2rad(align_theta_deg)),
            "init_x_cm": 100.0 * (truth_x_m - col("init_x_m")),
            "init_y_cm": 100.0 * (truth_y_m - col("init_y_m")),
            "init_theta_deg": _wrapped_deg(truth_theta_rad - np.deg2rad(col("init_theta_deg"))),
            **final,
            "status": status,
        },
        columns=list(TABLE_COLUMNS),
    )
    for name in COVARIANCE_COLUMNS:
        if name in est.columns:
            table[name] = col(name)
    table.attrs["tolerance_s"] = float(tolerance_s)
    return table


def _travelled_m(times_s: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """(N,) ``drift.travelled_m`` along ``poses`` taken in time order, in the given order."""
    order = np.argsort(times_s, kind="stable")
    along = np.empty(len(order))
    along[order] = travelled_m(poses[order])
    return along


def final_errors(
    truth: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, theta_deg: np.ndarray
) -> dict[str, np.ndarray]:
    """Errors of estimates (metres, degrees) against their true poses ``truth`` (N, 3: x m,
    y m, θ rad), surveyed minus estimate: ``err_x_cm``, ``err_y_cm``, ``err_theta_deg``
    (wrapped to [-180, 180)) and ``err_xy_cm`` (Euclidean), NaN where the estimate is."""
    err_x_cm = 100.0 * (truth[:, 0] - x_m)
    err_y_cm = 100.0 * (truth[:, 1] - y_m)
    return {
        "err_x_cm": err_x_cm,
        "err_y_cm": err_y_cm,
        "err_theta_deg": _wrapped_deg(truth[:, 2] - np.deg2rad(theta_deg)),
        "err_xy_cm": np.hypot(err_x_cm, err_y_cm),
    }


def scored(table: pd.DataFrame, only_ok: bool = False) -> np.ndarray:
    """(N,) bool: the poses of a ``table1`` result whose final errors enter the summary.

    A pose is scored when its final errors (X, Y, θ) are all finite, whatever
    its status; with ``only_ok`` also only when its status is an accepted one
    (``ok``, or ``recovered`` when tracking).
    """
    finite = np.all(
        np.isfinite(table[["err_x_cm", "err_y_cm", "err_theta_deg"]].to_numpy(dtype=float)),
        axis=1,
    )
    if only_ok:
        finite &= table["status"].isin(ESTIMATED).to_numpy()
    return finite


def _rms(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(finite**2))) if finite.size else math.nan


def _max_abs(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(np.max(np.abs(finite))) if finite.size else math.nan


def _status_counts(table: pd.DataFrame) -> dict[str, int]:
    """Poses per status, most frequent first (ties by name); surveyed poses without an
    estimate (``STATUS_NO_ESTIMATE``) last."""
    counts = table["status"].astype(str).value_counts()
    ordered = sorted(counts.items(), key=lambda item: (-item[1], item[0]))
    result = {str(status): int(n) for status, n in ordered if status != STATUS_NO_ESTIMATE}
    unpaired = int(counts.get(STATUS_NO_ESTIMATE, 0))
    if unpaired:
        result[STATUS_NO_ESTIMATE] = unpaired
    return result


def summary(table: pd.DataFrame, only_ok: bool = False, gates: Gates | None = None) -> pd.DataFrame:
    """RMS and maximum absolute value of each error column of a ``table1`` result.

    Returns a DataFrame indexed ``RMS``, ``max`` with the ERROR_COLUMNS as
    columns, every column over the same poses: the scored ones (``scored``:
    every pose with a final estimate, or with ``only_ok`` those with an
    accepted status). NaN values are skipped; a column with no value left is
    NaN. ``attrs`` holds the counts:

    - ``n_surveyed``: survey rows (the table's); ``n_poses``: those matched to an estimate
      row;
    - ``n_scored``: poses in the summary; ``only_ok``: the option;
    - ``n_no_estimate``: surveyed poses without a final estimate (unmatched in
      time, or matched to a row without a pose);
    - ``n_failed``: matched poses whose status is not an accepted one;
    - ``status_counts``: poses per status (dict, most frequent first; surveyed
      poses without an estimate row as ``no_estimate``);
    - ``verdict``: how the statuses bear out (``verdict_quality``);
    - ``gates``: the ``Gates`` given (None: none); ``outcomes``: each gate's
      ``GateOutcome``; ``n_beyond``: poses whose final error exceeds a per-pose
      limit, and ``n_gate_failed``: the poses failing the per-pose limits
      (beyond, or not accepted, or missing an error); both None without a
      per-pose limit.
    """
    score = scored(table, only_ok)
    stats = {}
    for name in ERROR_COLUMNS:
        values = table[name].to_numpy(dtype=float)[score]
        stats[name] = [_rms(values), _max_abs(values)]
    result = pd.DataFrame(stats, index=pd.Index(["RMS", "max"], name="stat"))
    n_surveyed = len(table)
    has_pose = scored(table)
    accepted = table["status"].isin(ESTIMATED).to_numpy()
    paired = ~unpaired_mask(table)
    gates = gates if gates is not None and gates.any else None
    per_pose = gates is not None and gates.per_pose
    limits = gates if gates is not None else Gates()
    result.attrs["verdict"] = verdict_quality(table)
    result.attrs.update(
        {
            "n_surveyed": n_surveyed,
            "n_poses": int(np.count_nonzero(paired)),
            "n_scored": int(np.count_nonzero(score)),
            "only_ok": bool(only_ok),
            "n_no_estimate": n_surveyed - int(np.count_nonzero(has_pose)),
            "n_failed": int(np.count_nonzero(paired & ~accepted)),
            "status_counts": _status_counts(table),
            "tolerance_s": table.attrs.get("tolerance_s"),
            "gates": gates,
            "outcomes": [] if gates is None else survey_outcomes(table, score, gates),
            "n_beyond": int(np.count_nonzero(beyond_mask(table, limits))) if per_pose else None,
            "n_gate_failed": len(pose_failures(table, limits)) if per_pose else None,
        }
    )
    return result


def verdict_quality(table: pd.DataFrame) -> dict[str, int]:
    """How the statuses of a ``table1`` result bear out against the truth.

    Right: within ``RIGHT_PLACE_M`` and ``RIGHT_PLACE_DEG`` of the surveyed pose, the place the
    confidence speaks of; a row without a pose is wrong. Flagged: a status other than
    an accepted one (``ok``, ``recovered``). Counts: ``accepted`` and ``accepted_right``,
    ``right`` and ``right_flagged``, ``wrong`` and ``wrong_flagged``, over the answers
    given: surveyed poses no estimate was paired with are left out.
    """
    table = table[~unpaired_mask(table)]
    err_m = table["err_xy_cm"].to_numpy(dtype=float) / 100.0
    err_deg = np.abs(table["err_theta_deg"].to_numpy(dtype=float))
    with np.errstate(invalid="ignore"):
        right = (err_m <= RIGHT_PLACE_M) & (err_deg <= RIGHT_PLACE_DEG)
    flagged = ~table["status"].isin(ESTIMATED).to_numpy()
    count = np.count_nonzero
    return {
        "accepted": int(count(~flagged)),
        "accepted_right": int(count(~flagged & right)),
        "right": int(count(right)),
        "right_flagged": int(count(right & flagged)),
        "wrong": int(count(~right)),
        "wrong_flagged": int(count(~right & flagged)),
    }


def _number_text(value: float, decimals: int, missing: str) -> str:
    if not np.isfinite(value):
        return missing
    text = f"{value:.{decimals}f}"
    # "-0.0" reads as a sign that the precision shown does not support.
    return text[1:] if text.startswith("-") and float(text) == 0.0 else text


_STAGE_COLUMNS = ("ae_deg", "init_x_cm", "init_y_cm", "init_theta_deg")
"""Columns only a localizer with stages and initial guesses fills (segloc's own)."""


def _displayed(table: pd.DataFrame) -> tuple[tuple[str, int, str, str], ...]:
    """The columns the md and latex tables show: all of ``_DISPLAY``, less AE and the initial
    errors when no pose has any (another localizer's estimates, which have neither)."""
    stages = table[list(_STAGE_COLUMNS)].to_numpy(dtype=float)
    if len(table) and not np.isfinite(stages).any():
        return tuple(d for d in _DISPLAY if d[0] not in _STAGE_COLUMNS)
    return _DISPLAY


def _display_rows(
    table: pd.DataFrame,
    stats: pd.DataFrame | None,
    missing: str,
    shown: tuple[tuple[str, int, str, str], ...],
) -> list[list[str]]:
    """Table rows then the RMS and max rows (none without ``stats``), as text cells (pose,
    the ``shown`` columns, status)."""
    numbers = [table[c].to_numpy(dtype=float) for c, *_ in shown]
    decimals = [d for _, d, *_ in shown]
    columns = list(zip(numbers, decimals, strict=True))
    rows = [
        [str(pose_id), *(_number_text(v[i], d, missing) for v, d in columns), str(status)]
        for i, (pose_id, status) in enumerate(zip(table["pose_id"], table["status"], strict=True))
    ]
    for stat, record in [] if stats is None else stats.iterrows():
        cells = [_number_text(record[c], d, missing) for c, d, *_ in shown]
        rows.append([_STAT_LABELS.get(str(stat), str(stat)), *cells, ""])
    return rows


def summary_lines(stats: pd.DataFrame) -> list[str]:
    """The counts of a ``summary`` in words, one sentence a line.

    Poses by status; which poses the RMS and max cover and how many surveyed
    poses have no estimate; how the statuses bear out; with per-pose limits,
    how many poses exceed them and how many fail them; each gate's outcome.
    """
    attrs = stats.attrs
    counts = ", ".join(f"{status} {n}" for status, n in attrs["status_counts"].items())
    lines = [f"{counted(attrs['n_surveyed'], 'surveyed pose')}: {counts}."]
    scored = counted(attrs["n_scored"], "pose")
    if attrs["only_ok"]:
        cover = f"the {scored} with status ok"
    else:
        cover = f"the {scored} with an estimate, whatever their status"
    without = attrs["n_no_estimate"]
    none = f"; {counted(without, 'surveyed pose')} {plural(without, 'has', 'have')} no estimate"
    lines.append(
        f"RMS and max (of absolute values) cover {cover}{none if without else ''}. "
        "Errors are surveyed minus computed; XY is the position error's magnitude √(X² + Y²)."
    )
    v = attrs["verdict"]
    lines.append(
        f"Verdict (right = within {RIGHT_PLACE_M * 100:g} cm and {RIGHT_PLACE_DEG:g}° of the "
        f"survey): {v['accepted_right']} of {v['accepted']} accepted answers right; "
        f"{v['right_flagged']} of {v['right']} right answers flagged; {v['wrong_flagged']} of "
        f"{v['wrong']} wrong answers flagged."
    )
    if attrs["n_beyond"] is not None:
        with_estimate = attrs["n_surveyed"] - without
        limits = attrs["gates"].limits_text()
        line = (
            f"{attrs['n_beyond']} of {counted(with_estimate, 'pose')} "
            f"exceed the per-pose limits ({limits})"
        )
        more = attrs["n_gate_failed"] - attrs["n_beyond"]
        if more:
            line += (
                f"; the gate fails {attrs['n_gate_failed']}, counting {more} without an "
                "accepted estimate (status other than ok)"
            )
        lines.append(line + ".")
    lines += [f"Gate: {outcome.text}." for outcome in attrs["outcomes"]]
    return lines


def pose_table_md(
    table: pd.DataFrame,
    stats: pd.DataFrame | None = None,
    *,
    rows: np.ndarray | None = None,
    extra: Mapping[str, Sequence[str]] | None = None,
) -> str:
    """A ``table1`` result as the md format shows it: a Markdown table of the poses at
    positions ``rows`` (default: all), in the columns the whole table shows, with the
    ``extra`` columns after the status (header → a cell per pose shown); with its
    ``summary`` ``stats``, the RMS and max rows after the poses and the lines of
    ``summary_lines`` under the table."""
    shown = _displayed(table)
    part = table if rows is None else table.iloc[rows]
    extra = extra or {}
    headers = ["pose", *(md for _, _, md, _ in shown), "status", *extra]
    cells = _display_rows(part, stats, _MISSING_MD, shown)
    for i, row in enumerate(cells):
        row += [str(column[i]) if i < len(part) else "" for column in extra.values()]
    # A bare "|" in a cell (a reason such as "|XY| 12.0 cm > 10.0 cm") would end it.
    cells = [[cell(text) for text in row] for row in cells]
    aligns = ("left", *("right" for _ in shown), "left", *("left" for _ in extra))
    body = pipe_table(headers, cells, aligns)
    if stats is None:
        return body + "\n"
    return body + "\n\n" + "\n".join(summary_lines(stats)) + "\n"


def _format_latex(table: pd.DataFrame, stats: pd.DataFrame) -> str:
    """A booktabs ``tabular`` (``latex.py``: its first line says it needs booktabs), summary
    rows under a rule and the counts of ``summary_lines`` in full-width rows under another."""
    shown = _displayed(table)
    headers = ["Pose", *(tex for _, _, _, tex in shown), "Status"]
    rows = _display_rows(table, stats, _MISSING_LATEX, shown)
    for row in rows:
        row[1:-1] = [f"${text}$" if text != _MISSING_LATEX else text for text in row[1:-1]]
    frame = pd.DataFrame(rows, columns=headers)
    styler = frame.style.hide(axis="index").format(escape="latex", subset=["Status"])
    n_columns = len(shown) + 2
    latex = styler.to_latex(column_format="l" + "r" * len(shown) + "l", hrules=True)
    lines = latex.splitlines()
    # Styler puts no rule between body rows; set the summary rows (last in the body) apart.
    lines.insert(lines.index(r"\bottomrule") - len(stats), r"\midrule")
    notes = [
        f"\\multicolumn{{{n_columns}}}{{l}}{{\\footnotesize {latex_text(line)}}} \\\\"
        for line in summary_lines(stats)
    ]
    at = lines.index(r"\bottomrule")
    lines[at:at] = [r"\midrule", *notes]
    return with_needs("\n".join(lines))


def _json_value(value: object) -> object:
    if isinstance(value, float | np.floating):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, np.integer | np.bool_):
        return value.item()
    return value


def _pose_flags(table: pd.DataFrame, stats: pd.DataFrame) -> tuple[np.ndarray, np.ndarray | None]:
    """Per pose: scored (in the summary of final errors), and beyond the gate (None: no gate)."""
    score = scored(table, stats.attrs["only_ok"])
    if stats.attrs["n_beyond"] is None:
        return score, None
    return score, beyond_mask(table, stats.attrs["gates"])


def _format_csv(table: pd.DataFrame, stats: pd.DataFrame) -> str:
    score, beyond = _pose_flags(table, stats)
    frame = table[list(TABLE_COLUMNS)].copy()
    frame["scored"] = score.astype(int)
    frame["beyond_gate"] = pd.array(
        [pd.NA] * len(table) if beyond is None else beyond.astype(int), dtype="Int64"
    )
    return rounded_frame(frame).to_csv(index=False)


def _format_json(table: pd.DataFrame, stats: pd.DataFrame) -> str:
    score, beyond = _pose_flags(table, stats)
    poses = []
    for i, row in enumerate(table[list(TABLE_COLUMNS)].itertuples(index=False)):
        pose = {name: _json_value(value) for name, value in zip(TABLE_COLUMNS, row, strict=True)}
        pose["scored"] = bool(score[i])
        pose["beyond_gate"] = None if beyond is None else bool(beyond[i])
        poses.append(pose)
    attrs = stats.attrs
    summary_out: dict[str, object] = {
        name: _json_value(attrs[name])
        for name in (
            "n_surveyed",
            "n_poses",
            "n_scored",
            "n_no_estimate",
            "n_failed",
            "only_ok",
            "tolerance_s",
        )
    }
    summary_out["status_counts"] = dict(attrs["status_counts"])
    summary_out["verdict"] = dict(attrs["verdict"])
    summary_out["gate"] = (
        None
        if attrs["gates"] is None
        else {
            "limits": {k: v for k, v in asdict(attrs["gates"]).items() if v is not None},
            "n_beyond": attrs["n_beyond"],
            "n_gate_failed": attrs["n_gate_failed"],
            "outcomes": outcomes_json(attrs["outcomes"]),
        }
    )
    for stat, record in stats.iterrows():
        summary_out[str(stat)] = {c: _json_value(record[c]) for c in ERROR_COLUMNS}
    return json_text({"poses": poses, "summary": summary_out})


def format_table(table: pd.DataFrame, summary: pd.DataFrame, fmt: str) -> str:
    """Render a ``table1`` result and its ``summary`` as text in format ``fmt``.

    - ``md``: a Markdown table like the paper's (0.1 cm, 0.01°), RMS and max rows
      after the poses, then the counts of ``summary_lines``; AE and the initial errors
      are left out when no pose has them (another localizer's estimates).
    - ``csv``: the per-pose rows, TABLE_COLUMNS (rounded to their units' precision,
      ``numbers.py``, as every number of csv and json) then ``scored``
      (1 when the pose is in the RMS and max) and ``beyond_gate`` (1 when an
      error exceeds a --fail-above limit, 0 when not, empty without limits).
    - ``latex``: a booktabs ``tabular`` of the md content.
    - ``json``: ``{"poses": [...], "summary": {...}}``: each pose with TABLE_COLUMNS,
      ``scored`` and ``beyond_gate``; the summary with ``n_surveyed``, ``n_poses``,
      ``n_scored``, ``n_no_estimate``, ``n_failed``, ``only_ok``, ``tolerance_s``,
      ``status_counts``, ``gate`` (null, or the ``limits`` set, ``n_beyond``,
      ``n_gate_failed`` and each gate's ``outcomes``), ``RMS`` and ``max``; NaN
      written as null.
    """
    if fmt == "md":
        return pose_table_md(table, summary)
    if fmt == "csv":
        return _format_csv(table, summary)
    if fmt == "latex":
        return _format_latex(table, summary)
    if fmt == "json":
        return _format_json(table, summary)
    raise ValueError(f"unknown table format {fmt!r}; choose one of {', '.join(FORMATS)}")
