"""Convergence curves: how often a run finds the right place, against how wrong its guess was.

A sweep's rows (``runs/sweep.py``) hold each scan's initial guess, its estimate and the
estimate's errors against the survey. The initial error of a row is its guess against the
true pose, as a distance (m) and a heading difference (°, wrapped to [0, 180]); a row
succeeds when its status is accepted (``estimates.ESTIMATED``) and its estimate lies within
a distance and a heading of the truth. ``convergence_table`` counts trials and successes per
combination of settings and bin of initial error, with a Wilson interval on each rate;
``draw_convergence`` draws them, ``format_convergence_md`` writes them as Markdown.

Bins hold their lower edge; the last one holds its upper edge too.
"""

from __future__ import annotations

from collections.abc import Sequence
from statistics import NormalDist
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from segloc_cli.estimates import ESTIMATED
from segloc_cli.method.confidence import RIGHT_PLACE_DEG, RIGHT_PLACE_M
from segloc_cli.wording import counted

if TYPE_CHECKING:
    from matplotlib.figure import Figure

# Edges double from 0.25 m: odometry between scans leaves a guess within the first bin, a
# robot put down by hand in a known room lands within 1 m, and 2 m is the default half width
# of the guided search (--search-half-width-m), so the last bin shows what lies beyond it.
POSITION_BINS_M = (0.0, 0.25, 0.5, 1.0, 2.0, 4.0)
# Stage 1 votes for the heading over the whole circle, so the bins run out to 180°: fine
# where compasses and odometry leave a guess, coarse where only the room's axes agree.
HEADING_BINS_DEG = (0.0, 5.0, 10.0, 20.0, 45.0, 90.0, 180.0)
AXES = ("position", "heading")
"""The initial errors the curves are drawn against, in the table's ``axis`` column."""
AXIS_UNITS = {"position": " m", "heading": "°"}
"""What follows an initial error of each axis in text."""
TRUTH_COLUMNS = ("log", "pose_id", "x_m", "y_m", "theta_deg")
"""A truth table: the surveyed pose (m, °, world frame) of each log's pose ids."""
ROW_COLUMNS = ("init_x_m", "init_y_m", "init_theta_deg", "x_m", "y_m", "theta_deg", "status",
               "err_x_cm", "err_y_cm", "err_xy_cm", "err_theta_deg")  # fmt: skip
"""What ``convergence_table`` reads of a sweep's rows (with ``log`` and ``pose_id`` when a
truth table is given, and the grid's columns)."""
TABLE_COLUMNS = ("combination", "axis", "bin_lo", "bin_hi", "n_trials", "n_success",
                 "success_rate", "wilson_lo", "wilson_hi")  # fmt: skip
"""The columns of ``convergence_table``; ``bin_lo`` and ``bin_hi`` are in the axis's unit
(m for position, ° for heading), rates and interval bounds in 0–1."""
ALL = "all"
"""The label of the one combination of a sweep without a grid."""
WILSON_CONFIDENCE = 0.95


