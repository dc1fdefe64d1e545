"""Figures of a run scored by relations (``segloc evaluate --relations``): where along the
estimated trajectory the relations go wrong, and how their errors run in time.

World frame, metres on the map's axes; relation errors in centimetres and degrees.

Figure names (files ``NAME.png`` and ``NAME.pdf``):

- ``trajectory``: the estimated trajectory over the map, each relation's start pose
  coloured by that relation's translational error;
- ``relation_errors_over_time``: the translational and rotational error of each used
  relation against the time of its first pose, with their mean and 95th percentile.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from segloc_cli.estimates import Relations
from segloc_cli.scoring.relations import RelationErrors
from segloc_cli.scoring.trend_plots import new_figure
from segloc_cli.timing import nearest_by_time

TRAJECTORY = "trajectory"
RELATION_ERRORS_OVER_TIME = "relation_errors_over_time"

RELATION_FIGURES = (TRAJECTORY, RELATION_ERRORS_OVER_TIME)
"""Figures of a run scored by relations, in drawing order."""

FIGURE_SIZES_IN = {
    TRAJECTORY: (8.0, 7.0),
    RELATION_ERRORS_OVER_TIME: (10.0, 6.0),
}
"""Width and height (inches) of each figure of this module."""

PERCENTILE = 95.0
"""The percentile drawn beside the mean in ``relation_errors_over_time``."""

_MAP_COLOUR = "0.65"
_PATH_COLOUR = "0.3"
_TRANS_COLOUR = "tab:blue"
_ROT_COLOUR = "tab:green"
_COLOUR_MAP = "viridis"


def relation_start_errors(
    times_s: np.ndarray, errors: RelationErrors, relations: Relations
) -> tuple[np.ndarray, np.ndarray]:
    """The pose each used relation starts at, and the largest translational error (cm) of
    the relations starting there.

    ``times_s`` (N,) are the estimates' times (s); a relation starts at the estimate
    nearest its t1. Returns ``rows`` (K,) indices into ``times_s``, each once, in
    increasing order, and ``trans_cm`` (K,).
    """
    t1_s = np.asarray(relations.t1_s, dtype=float)[np.asarray(errors.index, dtype=np.int64)]
    start = nearest_by_time(t1_s, times_s, np.inf)
    trans_cm = 100.0 * np.asarray(errors.trans_m, dtype=float)
    keep = start >= 0
    rows = np.unique(start[keep])
    largest = np.full(rows.size, -np.inf)
    np.maximum.at(largest, np.searchsorted(rows, start[keep]), trans_cm[keep])
    return rows, largest


def draw_trajectory(
    times_s: np.ndarray,
    poses: np.ndarray,
    errors: RelationErrors,
    relations: Relations,
    segments_world: np.ndarray | None = None,
) -> Figure:
    """The estimated trajectory ``poses`` (N, 3: x m, y m, θ rad, world frame; NaN rows:
    no estimate) as a line over the map's ``segments_world`` (M, 4: x1 y1 x2 y2 m) when
    given, with the start pose of each used relation coloured by its translational error
    (cm; the largest where several start at one pose), the largest drawn on top."""
    fig = new_figure(FIGURE_SIZES_IN[TRAJECTORY])
    ax = fig.subplots()
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    if segments_world is not None and len(segments_world):
        walls = np.asarray(segments_world, dtype=float).reshape(-1, 2, 2)
        ax.add_collection(
            LineCollection(list(walls), colors=_MAP_COLOUR, linewidths=2.0, label="map")
        )
    ax.plot(
        poses[:, 0],
        poses[:, 1],
        "-",
        color=_PATH_COLOUR,
        linewidth=0.8,
        label="estimated trajectory",
    )
    rows, trans_cm = relation_start_errors(times_s, errors, relations)
    order = np.argsort(trans_cm, kind="stable")
    if rows.size:
        points = ax.scatter(
            poses[rows[order], 0],
            poses[rows[order], 1],
            c=trans_cm[order],
            cmap=_COLOUR_MAP,
            s=22,
            zorder=3,
            label="start of a relation",
        )
        bar = fig.colorbar(points, ax=ax, shrink=0.85)
        bar.set_label("translational error of the relation starting there (cm)")
    _fit_view(ax, poses, segments_world)
    ax.set_aspect("equal")
    ax.xaxis.set_major_locator(MaxNLocator(nbins=8))
    ax.yaxis.set_major_locator(MaxNLocator(nbins=8))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="upper left", fontsize=8, framealpha=0.9)
    ax.set_title(
        f"Estimated trajectory, coloured by the error of the {errors.used} used relations\n"
        "at the pose each starts from (world frame)",
        fontsize=10,
    )
    return fig


def _fit_view(ax, poses: np.ndarray, segments_world: np.ndarray | None) -> None:
    """Limits around every finite pose and map end, with a small margin."""
    points = poses[np.all(np.isfinite(poses[:, :2]), axis=1), :2]
    if segments_world is not None and len(segments_world):
        points = np.vstack([points, np.asarray(segments_world, dtype=float).reshape(-1, 2)])
    if points.size == 0:
        return
    low, high = points.min(axis=0), points.max(axis=0)
    margin = 0.05 * float(max((high - low).max(), 1.0))
    ax.set_xlim(low[0] - margin, high[0] + margin)
    ax.set_ylim(low[1] - margin, high[1] + margin)


def draw_relation_errors_over_time(
    times_s: np.ndarray, errors: RelationErrors, relations: Relations
) -> Figure:
    """The translational (cm) and rotational (°) error of each used relation against its
    t1, in seconds from the first estimate of ``times_s`` (N,), each panel with the mean
    and the ``PERCENTILE``-th percentile as labelled lines."""
    fig = new_figure(FIGURE_SIZES_IN[RELATION_ERRORS_OVER_TIME])
    ax_trans, ax_rot = fig.subplots(2, 1, sharex=True)
    finite = np.asarray(times_s, dtype=float)
    finite = finite[np.isfinite(finite)]
    start_s = float(finite.min()) if finite.size else 0.0
    t1_s = np.asarray(relations.t1_s, dtype=float)[np.asarray(errors.index, dtype=np.int64)]
    x = t1_s - start_s
    order = np.argsort(x, kind="stable")
    panels = (
        (ax_trans, 100.0 * np.asarray(errors.trans_m, dtype=float), "cm", _TRANS_COLOUR),
        (ax_rot, np.asarray(errors.rot_deg, dtype=float), "°", _ROT_COLOUR),
    )
    for ax, values, unit, colour in panels:
        kind = "translational" if unit == "cm" else "rotational"
        ax.plot(
            x[order],
            values[order],
            "-o",
            color=colour,
            markersize=3,
            linewidth=0.8,
            label=f"{kind} error of a relation",
        )
        if values.size:
            mean = float(np.mean(values))
            high = float(np.percentile(values, PERCENTILE))
            ax.axhline(mean, color="black", linestyle="--", label=f"mean {mean:.2f} {unit}")
            ax.axhline(
                high,
                color="tab:red",
                linestyle=":",
                label=f"{PERCENTILE:g}th percentile {high:.2f} {unit}",
            )
        ax.set_ylabel(f"{kind} error ({unit})")
        ax.set_ylim(bottom=0.0)
        ax.yaxis.set_major_locator(MaxNLocator(nbins=6))
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, borderaxespad=0.0)
    ax_rot.xaxis.set_major_locator(MaxNLocator(nbins=10))
    ax_rot.set_xlabel("time of the relation's first pose since the first estimate (s)")
    fig.suptitle(f"Errors of the {errors.used} used relations ({errors.skipped} skipped)")
    return fig


def relation_figures(
    times_s: np.ndarray,
    poses: np.ndarray,
    errors: RelationErrors,
    relations: Relations,
    segments_world: np.ndarray | None = None,
) -> dict[str, Callable[[], Figure]]:
    """The figures of a run scored by relations, by name (``RELATION_FIGURES``), each drawn
    when called.

    ``times_s`` (N,) s and ``poses`` (N, 3: x m, y m, θ rad, world frame) are the
    trajectory ``relation_errors`` scored, ``errors`` its result on ``relations``;
    ``segments_world`` (M, 4: x1 y1 x2 y2 m) the map drawn under the trajectory, if any.
    """
    return {
        TRAJECTORY: lambda: draw_trajectory(times_s, poses, errors, relations, segments_world),
        RELATION_ERRORS_OVER_TIME: lambda: draw_relation_errors_over_time(
            times_s, errors, relations
        ),
    }
