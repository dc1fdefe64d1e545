"""Figures of Table 1 alone: the final errors of each pose, and their trend along the run.

Each figure takes a ``evaluate.table1`` result (one row per surveyed pose) and needs no
map or scan. Errors are surveyed minus final estimate, world frame: X, Y and |XY| in
centimetres, θ in degrees. Poses that failed (by default, those whose status is not an
accepted one, ``estimates.ESTIMATED``; or whichever the caller says failed its gates) are
drawn in their own colour, named in the legend.

Figure names (files ``NAME.png`` and ``NAME.pdf``):

- ``errors``: a bar per pose and error, on one evenly spaced slot per pose or on time;
- ``errors_over_time``: the errors against the survey time, from the first surveyed pose;
- ``errors_over_distance``: the errors against the path length along the surveyed poses.

The helpers that keep tick labels readable (``slot_ticks``) and build a figure on its
own Agg canvas (``new_figure``) serve the other figure modules too.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from segloc_cli.estimates import ESTIMATED

ERRORS = "errors"
ERRORS_OVER_TIME = "errors_over_time"
ERRORS_OVER_DISTANCE = "errors_over_distance"

TABLE_FIGURES = (ERRORS, ERRORS_OVER_TIME, ERRORS_OVER_DISTANCE)
"""Figures drawn from Table 1 alone, in drawing order."""

FIGURE_SIZES_IN = {
    ERRORS: (10.0, 9.0),
    ERRORS_OVER_TIME: (10.0, 6.5),
    ERRORS_OVER_DISTANCE: (10.0, 6.5),
}
"""Width and height (inches) of each figure of this module."""

AXES = ("pose", "time")
"""Horizontal axes of the ``errors`` figure: one slot per pose, or the survey time."""

MAX_TICK_LABELS = 20
"""At most this many labelled ticks on an axis of one slot per pose."""

BAR_FILL = 0.8
"""Share of its slot (or of the smallest gap between poses in time) a bar fills."""

PASSED_COLOUR = "tab:blue"
FLAGGED_COLOUR = "tab:red"
MISSING_COLOUR = "0.35"
SERIES_COLOURS = {
    "err_x_cm": "tab:blue",
    "err_y_cm": "tab:orange",
    "err_xy_cm": "black",
    "err_theta_deg": "tab:green",
}
"""One colour per error, the same in every figure of this module."""

# Average advance of a digit as a share of the font size, to foresee a label's width.
_CHAR_WIDTH_EM = 0.62
_TICK_FONT_PT = 9.0
# The share of a figure's width its axes get once the labels and the legend are placed.
_AXES_SHARE = 0.78

_PANELS = (
    ("err_x_cm", "X error (cm)", "X"),
    ("err_y_cm", "Y error (cm)", "Y"),
    ("err_xy_cm", "|XY| error (cm)", "|XY|"),
    ("err_theta_deg", "θ error (°)", "θ"),
)
"""Column, axis label and series name of each error, in panel order."""

_TIME_LABEL = "survey time since the first surveyed pose (s)"
_DISTANCE_LABEL = "distance travelled along the surveyed poses (m)"


# --------------------------------------------------------------------------- shared


def new_figure(size_in: tuple[float, float]) -> Figure:
    """A figure of ``size_in`` (width, height in inches) on its own Agg canvas, laid out
    by constrained layout; no pyplot state is touched."""
    fig = Figure(figsize=size_in, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def thinned_slots(n: int, max_labels: int = MAX_TICK_LABELS) -> np.ndarray:
    """Indices of the slots (of ``n``) that get a label: every k-th from the first, with k
    the smallest step that keeps at most ``max_labels`` of them."""
    step = max(1, math.ceil(n / max(1, max_labels)))
    return np.arange(0, n, step)


MAX_MINOR_TICKS = 100
"""Slots of a per-pose axis that each keep a minor tick; beyond, none do."""


def slot_ticks(
    ax: Axes,
    labels: Sequence[str],
    axes_width_in: float,
    max_labels: int = MAX_TICK_LABELS,
) -> None:
    """Label the slots 0 … n−1 of ``ax``'s x axis with ``labels`` (one per slot), thinned to
    at most ``max_labels``, turned upright when they would not fit side by side on an axis
    about ``axes_width_in`` inches wide; every slot keeps a minor tick while there are at
    most ``MAX_MINOR_TICKS`` (more would merge into a bar, and cost a second each)."""
    n = len(labels)
    shown = thinned_slots(n, max_labels)
    ax.set_xlim(-0.5, n - 0.5)
    if n <= MAX_MINOR_TICKS:
        ax.set_xticks(np.arange(n), minor=True)
    ax.set_xticks(shown, [str(labels[i]) for i in shown])
    if shown.size == 0:
        return
    spacing_pt = 72.0 * axes_width_in * (shown[1] - shown[0] if shown.size > 1 else n) / n
    widest_pt = max(len(str(labels[i])) for i in shown) * _CHAR_WIDTH_EM * _TICK_FONT_PT
    rotation = 90 if widest_pt > 0.8 * spacing_pt else 0
    ax.tick_params(axis="x", which="major", labelsize=_TICK_FONT_PT, labelrotation=rotation)


def failed_poses(accepted: np.ndarray, flagged: np.ndarray | None = None) -> np.ndarray:
    """(N,) bool: the poses drawn as failed, ``flagged`` (N,) when given (e.g. those beyond
    the gates), else those not ``accepted`` (N,) (status not in ``ESTIMATED``)."""
    accepted = np.asarray(accepted, dtype=bool).reshape(-1)
    if flagged is None:
        return ~accepted
    flagged = np.asarray(flagged, dtype=bool).reshape(-1)
    if flagged.size != accepted.size:
        raise ValueError(f"flagged has {flagged.size} entries for {accepted.size} poses")
    return flagged


def flag_labels(flagged_given: bool) -> tuple[str, str]:
    """Legend texts of the poses that passed and of those that failed."""
    if flagged_given:
        return "within the gates", "failed the gates"
    return "accepted (ok, recovered)", "not accepted (status)"


def _outside_legend(ax: Axes) -> None:
    """The legend right of ``ax``, so it never hides a bar or a point."""
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, borderaxespad=0.0)


def _times_from_first(table: pd.DataFrame) -> np.ndarray:
    """(N,) survey time of each pose minus that of the first surveyed pose (s)."""
    if "time_s" not in table.columns:
        raise ValueError("the table has no time_s column (a table1 result has)")
    times_s = table["time_s"].to_numpy(dtype=float)
    finite = times_s[np.isfinite(times_s)]
    return times_s - (finite.min() if finite.size else 0.0)


# --------------------------------------------------------------------------- per pose


def errors_by_pose(table: pd.DataFrame) -> pd.DataFrame:
    """Per pose of a ``table1`` result: ``pose_id``, ``err_x_cm``, ``err_y_cm``,
    ``err_xy_cm`` (cm), ``err_theta_deg`` (°; surveyed minus final estimate, world frame),
    ``accepted`` (status ok or recovered) and, where the table has it, ``time_s`` (s)."""
    frame = pd.DataFrame(
        {
            "pose_id": table["pose_id"].to_numpy(dtype=np.int64),
            **{column: table[column].to_numpy(dtype=float) for column, _, _ in _PANELS},
            "accepted": table["status"].isin(ESTIMATED).to_numpy(),
        }
    )
    if "time_s" in table.columns:
        frame["time_s"] = table["time_s"].to_numpy(dtype=float)
    return frame


def _bar_positions(errors: pd.DataFrame, axis: str) -> tuple[np.ndarray, float]:
    """Where each pose's bar stands on the x axis, and the bars' width."""
    if axis == "pose":
        return np.arange(len(errors), dtype=float), BAR_FILL
    if "time_s" not in errors.columns:
        raise ValueError('axis="time" needs the time_s column (a table1 result has it)')
    x = _times_from_first(errors)
    gaps = np.diff(np.unique(x[np.isfinite(x)]))
    return x, BAR_FILL * (float(gaps.min()) if gaps.size else 1.0)


def draw_errors(
    errors: pd.DataFrame,
    axis: str = "pose",
    flagged: np.ndarray | None = None,
) -> Figure:
    """Bars of the X, Y, |XY| (cm) and θ (°) errors of each pose (``errors_by_pose``).

    With ``axis="pose"`` each pose has one evenly spaced slot, labelled by its id (thinned
    to at most ``MAX_TICK_LABELS`` labels); with ``axis="time"`` a bar stands at the pose's
    survey time since the first surveyed pose (s). ``flagged`` (N,) bool marks the poses
    that failed the gates; by default, those not accepted. Failed poses are drawn in their
    own colour and a pose without an estimate as a grey cross on zero, each named in the
    legend.
    """
    if axis not in AXES:
        raise ValueError(f"axis must be one of {', '.join(AXES)}, not {axis!r}")
    fig = new_figure(FIGURE_SIZES_IN[ERRORS])
    axes = fig.subplots(len(_PANELS), 1, sharex=True)
    failed = failed_poses(errors["accepted"].to_numpy(dtype=bool), flagged)
    passed_label, failed_label = flag_labels(flagged is not None)
    x, width = _bar_positions(errors, axis)
    for ax, (column, label, _) in zip(axes, _PANELS, strict=True):
        values = errors[column].to_numpy(dtype=float)
        finite = np.isfinite(values) & np.isfinite(x)
        for chosen, colour, name in (
            (finite & ~failed, PASSED_COLOUR, passed_label),
            (finite & failed, FLAGGED_COLOUR, failed_label),
        ):
            if chosen.any():
                ax.bar(x[chosen], values[chosen], width=width, color=colour, label=name)
        missing = ~np.isfinite(values) & np.isfinite(x)
        if missing.any():
            ax.plot(
                x[missing],
                np.zeros(int(missing.sum())),
                "x",
                color=MISSING_COLOUR,
                markersize=6,
                label="no estimate",
            )
        ax.axhline(0.0, color="0.5", linewidth=0.8)
        ax.set_ylabel(label)
        ax.yaxis.set_major_locator(MaxNLocator(nbins=5))
        ax.grid(True, axis="y", alpha=0.3)
    bottom = axes[-1]
    if axis == "pose":
        axes_width_in = FIGURE_SIZES_IN[ERRORS][0] * _AXES_SHARE
        slot_ticks(bottom, [str(v) for v in errors["pose_id"]], axes_width_in)
        bottom.set_xlabel("pose id (one slot per surveyed pose, in survey order)")
    else:
        bottom.xaxis.set_major_locator(MaxNLocator(nbins=10))
        bottom.set_xlabel(_TIME_LABEL)
    _outside_legend(axes[0])
    fig.suptitle(f"Final errors of {len(errors)} surveyed poses (surveyed − estimate, world frame)")
    return fig


# --------------------------------------------------------------------------- trends


def draw_error_trend(
    table: pd.DataFrame,
    along: str = "time",
    flagged: np.ndarray | None = None,
) -> Figure:
    """The X, Y, |XY| errors (cm, one panel) and θ (°, another) of a ``table1`` result as
    lines with markers, against the survey time since the first surveyed pose (s,
    ``along="time"``) or the distance travelled along the surveyed poses (m,
    ``along="distance"``, the ``travelled_m`` column). Poses that failed (``flagged`` (N,)
    bool, by default those not accepted) are marked by a red ring on each of their points
    and a red line across the panel where they have no estimate.
    """
    if along == "time":
        name, x, x_label = ERRORS_OVER_TIME, _times_from_first(table), _TIME_LABEL
    elif along == "distance":
        if "travelled_m" not in table.columns:
            raise ValueError("the table has no travelled_m column (a table1 result has)")
        name, x_label = ERRORS_OVER_DISTANCE, _DISTANCE_LABEL
        x = table["travelled_m"].to_numpy(dtype=float)
    else:
        raise ValueError(f'along must be "time" or "distance", not {along!r}')
    failed = failed_poses(table["status"].isin(ESTIMATED).to_numpy(), flagged)
    _, failed_label = flag_labels(flagged is not None)
    order = np.argsort(x, kind="stable")
    x, failed = x[order], failed[order]

    fig = new_figure(FIGURE_SIZES_IN[name])
    ax_xy, ax_theta = fig.subplots(2, 1, sharex=True, height_ratios=[1.6, 1.0])
    groups = ((ax_xy, _PANELS[:3], "position error (cm)"), (ax_theta, _PANELS[3:], "θ error (°)"))
    for ax, panels, y_label in groups:
        values = np.column_stack([table[c].to_numpy(dtype=float)[order] for c, _, _ in panels])
        for k, (column, _, series) in enumerate(panels):
            ax.plot(
                x,
                values[:, k],
                "-o",
                color=SERIES_COLOURS[column],
                markersize=3.5,
                linewidth=1.2,
                label=series,
            )
        ring = failed[:, None] & np.isfinite(values)
        if ring.any():
            rows, cols = np.nonzero(ring)
            ax.plot(
                x[rows],
                values[rows, cols],
                "o",
                mfc="none",
                mec=FLAGGED_COLOUR,
                markersize=9,
                markeredgewidth=1.5,
                label=failed_label,
            )
        blank = failed & ~np.isfinite(values).any(axis=1) & np.isfinite(x)
        if blank.any():
            # One collection for them all: a log whose localizer fell silent has thousands.
            ax.vlines(
                x[blank],
                0.0,
                1.0,
                transform=ax.get_xaxis_transform(),
                colors=FLAGGED_COLOUR,
                linestyles=":",
                linewidth=1.0,
                label=f"{failed_label}, no estimate",
            )
        ax.axhline(0.0, color="0.5", linewidth=0.8)
        ax.set_ylabel(y_label)
        ax.yaxis.set_major_locator(MaxNLocator(nbins=6))
        ax.grid(True, alpha=0.3)
        _outside_legend(ax)
    ax_theta.xaxis.set_major_locator(MaxNLocator(nbins=10))
    ax_theta.set_xlabel(x_label)
    what = "survey time" if along == "time" else "distance travelled"
    fig.suptitle(
        f"Final errors of {len(table)} surveyed poses against {what} "
        "(surveyed − estimate, world frame)"
    )
    return fig
