"""Scoring localization estimates against surveyed ground truth: the paper's Table 1.

Errors are "surveyed minus computed" in the world frame, as in Reina & Gonzalez
(2000), section 5.2: positions in centimetres, headings in degrees wrapped to
[-180, 180). Every function here is pure; reading and writing files is the
command line's job.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd

from segloc_cli.errors import InputError
from segloc_cli.geometry import wrap_angle
from segloc_cli.io.tables import ESTIMATE_COLUMNS, PoseTable, nearest_by_time
from segloc_cli.localize import ESTIMATED

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
"""Errors of the final estimate; only poses with status ``ok`` count in their summary."""

TABLE_COLUMNS = ("pose_id", *ERROR_COLUMNS, "status")

FORMATS = ("md", "csv", "latex", "json")

# Columns shown in the md and latex tables, with their decimals (the paper's: 0.1 cm, 0.01°)
# and headers. err_xy_cm stays in csv and json only, as the paper has no such column.
_DISPLAY = (
    ("ae_deg", 2, "AE (°)", r"AE ($^\circ$)"),
    ("init_x_cm", 1, "init X (cm)", r"init $X$ (cm)"),
    ("init_y_cm", 1, "init Y (cm)", r"init $Y$ (cm)"),
    ("init_theta_deg", 2, "init θ (°)", r"init $\theta$ ($^\circ$)"),
    ("err_x_cm", 1, "X (cm)", r"$X$ (cm)"),
    ("err_y_cm", 1, "Y (cm)", r"$Y$ (cm)"),
    ("err_theta_deg", 2, "θ (°)", r"$\theta$ ($^\circ$)"),
)
_MISSING_MD = "—"
_MISSING_LATEX = "--"

# Errors pass through degree/radian conversions; a pose exactly at a limit must not fail on
# the last bits of that round trip.
_GATE_SLACK = 1e-9


def _time_span(times_s: np.ndarray) -> str:
    finite = times_s[np.isfinite(times_s)]
    if finite.size == 0:
        return "no valid times"
    return f"{finite.min():.3f} to {finite.max():.3f} s ({times_s.size} rows)"


def _wrapped_deg(diff_rad: np.ndarray) -> np.ndarray:
    return np.rad2deg(wrap_angle(diff_rad))


def _status_text(status: np.ndarray) -> np.ndarray:
    """Status words (N,) as str, "missing" where the estimate has none."""
    text = np.array([str(v) for v in status], dtype=object)
    return np.where(pd.isna(status) | (text == ""), "missing", text).astype(object)


def table1(estimates: pd.DataFrame, survey: PoseTable, tolerance_s: float = 0.05) -> pd.DataFrame:
    """Per-pose errors of ``estimates`` against ``survey``, one row per matched survey pose.

    Each survey row is paired with the estimate nearest in time within
    ``tolerance_s`` seconds; unmatched survey rows are left out and the rest keep
    survey order. Columns (TABLE_COLUMNS): ``pose_id`` (the survey's id),
    ``ae_deg`` (surveyed heading minus the stage-1 heading), ``init_x_cm``,
    ``init_y_cm``, ``init_theta_deg`` (surveyed minus initial guess),
    ``err_x_cm``, ``err_y_cm``, ``err_theta_deg`` (surveyed minus final
    estimate), ``err_xy_cm`` (Euclidean position error) and the estimate's
    ``status``. World frame; cm and degrees, headings wrapped to [-180, 180).
    ``survey`` is a PoseTable or any object with its ``pose_id`` (N,),
    ``time_s`` (N,) and ``poses`` (N, 3: x m, y m, θ rad) arrays.
    Errors are NaN where the estimate holds NaN (e.g. a failed pose).

    Raises InputError when ``estimates`` lacks a column or no survey row has a match.
    """
    missing = [c for c in ESTIMATE_COLUMNS if c not in estimates.columns]
    if missing:
        raise InputError(f"estimates lack the column(s) {', '.join(missing)}")

    survey_times_s = np.asarray(survey.time_s, dtype=float).reshape(-1)
    survey_ids = np.asarray(survey.pose_id).reshape(-1)
    survey_poses = np.asarray(survey.poses, dtype=float).reshape(-1, 3)
    est_times_s = estimates["time_s"].to_numpy(dtype=float)

    match = nearest_by_time(survey_times_s, est_times_s, tolerance_s)
    matched = match >= 0
    if not matched.any():
        raise InputError(
            f"no estimate lies within {tolerance_s:g} s of any survey time: "
            f"estimates span {_time_span(est_times_s)}, "
            f"survey spans {_time_span(survey_times_s)}"
        )
    est = estimates.iloc[match[matched]]
    truth = survey_poses[matched]

    def col(name: str) -> np.ndarray:
        return est[name].to_numpy(dtype=float)

    truth_x_m, truth_y_m, truth_theta_rad = truth[:, 0], truth[:, 1], truth[:, 2]
    err_x_cm = 100.0 * (truth_x_m - col("x_m"))
    err_y_cm = 100.0 * (truth_y_m - col("y_m"))
    return pd.DataFrame(
        {
            "pose_id": survey_ids[matched].astype(np.int64),
            "ae_deg": _wrapped_deg(truth_theta_rad - np.deg2rad(col("align_theta_deg"))),
            "init_x_cm": 100.0 * (truth_x_m - col("init_x_m")),
            "init_y_cm": 100.0 * (truth_y_m - col("init_y_m")),
            "init_theta_deg": _wrapped_deg(truth_theta_rad - np.deg2rad(col("init_theta_deg"))),
            "err_x_cm": err_x_cm,
            "err_y_cm": err_y_cm,
            "err_theta_deg": _wrapped_deg(truth_theta_rad - np.deg2rad(col("theta_deg"))),
            "err_xy_cm": np.hypot(err_x_cm, err_y_cm),
            "status": _status_text(est["status"].to_numpy(dtype=object)),
        },
        columns=list(TABLE_COLUMNS),
    )


def _rms(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(finite**2))) if finite.size else math.nan


def _max_abs(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(np.max(np.abs(finite))) if finite.size else math.nan


def summary(table: pd.DataFrame) -> pd.DataFrame:
    """RMS and maximum absolute value of each error column of a ``table1`` result.

    Returns a DataFrame indexed ``RMS``, ``max`` with the ERROR_COLUMNS as
    columns. The final-error columns (FINAL_ERROR_COLUMNS) use only poses whose
    status marks an accepted estimate (``ok``, or ``recovered`` when tracking);
    the others use every pose. NaN values are skipped; a column with no value
    left is NaN. ``attrs["n_poses"]`` and ``attrs["n_failed"]`` count the poses
    and those without an accepted estimate.
    """
    ok = table["status"].isin(ESTIMATED).to_numpy()
    stats = {}
    for name in ERROR_COLUMNS:
        values = table[name].to_numpy(dtype=float)
        if name in FINAL_ERROR_COLUMNS:
            values = values[ok]
        stats[name] = [_rms(values), _max_abs(values)]
    result = pd.DataFrame(stats, index=pd.Index(["RMS", "max"], name="stat"))
    result.attrs["n_poses"] = len(table)
    result.attrs["n_failed"] = int(np.count_nonzero(~ok))
    return result


def _exceeding_pair(value: float, limit: float, decimals: int) -> tuple[str, str]:
    """``value`` and ``limit`` as text, with enough decimals to show value > limit."""
    # At the table's precision 1.04 cm against a 1.0 cm gate would read "1.0 cm > 1.0 cm".
    while decimals < 9 and (
        round(value, decimals) <= round(limit, decimals) or round(limit, decimals) != limit
    ):
        decimals += 1
    return f"{value:.{decimals}f}", f"{limit:.{decimals}f}"


def _check_limit(limit: float | None, name: str) -> None:
    if limit is not None and not limit >= 0.0:
        raise ValueError(f"{name} must be a non-negative number, got {limit}")


def gate(
    table: pd.DataFrame,
    fail_above_cm: float | None = None,
    fail_above_deg: float | None = None,
) -> list[str]:
    """Violations of the error limits by a ``table1`` result, one message each, in table order.

    ``fail_above_cm`` limits |err_x_cm| and |err_y_cm|; ``fail_above_deg`` limits
    |err_theta_deg|. When either limit is set, a pose whose status is not ``ok``
    or whose gated error is missing is a violation too. Empty list: all pass.
    """
    _check_limit(fail_above_cm, "fail_above_cm")
    _check_limit(fail_above_deg, "fail_above_deg")
    if fail_above_cm is None and fail_above_deg is None:
        return []
    checks = []
    if fail_above_cm is not None:
        checks += [("err_x", "err_x_cm", fail_above_cm, 1, " cm")]
        checks += [("err_y", "err_y_cm", fail_above_cm, 1, " cm")]
    if fail_above_deg is not None:
        checks += [("err_theta", "err_theta_deg", fail_above_deg, 2, "°")]

    abs_errors = {col: np.abs(table[col].to_numpy(dtype=float)) for _, col, *_ in checks}
    messages = []
    for row, (pose_id, status) in enumerate(zip(table["pose_id"], table["status"], strict=True)):
        if status not in ESTIMATED:
            messages.append(f"pose {pose_id}: status {status}")
            continue
        for label, col, limit, decimals, unit in checks:
            value = abs_errors[col][row]
            if not np.isfinite(value):
                messages.append(f"pose {pose_id}: {label} is missing")
            elif value > limit + _GATE_SLACK:
                value_text, limit_text = _exceeding_pair(value, limit, decimals)
                messages.append(
                    f"pose {pose_id}: |{label}| {value_text}{unit} > {limit_text}{unit}"
                )
    return messages


def _number_text(value: float, decimals: int, missing: str) -> str:
    if not np.isfinite(value):
        return missing
    text = f"{value:.{decimals}f}"
    # "-0.0" reads as a sign that the precision shown does not support.
    return text[1:] if text.startswith("-") and float(text) == 0.0 else text


def _display_rows(table: pd.DataFrame, stats: pd.DataFrame, missing: str) -> list[list[str]]:
    """Table rows then the RMS and max rows, as text cells (pose, displayed columns, status)."""
    rows = []
    for _, record in table.iterrows():
        cells = [_number_text(record[c], d, missing) for c, d, *_ in _DISPLAY]
        rows.append([str(record["pose_id"]), *cells, str(record["status"])])
    for stat, record in stats.iterrows():
        cells = [_number_text(record[c], d, missing) for c, d, *_ in _DISPLAY]
        rows.append([str(stat), *cells, ""])
    return rows


def _format_md(table: pd.DataFrame, stats: pd.DataFrame) -> str:
    headers = ["pose", *(md for _, _, md, _ in _DISPLAY), "status"]
    frame = pd.DataFrame(_display_rows(table, stats, _MISSING_MD), columns=headers)
    body = frame.to_markdown(
        index=False,
        disable_numparse=True,
        colalign=("left", *("right" for _ in _DISPLAY), "left"),
    )
    n_poses, n_failed = stats.attrs["n_poses"], stats.attrs["n_failed"]
    note = (
        f"{n_poses} poses, {n_failed} failed; errors are surveyed minus computed, "
        "and RMS and max of X, Y, θ cover the poses with status ok."
    )
    return f"{body}\n\n{note}\n"


def _format_latex(table: pd.DataFrame, stats: pd.DataFrame) -> str:
    """A booktabs ``tabular`` (needs ``\\usepackage{booktabs}``), summary rows under a rule."""
    headers = ["Pose", *(tex for _, _, _, tex in _DISPLAY), "Status"]
    rows = _display_rows(table, stats, _MISSING_LATEX)
    for row in rows:
        row[1:-1] = [f"${cell}$" if cell != _MISSING_LATEX else cell for cell in row[1:-1]]
    frame = pd.DataFrame(rows, columns=headers)
    styler = frame.style.hide(axis="index").format(escape="latex", subset=["Status"])
    latex = styler.to_latex(column_format="l" + "r" * len(_DISPLAY) + "l", hrules=True)
    lines = latex.splitlines()
    # Styler puts no rule between body rows; set the summary rows (last in the body) apart.
    lines.insert(lines.index(r"\bottomrule") - len(stats), r"\midrule")
    return "\n".join(lines) + "\n"


def _json_value(value: object) -> object:
    if isinstance(value, float | np.floating):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def _format_json(table: pd.DataFrame, stats: pd.DataFrame) -> str:
    poses = [
        {name: _json_value(value) for name, value in zip(TABLE_COLUMNS, row, strict=True)}
        for row in table[list(TABLE_COLUMNS)].itertuples(index=False)
    ]
    summary_out: dict[str, object] = {
        "n_poses": int(stats.attrs["n_poses"]),
        "n_failed": int(stats.attrs["n_failed"]),
    }
    for stat, record in stats.iterrows():
        summary_out[str(stat)] = {c: _json_value(record[c]) for c in ERROR_COLUMNS}
    return json.dumps({"poses": poses, "summary": summary_out}, indent=2, allow_nan=False) + "\n"


def format_table(table: pd.DataFrame, summary: pd.DataFrame, fmt: str) -> str:
    """Render a ``table1`` result and its ``summary`` as text in format ``fmt``.

    - ``md``: a Markdown table like the paper's (0.1 cm, 0.01°), RMS and max rows
      after the poses, and a line with the pose counts.
    - ``csv``: the per-pose rows with TABLE_COLUMNS as header, full precision.
    - ``latex``: a booktabs ``tabular`` of the md content.
    - ``json``: ``{"poses": [...], "summary": {"n_poses", "n_failed", "RMS", "max"}}``,
      full precision, NaN written as null.
    """
    if fmt == "md":
        return _format_md(table, summary)
    if fmt == "csv":
        return table[list(TABLE_COLUMNS)].to_csv(index=False)
    if fmt == "latex":
        return _format_latex(table, summary)
    if fmt == "json":
        return _format_json(table, summary)
    raise ValueError(f"unknown table format {fmt!r}; choose one of {', '.join(FORMATS)}")