def wilson_interval(
    successes: np.ndarray, trials: np.ndarray, confidence: float = WILSON_CONFIDENCE
) -> tuple[np.ndarray, np.ndarray]:
    """The Wilson score interval (lower, upper bounds, 0–1) of each success rate
    ``successes / trials`` at ``confidence``; NaN where there is no trial.

    Unlike the normal approximation it stays within [0, 1] and does not shrink to nothing
    at 0 or all successes, which few trials per bin often give.
    """
    k = np.asarray(successes, dtype=float)
    n = np.asarray(trials, dtype=float)
    z = NormalDist().inv_cdf(0.5 + confidence / 2.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        p = k / n
        scale = 1.0 + z * z / n
        centre = (p + z * z / (2.0 * n)) / scale
        half = z * np.sqrt(p * (1.0 - p) / n + z * z / (4.0 * n * n)) / scale
    empty = n <= 0
    # At no success (or all) the bound is exactly 0 (or 1); the sum would leave rounding.
    low = np.where(k <= 0, 0.0, centre - half)
    high = np.where(k >= n, 1.0, centre + half)
    return np.where(empty, np.nan, low), np.where(empty, np.nan, high)


def _wrapped_deg(diff_deg: np.ndarray) -> np.ndarray:
    # Wrapped in degrees, not through radians, so that a difference of exactly 5° stays 5°
    # and falls in the bin it lies on the edge of.
    return (diff_deg + 180.0) % 360.0 - 180.0


def true_poses(rows: pd.DataFrame, truth: pd.DataFrame | None = None) -> np.ndarray:
    """The true pose of each row (N, 3: x m, y m, θ °; world frame): from ``truth`` (columns
    ``TRUTH_COLUMNS``) by the row's log and pose id where it holds them, else the estimate
    plus its error (errors are surveyed minus estimate); NaN where neither is known."""
    x = rows["x_m"].to_numpy(float) + rows["err_x_cm"].to_numpy(float) / 100.0
    y = rows["y_m"].to_numpy(float) + rows["err_y_cm"].to_numpy(float) / 100.0
    theta = rows["theta_deg"].to_numpy(float) + rows["err_theta_deg"].to_numpy(float)
    poses = np.column_stack([x, y, theta])
    if truth is None or len(rows) == 0:
        return poses
    # Pose ids as floats on both sides: the rows' may be, where a failed task left NaN.
    keys = pd.DataFrame({"log": rows["log"].astype(str).to_numpy(),
                         "pose_id": rows["pose_id"].to_numpy(float)})  # fmt: skip
    survey = truth.assign(log=truth["log"].astype(str), pose_id=truth["pose_id"].astype(float))
    survey = survey.drop_duplicates(["log", "pose_id"])
    matched = keys.merge(survey, how="left", on=["log", "pose_id"])
    surveyed = matched[["x_m", "y_m", "theta_deg"]].to_numpy(float)
    known = np.isfinite(surveyed).all(axis=1)
    poses[known] = surveyed[known]
    return poses


def initial_errors(
    rows: pd.DataFrame, truth: pd.DataFrame | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """How far each row's guess lies from its true pose (``true_poses``): the distance (m)
    and the heading difference wrapped to [0, 180] (°); NaN where the row has no guess (a
    global search, a pose without a scan or guess, a failed task) or no known truth."""
    poses = true_poses(rows, truth)
    dx = poses[:, 0] - rows["init_x_m"].to_numpy(float)
    dy = poses[:, 1] - rows["init_y_m"].to_numpy(float)
    turn = np.abs(_wrapped_deg(poses[:, 2] - rows["init_theta_deg"].to_numpy(float)))
    return np.hypot(dx, dy), turn


def succeeded(rows: pd.DataFrame, success_cm: float, success_deg: float) -> np.ndarray:
    """(N,) bool: the rows with an accepted status whose estimate lies within ``success_cm``
    (cm, in the plane) and ``success_deg`` (°) of the truth, both edges included."""
    accepted = rows["status"].isin(ESTIMATED).to_numpy()
    near = rows["err_xy_cm"].to_numpy(float) <= success_cm
    turned = np.abs(rows["err_theta_deg"].to_numpy(float)) <= success_deg
    return accepted & near & turned


def combination_labels(rows: pd.DataFrame, grid_keys: Sequence[str]) -> np.ndarray:
    """(N,) the combination of each row as "key=value, …" over ``grid_keys``; ``ALL`` for
    every row when the rows hold one combination or none is named."""
    if not grid_keys:
        return np.full(len(rows), ALL, dtype=object)
    columns = [rows[k].tolist() for k in grid_keys]
    labels = np.array(
        [", ".join(f"{k}={v}" for k, v in zip(grid_keys, values, strict=True))
         for values in zip(*columns, strict=True)],
        dtype=object,
    )  # fmt: skip
    return np.full(len(rows), ALL, dtype=object) if len(set(labels)) <= 1 else labels


def bin_index(values: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """The bin of each value (−1: in none): bins hold their lower edge, the last its upper."""
    index = np.searchsorted(edges, values, side="right") - 1
    index[values == edges[-1]] = edges.size - 2
    outside = ~np.isfinite(values) | (values < edges[0]) | (values > edges[-1])
    index[outside] = -1
    return index


def convergence_table(
    rows: pd.DataFrame,
    truth: pd.DataFrame | None = None,
    grid_keys: Sequence[str] = (),
    success_cm: float = 100.0 * RIGHT_PLACE_M,
    success_deg: float = RIGHT_PLACE_DEG,
) -> pd.DataFrame:
    """Success against initial error: per combination (``combination_labels``, in order of
    appearance), axis (``AXES``) and bin (``POSITION_BINS_M``, ``HEADING_BINS_DEG``), the
    trials, the successes (``succeeded`` with ``success_cm`` and ``success_deg``), their
    rate and its 95 % Wilson interval: ``TABLE_COLUMNS``, NaN rates for an empty bin.

    ``rows`` are a sweep's (``ROW_COLUMNS``); ``truth`` (``TRUTH_COLUMNS``), where it holds a
    row's pose, is its truth: without it a row with a guess but no estimate, a miss, would
    go uncounted. Rows that fall in
    no bin are counted in ``attrs["notes"]``, lines of text; ``attrs["success_cm"]`` and
    ``attrs["success_deg"]`` keep the criterion.
    """
    missing = [c for c in (*ROW_COLUMNS, *grid_keys) if c not in rows.columns]
    if missing:
        raise ValueError(f"rows lack the column(s) {', '.join(missing)}")
    position_m, heading_deg = initial_errors(rows, truth)
    success = succeeded(rows, success_cm, success_deg)
    labels = combination_labels(rows, grid_keys)
    edges = {"position": np.asarray(POSITION_BINS_M), "heading": np.asarray(HEADING_BINS_DEG)}
    bins = {
        "position": bin_index(position_m, edges["position"]),
        "heading": bin_index(heading_deg, edges["heading"]),
    }
    parts = []
    for label in dict.fromkeys(labels):
        mine = labels == label
        for axis in AXES:
            n_bins = edges[axis].size - 1
            chosen = mine & (bins[axis] >= 0)
            n = np.bincount(bins[axis][chosen], minlength=n_bins)
            k = np.bincount(bins[axis][chosen], weights=success[chosen], minlength=n_bins)
            k = k.astype(np.int64)
            low, high = wilson_interval(k, n)
            with np.errstate(divide="ignore", invalid="ignore"):
                rate = np.where(n > 0, k / n, np.nan)
            parts.append(pd.DataFrame({
                "combination": label, "axis": axis, "bin_lo": edges[axis][:-1],
                "bin_hi": edges[axis][1:], "n_trials": n, "n_success": k,
                "success_rate": rate, "wilson_lo": low, "wilson_hi": high,
            }))  # fmt: skip
    table = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=TABLE_COLUMNS)
    table.attrs["notes"] = _notes(rows, position_m, heading_deg)
    table.attrs["success_cm"] = float(success_cm)
    table.attrs["success_deg"] = float(success_deg)
    return table


def _notes(rows: pd.DataFrame, position_m: np.ndarray, heading_deg: np.ndarray) -> list[str]:
    """Lines counting the rows left out of the bins, and why."""
    guessed = rows[["init_x_m", "init_y_m", "init_theta_deg"]].notna().all(axis=1).to_numpy()
    measured = np.isfinite(position_m) & np.isfinite(heading_deg)
    notes = []
    if (~guessed).any():
        notes.append(
            "no guess (a global search, a pose without a scan or guess, a failed task): "
            f"{int((~guessed).sum())} of {counted(len(rows), 'row')}, in no bin"
        )
    unknown = guessed & ~measured
    if unknown.any():
        notes.append(
            "a guess, but neither an estimate nor a survey pose to measure it against: "
            f"{counted(int(unknown.sum()), 'row')}, in no bin"
        )
    far = measured & (position_m > POSITION_BINS_M[-1])
    if far.any():
        notes.append(
            f"a guess beyond {POSITION_BINS_M[-1]:g} m of the truth: "
            f"{counted(int(far.sum()), 'row')}, in no position bin"
        )
    return notes


def _edge_text(value: float) -> str:
    return f"{value:g}"


def format_convergence_md(table: pd.DataFrame) -> str:
    """The table of ``convergence_table`` as Markdown: the criterion of success, a row per
    combination, axis and bin (rates in %, 1 decimal; "–" for an empty bin), then its notes."""
    shown = pd.DataFrame({
        "combination": table["combination"],
        "initial error": [
            f"{_edge_text(lo)}–{_edge_text(hi)}{AXIS_UNITS[axis]}"
            for axis, lo, hi in zip(table["axis"], table["bin_lo"], table["bin_hi"], strict=True)
        ],
        "trials": table["n_trials"].astype(int).astype(str),
        "successes": table["n_success"].astype(int).astype(str),
        "success %": [_percent(v) for v in table["success_rate"]],
        "95 % interval": [
            "–" if not np.isfinite(lo) else f"{_percent(lo)}–{_percent(hi)}"
            for lo, hi in zip(table["wilson_lo"], table["wilson_hi"], strict=True)
        ],
    })  # fmt: skip
    criterion = (
        f"Success: an accepted estimate ({', '.join(ESTIMATED)}) within "
        f"{table.attrs.get('success_cm', 100.0 * RIGHT_PLACE_M):g} cm and "
        f"{table.attrs.get('success_deg', RIGHT_PLACE_DEG):g}° of the truth. Initial error: "
        "the guess against the truth; a bin holds its lower edge, the last one its upper edge "
        "too. Intervals: 95 % Wilson."
    )
    lines = [criterion, "", shown.to_markdown(index=False, disable_numparse=True)]
    notes = table.attrs.get("notes", [])
    if notes:
        lines += ["", *(f"- {note}" for note in notes)]
    return "\n".join(lines) + "\n"


def _percent(rate: float) -> str:
    return f"{100.0 * rate:.1f}" if np.isfinite(rate) else "–"


_DODGE = 0.04
"""How far apart (in bin widths) the points of two combinations are drawn in a bin."""


def draw_convergence(table: pd.DataFrame) -> Figure:
    """Two panels, success (%) against initial position error and against initial heading
    error: a line per combination through its bins' rates, its Wilson interval as a band.
    Bins are drawn equally wide, ticked at their edges (m, °)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from segloc_cli.scoring.plots import SUCCESS_VS_INITIAL_ERROR, figure_size_in, method_colours

    fig = Figure(figsize=figure_size_in(SUCCESS_VS_INITIAL_ERROR, len(AXES)), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(AXES), sharey=True)
    labels = list(dict.fromkeys(table["combination"]))
    colours = method_colours(labels)
    names = {"position": "initial position error (m)", "heading": "initial heading error (°)"}
    for ax, axis in zip(axes, AXES, strict=True):
        part = table[table["axis"] == axis]
        edges = np.unique(np.concatenate([part["bin_lo"], part["bin_hi"]]))
        for j, label in enumerate(labels):
            bins = part[part["combination"] == label]
            # Side by side within each bin, so that curves that agree stay visible.
            centres = np.arange(len(bins)) + 0.5 + _DODGE * (j - (len(labels) - 1) / 2)
            colour = colours[label]
            ax.fill_between(centres, 100.0 * bins["wilson_lo"], 100.0 * bins["wilson_hi"],
                            color=colour, alpha=0.2, linewidth=0)  # fmt: skip
            ax.plot(centres, 100.0 * bins["success_rate"], "-o", color=colour, label=label)
        ax.set_xticks(np.arange(edges.size), [_edge_text(e) for e in edges])
        ax.set_xlim(0, max(edges.size - 1, 1))
        ax.set_ylim(-3.0, 103.0)
        ax.set_xlabel(names[axis])
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("success (%)")
    axes[0].legend(fontsize=8, loc="lower left", title="95 % Wilson bands", title_fontsize=8)
    return fig
