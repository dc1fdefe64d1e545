"""Figures of the method at work, after Figs. 10–15 of Reina & Gonzalez (2000).

Each figure has a pure data function (arrays and tables in, arrays or a
DataFrame out) and a drawing function that turns that data into a
``matplotlib.figure.Figure``; ``io/figures.save_figure`` writes it as PNG and PDF. Figures
are built on their own Agg canvas, never through pyplot, so drawing leaves no
global state behind. World frame, metres and degrees on every axis.

Figure names (files ``NAME.png`` and ``NAME.pdf``):

- ``overlay``: local maps placed at their estimates over the global map;
- ``heading_by_vote``: stage-1 heading error per pose for each vote scheme;
- ``accumulator``: the stage-1 votes of one pose, weighted against unweighted;
- ``coarse_to_fine``: stage-2 tracks from guesses on a ring around one pose;
- ``errors``, ``errors_over_time``, ``errors_over_distance``: the final errors of Table 1
  per pose and along the run (drawn in ``trend_plots``, from the table alone);
- ``trajectory``, ``relation_errors_over_time``: a run scored by relations
  (``relation_plots.relation_figures``, also importable from here);
- ``success_vs_initial_error``: success rate against the initial position
  error, per method and dataset, from a table of trials.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure

from segloc_cli.config import TIME_TOLERANCE_MS, LocalizeParams
from segloc_cli.estimates import STATUS_OK, PoseTable
from segloc_cli.geometry import Pose2, transform_points, transform_segments, wrap_angle
from segloc_cli.method.align import VOTE_SCHEMES, RTable, accumulate, align, candidate_headings
from segloc_cli.method.extract import ExtractParams, extract_segments
from segloc_cli.method.overlap import coarse_to_fine
from segloc_cli.scan import Scan
from segloc_cli.scoring import relation_plots, trend_plots
from segloc_cli.scoring.relation_plots import RELATION_FIGURES as RELATION_FIGURES
from segloc_cli.scoring.relation_plots import relation_figures as relation_figures
from segloc_cli.scoring.trend_plots import (
    ERRORS,
    ERRORS_OVER_DISTANCE,
    ERRORS_OVER_TIME,
    TABLE_FIGURES,
    draw_error_trend,
    draw_errors,
    errors_by_pose,
    slot_ticks,
)
from segloc_cli.timing import pair_by_time

OVERLAY = "overlay"
HEADING_BY_VOTE = "heading_by_vote"
ACCUMULATOR = "accumulator"
COARSE_TO_FINE = "coarse_to_fine"
SUCCESS_VS_INITIAL_ERROR = "success_vs_initial_error"

MAP_FIGURES = (OVERLAY, HEADING_BY_VOTE, ACCUMULATOR, COARSE_TO_FINE)
"""Figures that need the global map and the scans, besides those of Table 1 alone."""
EVALUATION_FIGURES = (*MAP_FIGURES, *TABLE_FIGURES)
"""Figures drawn from one evaluated run, in drawing order; ``TABLE_FIGURES`` need no map."""

INIT_ERROR_BINS_M = (0.0, 0.5, 1.0, 1.5, 2.0)
"""Edges of the initial position-error bins of ``success_vs_initial_error`` (metres)."""

SCHEME_COLOURS = {
    "product": "tab:blue",
    "count": "tab:orange",
    "local": "tab:green",
    "sum": "tab:brown",
}
"""One colour per vote scheme, the same in every figure."""

# Methods of a trials table take these in name order, after any named in SCHEME_COLOURS.
_SPARE_COLOURS = ("tab:pink", "tab:olive", "tab:cyan", "tab:gray", "tab:purple", "tab:red")
_SCHEME_MARKERS = {"product": "o", "count": "s", "local": "^", "sum": "D"}

_MAP_COLOUR = "0.65"
_LOCAL_COLOUR = "tab:red"
_POINT_COLOUR = "0.15"
_TRACK_COLOUR = "tab:purple"
_TRUTH_COLOUR = "black"

_AXES_SHARE = 0.8
"""The share of a figure's width its axes get beside their labels and legend."""
_PANEL_IN = 4.0
"""Side of one map panel (inches)."""
_MAX_COLUMNS = 3


# --------------------------------------------------------------------------- inputs


@dataclass(frozen=True)
class SurveyedScan:
    """One surveyed pose with its scan and its estimate.

    ``truth``, ``initial`` and ``estimate`` are world-frame poses (metres,
    radians; ``estimate`` is NaN-filled for a failed pose, ``initial`` for a
    run without initial guesses). ``segments_robot`` (N, 4) is the scan's
    local map and ``points_robot`` (K, 2) its valid readings, both in metres,
    robot frame.
    """

    pose_id: int
    truth: Pose2
    initial: Pose2
    estimate: Pose2
    segments_robot: np.ndarray
    points_robot: np.ndarray


def surveyed_scans(
    estimates: pd.DataFrame,
    survey: PoseTable,
    scans: Sequence[Scan],
    tolerance_s: float = TIME_TOLERANCE_MS / 1e3,
    extract_params: ExtractParams | None = None,
    *,
    paths: tuple[object, object, object] = ("survey", "estimates", "log"),
) -> list[SurveyedScan]:
    """Pair survey rows with estimates, and estimates with scans, by time.

    ``estimates`` is an estimates table (``read_estimates``); each survey row
    takes the estimate nearest in time within ``tolerance_s`` seconds, as
    ``evaluate.table1`` does, and that estimate the scan nearest its time.
    Rows missing either are left out; the rest keep survey order. An ambiguous
    pairing (``timing.pair_by_time``) raises ``InputError`` naming the file
    among ``paths`` (survey, estimates, log) at fault. Local maps are
    extracted with ``extract_params`` (default: as ``segloc localize``).
    """
    survey_path, estimates_path, log_path = paths
    est_times_s = estimates["time_s"].to_numpy(dtype=float)
    est_rows = pair_by_time(
        survey.time_s,
        est_times_s,
        tolerance_s,
        query_path=survey_path,
        ref_path=estimates_path,
    )
    scan_times_s = np.array([scan.time_s for scan in scans], dtype=float)
    query_s = np.where(est_rows >= 0, est_times_s[np.maximum(est_rows, 0)], np.nan)
    scan_rows = pair_by_time(
        query_s,
        scan_times_s,
        tolerance_s,
        query_path=estimates_path,
        ref_path=log_path,
        query_label="estimate",
        ref_label="scan",
    )

    def pose(row: pd.Series, prefix: str) -> Pose2:
        return Pose2.from_deg(row[f"{prefix}x_m"], row[f"{prefix}y_m"], row[f"{prefix}theta_deg"])

    items = []
    for i in np.flatnonzero((est_rows >= 0) & (scan_rows >= 0)):
        row = estimates.iloc[est_rows[i]]
        scan = scans[scan_rows[i]]
        items.append(
            SurveyedScan(
                pose_id=int(survey.pose_id[i]),
                truth=Pose2(*(float(v) for v in survey.poses[i])),
                initial=pose(row, "init_"),
                estimate=pose(row, ""),
                segments_robot=extract_segments(scan, extract_params),
                points_robot=scan.points(),
            )
        )
    return items


# --------------------------------------------------------------------------- colours and files


def method_colours(names: Iterable[str]) -> dict[str, str]:
    """A colour per name: vote schemes keep ``SCHEME_COLOURS``, others take spares in name order."""
    names = list(dict.fromkeys(names))
    colours = {name: SCHEME_COLOURS[name] for name in names if name in SCHEME_COLOURS}
    others = sorted(name for name in names if name not in SCHEME_COLOURS)
    for k, name in enumerate(others):
        colours[name] = _SPARE_COLOURS[k % len(_SPARE_COLOURS)]
    return colours


def figure_size_in(name: str, n_panels: int = 1) -> tuple[float, float]:
    """Width and height (inches) of figure ``name`` with ``n_panels`` panels.

    Only ``overlay`` and ``success_vs_initial_error`` vary with the panel count.
    """
    if name == OVERLAY:
        rows, cols = _grid(n_panels)
        return (_PANEL_IN * cols, _PANEL_IN * rows)
    if name == SUCCESS_VS_INITIAL_ERROR:
        return (max(5.0, 4.0 * n_panels), 4.0)
    sizes = {
        HEADING_BY_VOTE: (8.0, 4.0),
        ACCUMULATOR: (10.0, 4.0),
        COARSE_TO_FINE: (10.0, 5.0),
        **trend_plots.FIGURE_SIZES_IN,
        **relation_plots.FIGURE_SIZES_IN,
    }
    if name not in sizes:
        raise ValueError(f"unknown figure {name!r}")
    return sizes[name]


def _grid(n_panels: int) -> tuple[int, int]:
    cols = max(1, min(_MAX_COLUMNS, n_panels))
    return (max(1, math.ceil(n_panels / cols)), cols)


def _new_figure(name: str, n_panels: int = 1) -> Figure:
    return trend_plots.new_figure(figure_size_in(name, n_panels))


# --------------------------------------------------------------------------- overlay


@dataclass(frozen=True)
class OverlayPanel:
    """One pose of the overlay: its local map and readings placed at its estimate.

    ``segments_world`` (N, 4) and ``points_world`` (K, 2) are in metres, world
    frame; ``extent_m`` is (x_min, x_max, y_min, y_max) of a square around the
    local map with a margin. Errors are those of Table 1 (cm, degrees).
    """

    pose_id: int
    estimate: Pose2
    truth: Pose2
    segments_world: np.ndarray
    points_world: np.ndarray
    extent_m: tuple[float, float, float, float]
    err_xy_cm: float
    err_theta_deg: float


def overlay_pose_ids(pose_ids: np.ndarray, err_xy_cm: np.ndarray, n: int = 6) -> np.ndarray:
    """Which poses to show, from best to worst position error: ``n`` evenly spaced in rank
    of |XY|, so the best and the worst are among them, and the median too when ``n`` ≥ 3.

    ``pose_ids`` (P,) in survey order, ``err_xy_cm`` (P,) their position errors (cm; NaN:
    no estimate, never chosen while a pose has one). Every pose with an error when there
    are no more than ``n``; the first ``n`` when no pose has one.
    """
    pose_ids = np.asarray(pose_ids)
    ranked = _ranked_ids(pose_ids, err_xy_cm)
    k = ranked.size
    if n <= 0:
        return pose_ids[:0]
    if k == 0:
        return pose_ids[:n]
    if k <= n:
        return ranked
    picks = np.round(np.linspace(0, k - 1, n)).astype(np.int64)
    median = (k - 1) // 2
    interior = np.arange(1, n - 1)
    if interior.size and median not in picks:
        picks[interior[np.argmin(np.abs(picks[interior] - median))]] = median
    return ranked[picks]


def overlay_caption(
    pose_ids: np.ndarray, err_xy_cm: np.ndarray, shown: np.ndarray, n_poses: int | None = None
) -> str:
    """Which poses an overlay shows and why, e.g. "poses 7 (best), 3, 12 (median), 9,
    4 (worst) of 37: evenly spaced from the best to the worst |XY| of the 30 with an
    estimate". ``pose_ids`` and ``err_xy_cm`` (P,) are the candidates (cm, NaN: no
    estimate), ``shown`` the chosen ids, ``n_poses`` the table's size (default P)."""
    ranked = _ranked_ids(np.asarray(pose_ids), err_xy_cm)
    total = len(pose_ids) if n_poses is None else n_poses
    if ranked.size == 0:
        return f"poses {', '.join(str(i) for i in shown)} of {total}: none has an estimate"
    tags = {ranked[-1]: "worst", ranked[(ranked.size - 1) // 2]: "median", ranked[0]: "best"}
    names = ", ".join(f"{i} ({tags[i]})" if i in tags else str(i) for i in shown)
    if len(shown) == ranked.size:
        return f"poses {names} of {total}: every one with an estimate, best to worst |XY|"
    return (
        f"poses {names} of {total}: evenly spaced from the best to the worst |XY| "
        f"of the {ranked.size} with an estimate"
    )


def _ranked_ids(pose_ids: np.ndarray, err_xy_cm: np.ndarray) -> np.ndarray:
    """The ids of the poses with a finite error, from the smallest error to the largest."""
    err_xy_cm = np.asarray(err_xy_cm, dtype=float)
    finite = np.flatnonzero(np.isfinite(err_xy_cm))
    return np.asarray(pose_ids)[finite[np.argsort(err_xy_cm[finite], kind="stable")]]


def overlay_panels(
    items: Sequence[SurveyedScan], table: pd.DataFrame, n: int = 6, margin_m: float = 1.0
) -> list[OverlayPanel]:
    """Panels of the overlay figure for up to ``n`` poses (see ``overlay_pose_ids``), from
    the best position error to the worst.

    ``table`` is a ``evaluate.table1`` result; poses without an estimate or a
    local map are not shown.
    """
    by_id, rows = _overlay_candidates(items, table)
    errors = rows.set_index("pose_id")
    panels = []
    for pose_id in overlay_pose_ids(rows["pose_id"].to_numpy(), rows["err_xy_cm"].to_numpy(), n):
        item = by_id[int(pose_id)]
        segments = transform_segments(item.segments_robot, item.estimate)
        panels.append(
            OverlayPanel(
                pose_id=int(pose_id),
                estimate=item.estimate,
                truth=item.truth,
                segments_world=segments,
                points_world=transform_points(item.points_robot, item.estimate),
                extent_m=_square_extent(segments.reshape(-1, 2), margin_m),
                err_xy_cm=float(errors.at[pose_id, "err_xy_cm"]),
                err_theta_deg=float(errors.at[pose_id, "err_theta_deg"]),
            )
        )
    return panels


def _overlay_candidates(
    items: Sequence[SurveyedScan], table: pd.DataFrame
) -> tuple[dict[int, SurveyedScan], pd.DataFrame]:
    """The items an overlay may show (an estimate and a local map), by id, and their rows."""
    by_id = {
        item.pose_id: item
        for item in items
        if np.isfinite(item.estimate.as_array()).all() and item.segments_robot.shape[0] > 0
    }
    return by_id, table[table["pose_id"].isin(list(by_id))]


def _overlay_figure(
    segments_world: np.ndarray, items: Sequence[SurveyedScan], table: pd.DataFrame, n: int = 6
) -> Figure:
    panels = overlay_panels(items, table, n)
    _, rows = _overlay_candidates(items, table)
    shown = np.array([panel.pose_id for panel in panels], dtype=np.int64)
    caption = overlay_caption(rows["pose_id"].to_numpy(), rows["err_xy_cm"], shown, len(table))
    return draw_overlay(segments_world, panels, caption)


def _number(value: float, decimals: int, sign: bool = False) -> str:
    """``value`` with ``decimals`` decimals, without the sign of a rounded-off zero."""
    if not np.isfinite(value):
        return "—"
    text = f"{value:{'+' if sign else ''}.{decimals}f}"
    return text[1:] if float(text) == 0.0 and text[0] in "+-" else text


def _square_extent(points: np.ndarray, margin_m: float) -> tuple[float, float, float, float]:
    """The square around ``points`` (K, 2) grown by ``margin_m``, so equal axes fill a panel."""
    low, high = points.min(axis=0), points.max(axis=0)
    centre = (low + high) / 2.0
    half = float((high - low).max()) / 2.0 + margin_m
    return (centre[0] - half, centre[0] + half, centre[1] - half, centre[1] + half)


def _draw_map(ax, segments_world: np.ndarray, label: str | None = "global map") -> None:
    lines = LineCollection(
        list(segments_world.reshape(-1, 2, 2)), colors=_MAP_COLOUR, linewidths=2.5, label=label
    )
    ax.add_collection(lines)


def _draw_pose(ax, pose: Pose2, colour: str, marker: str, label: str, size_m: float) -> None:
    ax.plot(pose.x, pose.y, marker, color=colour, markersize=8, label=label, zorder=5)
    ax.arrow(
        pose.x,
        pose.y,
        size_m * np.cos(pose.theta),
        size_m * np.sin(pose.theta),
        color=colour,
        width=size_m * 0.04,
        length_includes_head=True,
        zorder=5,
    )


def draw_overlay(
    segments_world: np.ndarray, panels: Sequence[OverlayPanel], caption: str | None = None
) -> Figure:
    """Global map (grey) with each panel's local map and readings at its estimated pose;
    ``caption`` (e.g. ``overlay_caption``) says under the title which poses and why."""
    fig = _new_figure(OVERLAY, len(panels))
    rows, cols = _grid(len(panels))
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    for ax, panel in zip(axes, panels, strict=False):
        x0, x1, y0, y1 = panel.extent_m
        _draw_map(ax, segments_world)
        ax.plot(*panel.points_world.T, ".", color=_POINT_COLOUR, markersize=1.5)
        # A stand-in, so the legend shows the readings' marker at a size one can see.
        ax.plot([], [], ".", color=_POINT_COLOUR, markersize=6, label="readings")
        local = LineCollection(
            list(panel.segments_world.reshape(-1, 2, 2)),
            colors=_LOCAL_COLOUR,
            linewidths=1.2,
            label="local map",
        )
        ax.add_collection(local)
        _draw_pose(ax, panel.estimate, _LOCAL_COLOUR, "o", "estimate", (x1 - x0) / 15)
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_aspect("equal")
        ax.set_title(
            f"pose {panel.pose_id}: {_number(panel.err_xy_cm, 1)} cm, "
            f"{_number(panel.err_theta_deg, 2, sign=True)}°",
            fontsize=10,
        )
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    for ax in axes[len(panels) :]:
        ax.set_visible(False)
    if panels:
        axes[0].legend(loc="upper left", fontsize=7, framealpha=0.9)
    title = "Local maps at their estimated poses over the global map"
    fig.suptitle(title if caption is None else f"{title}\n{caption}")
    return fig


# --------------------------------------------------------------------------- stage 1


def heading_errors_by_vote(
    segments_world: np.ndarray,
    items: Sequence[SurveyedScan],
    window_deg: float = 20.0,
    bin_deg: float = 1.0,
    schemes: Sequence[str] = VOTE_SCHEMES,
) -> pd.DataFrame:
    """Stage-1 heading error (degrees, surveyed minus computed) per pose and vote scheme.

    The heading is the best peak of ``align`` with the whole map's R-table,
    within ±``window_deg`` of each pose's initial heading (the whole circle
    when a pose has none): stage 1 as ``segloc localize`` runs it whenever the
    map lies within the scan's reach, as the hall's does. ``segments_world``
    (M, 4) is the global map, metres, world frame. Returns a DataFrame indexed
    by ``pose_id``, one column per scheme; NaN where the vote found nothing.
    """
    rtable = RTable.build(np.asarray(segments_world, dtype=float), bin_deg)
    errors = {}
    for item in items:
        prior = item.initial.theta if np.isfinite(item.initial.theta) else None
        row = []
        for scheme in schemes:
            result = align(rtable, item.segments_robot, prior, window_deg, scheme)
            if result.peaks_rad.size == 0:
                row.append(np.nan)
            else:
                row.append(float(np.rad2deg(wrap_angle(item.truth.theta - result.best_rad))))
        errors[item.pose_id] = row
    frame = pd.DataFrame.from_dict(errors, orient="index", columns=list(schemes), dtype=float)
    frame.index.name = "pose_id"
    return frame


def draw_heading_by_vote(errors: pd.DataFrame, window_deg: float = 20.0) -> Figure:
    """One marker series per vote scheme: heading error (°) on one evenly spaced slot per
    pose, labelled by pose id (thinned to a readable count)."""
    fig = _new_figure(HEADING_BY_VOTE)
    ax = fig.subplots()
    colours = method_colours(errors.columns)
    n = len(errors.columns)
    slots = np.arange(len(errors), dtype=float)
    for k, scheme in enumerate(errors.columns):
        # Side by side within each slot, so equal errors do not hide each other.
        shift = (k - (n - 1) / 2) * 0.12
        ax.plot(
            slots + shift,
            errors[scheme].to_numpy(),
            _SCHEME_MARKERS.get(scheme, "o"),
            color=colours[scheme],
            label=scheme,
            linestyle="none",
        )
    ax.axhline(0.0, color="0.5", linewidth=0.8)
    width_in = figure_size_in(HEADING_BY_VOTE)[0] * _AXES_SHARE
    slot_ticks(ax, [str(v) for v in errors.index], width_in)
    ax.set_xlabel("pose id (one slot per pose)")
    ax.set_ylabel("heading error (°)")
    ax.set_title(
        f"Stage-1 heading error (surveyed − voted) by vote scheme, "
        f"±{window_deg:g}° around the initial",
        fontsize=10,
    )
    ax.legend(title="vote", fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.grid(True, axis="y", alpha=0.3)
    return fig


def accumulator_curves(
    segments_world: np.ndarray,
    item: SurveyedScan,
    window_deg: float | None = 20.0,
    bin_deg: float = 1.0,
    schemes: Sequence[str] = ("product", "count"),
) -> pd.DataFrame:
    """The stage-1 accumulator of one pose under each scheme, each divided by its maximum.

    With ``window_deg`` the headings span ± that around the pose's initial
    heading (around the true heading when it has none), as stage 1 scores
    them; with None, the whole circle. Returns columns ``heading_deg``
    (world frame, increasing, unwrapped around the window's centre) and one
    per scheme (0–1); ``attrs["truth_deg"]`` and ``attrs["initial_deg"]`` are
    the true and initial headings on the same axis (the latter NaN when the
    pose has none).
    """
    rtable = RTable.build(np.asarray(segments_world, dtype=float), bin_deg)
    if window_deg is None:
        centre = 0.0
        headings = candidate_headings(None, 0.0, rtable.bin_width_rad)
    else:
        centre = item.initial.theta if np.isfinite(item.initial.theta) else item.truth.theta
        headings = candidate_headings(centre, np.deg2rad(window_deg), rtable.bin_width_rad)
    axis_rad = centre + wrap_angle(headings - centre)
    order = np.argsort(axis_rad)
    frame = pd.DataFrame({"heading_deg": np.rad2deg(axis_rad[order])})
    for scheme in schemes:
        votes = accumulate(rtable, item.segments_robot, headings, scheme)[order]
        top = votes.max() if votes.size else 0.0
        frame[scheme] = votes / top if top > 0 else votes
    for key, pose in (("truth_deg", item.truth), ("initial_deg", item.initial)):
        frame.attrs[key] = float(np.rad2deg(centre + wrap_angle(pose.theta - centre)))
    return frame


def draw_accumulator(curves: Sequence[pd.DataFrame], titles: Sequence[str]) -> Figure:
    """Normalised votes against heading, one panel per accumulator, the true heading marked."""
    fig = _new_figure(ACCUMULATOR)
    axes = fig.subplots(1, len(curves), squeeze=False).ravel()
    for ax, frame, title in zip(axes, curves, titles, strict=True):
        schemes = [c for c in frame.columns if c != "heading_deg"]
        colours = method_colours(schemes)
        for k, scheme in enumerate(schemes):
            label = {"product": "weighted (product)", "count": "unweighted (count)"}.get(
                scheme, scheme
            )
            # The first scheme (the paper's) is drawn last, on top of the others.
            ax.plot(
                frame["heading_deg"],
                frame[scheme],
                color=colours[scheme],
                label=label,
                zorder=3 + len(schemes) - k,
            )
        ax.axvline(
            frame.attrs["truth_deg"], color=_TRUTH_COLOUR, linestyle="--", label="true heading"
        )
        if np.isfinite(frame.attrs.get("initial_deg", np.nan)):
            ax.axvline(
                frame.attrs["initial_deg"], color="0.4", linestyle=":", label="initial heading"
            )
        span = float(frame["heading_deg"].max() - frame["heading_deg"].min())
        if span > 180.0:
            ax.set_xticks(np.arange(-180.0, 181.0, 45.0))
        ax.set_xlabel("heading (°)")
        ax.set_ylabel("votes / maximum")
        ax.set_ylim(0.0, 1.05)
        ax.set_title(title, fontsize=10)
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8, loc="best")
    return fig


# --------------------------------------------------------------------------- stage 2


def ring_guesses(
    truth: Pose2, n: int = 8, radius_m: float = 1.5, heading_error_deg: float = 2.0
) -> np.ndarray:
    """``n`` initial guesses (n, 3: x m, y m, θ rad, world frame) on a ring around ``truth``.

    Positions are evenly spaced on a circle of ``radius_m``, the first at
    half a spacing from the +x axis; headings are the true one plus and
    minus ``heading_error_deg`` in turn, standing in for the small error
    stage 1 leaves.
    """
    # Off the axes: a guess exactly one grid step (1.5 m by default) along x or y from the
    # truth has the truth on its first grid and converges in one iteration, which shows nothing.
    angles = 2.0 * np.pi * (np.arange(n) + 0.5) / n
    signs = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    return np.column_stack(
        [
            truth.x + radius_m * np.cos(angles),
            truth.y + radius_m * np.sin(angles),
            wrap_angle(truth.theta + signs * np.deg2rad(heading_error_deg)),
        ]
    )


def coarse_to_fine_tracks(
    segments_world: np.ndarray,
    segments_robot: np.ndarray,
    guesses: np.ndarray,
    params: LocalizeParams | None = None,
) -> pd.DataFrame:
    """The stage-2 estimate after each iteration, from each guess (G, 3).

    ``segments_world`` (M, 4) is the global map and ``segments_robot`` (N, 4)
    the local map; stage 2 runs with ``params``' grid, heading step,
    iterations, ratio and re-centring (default: as ``segloc localize``).
    Returns long-format rows ``guess`` (index into ``guesses``), ``step``
    (0 = the guess itself), ``x_m``, ``y_m``, ``theta_deg``, world frame.
    """
    p = params or LocalizeParams()
    frames = []
    for g, guess in enumerate(np.asarray(guesses, dtype=float).reshape(-1, 3)):
        track = coarse_to_fine(
            segments_world,
            segments_robot,
            Pose2(*(float(v) for v in guess)),
            grid_m=p.grid_m,
            dtheta_deg=p.dtheta_deg,
            iterations=p.iterations,
            ratio=p.ratio,
            recentres=p.recentres,
        ).track
        frames.append(
            pd.DataFrame(
                {
                    "guess": g,
                    "step": np.arange(len(track)),
                    "x_m": track[:, 0],
                    "y_m": track[:, 1],
                    "theta_deg": np.rad2deg(track[:, 2]),
                }
            )
        )
    return pd.concat(frames, ignore_index=True)


def draw_coarse_to_fine(
    segments_world: np.ndarray, tracks: pd.DataFrame, truth: Pose2, margin_m: float = 1.0
) -> Figure:
    """Stage-2 tracks over the map near ``truth``, and each one's distance to it per iteration."""
    fig = _new_figure(COARSE_TO_FINE)
    ax_map, ax_err = fig.subplots(1, 2, width_ratios=[1.0, 1.1])
    _draw_map(ax_map, segments_world)
    for g, track in tracks.groupby("guess", sort=True):
        x, y = track["x_m"].to_numpy(), track["y_m"].to_numpy()
        first = g == tracks["guess"].iloc[0]
        ax_map.plot(x, y, "-", color=_TRACK_COLOUR, linewidth=1.0, label="track" if first else None)
        ax_map.plot(x[1:-1], y[1:-1], ".", color=_TRACK_COLOUR, markersize=4)
        ax_map.plot(
            x[0], y[0], "o", mfc="white", mec=_TRACK_COLOUR, label="start" if first else None
        )
        ax_map.plot(x[-1], y[-1], "o", color=_TRACK_COLOUR, label="end" if first else None)
        dist_cm = 100.0 * np.hypot(x - truth.x, y - truth.y)
        # A converged track sits at exactly zero on some steps; log axes need a floor.
        ax_err.plot(
            track["step"], np.maximum(dist_cm, 1e-2), "-o", color=_TRACK_COLOUR, markersize=3
        )
    ax_map.plot(truth.x, truth.y, "*", color=_TRUTH_COLOUR, markersize=14, label="true pose")
    half = float(np.hypot(tracks["x_m"] - truth.x, tracks["y_m"] - truth.y).max()) + margin_m
    ax_map.set_xlim(truth.x - half, truth.x + half)
    ax_map.set_ylim(truth.y - half, truth.y + half)
    ax_map.set_aspect("equal")
    ax_map.set_xlabel("x (m)")
    ax_map.set_ylabel("y (m)")
    ax_map.set_title("Tracks from guesses around the true pose", fontsize=10)
    ax_map.legend(fontsize=7, loc="upper left", framealpha=0.9)
    ax_err.set_yscale("log")
    ax_err.set_xlabel("iteration")
    ax_err.set_ylabel("distance to the true position (cm)")
    ax_err.set_title("Convergence (distances under 0.01 cm drawn at 0.01 cm)", fontsize=10)
    ax_err.grid(True, which="both", alpha=0.3)
    return fig


# --------------------------------------------------------------------------- trials


TRIAL_COLUMNS = ("dataset", "method", "init_err_m", "success")
"""Columns of a trials table that ``success_rates`` reads (others are ignored)."""


def _as_bool(values: pd.Series) -> np.ndarray:
    """Booleans from bools, numbers (missing: False) or words such as "True" and "false"."""
    if pd.api.types.is_bool_dtype(values) or pd.api.types.is_numeric_dtype(values):
        return values.fillna(0).to_numpy().astype(bool)
    text = values.astype(str).str.strip().str.lower()
    return text.isin(("true", "1", "yes")).to_numpy()


def success_rates(
    trials: pd.DataFrame, bins_m: Sequence[float] = INIT_ERROR_BINS_M
) -> pd.DataFrame:
    """Share of successful trials per dataset, method and initial position-error bin.

    ``trials`` has at least ``TRIAL_COLUMNS``: ``init_err_m`` the initial
    position error (metres), ``success`` a bool. Bins are [lo, hi) except the
    last, which includes its upper edge; trials outside every bin are left
    out. Returns one row per dataset, method (both in order of appearance)
    and bin: ``dataset``, ``method``, ``bin_lo_m``, ``bin_hi_m``, ``n_trials``,
    ``n_success``, ``success_rate`` (0–1, NaN for an empty bin).
    """
    missing = [c for c in TRIAL_COLUMNS if c not in trials.columns]
    if missing:
        raise ValueError(f"trials lack the column(s) {', '.join(missing)}")
    from segloc_cli.scoring.convergence import bin_index

    edges = np.asarray(bins_m, dtype=float)
    n_bins = edges.size - 1
    index = bin_index(trials["init_err_m"].to_numpy(dtype=float), edges)
    inside = index >= 0
    frame = pd.DataFrame(
        {
            "dataset": trials["dataset"].to_numpy(),
            "method": trials["method"].to_numpy(),
            "bin": index,
            "success": _as_bool(trials["success"]),
        }
    )
    pairs = frame[["dataset", "method"]].drop_duplicates()
    counts = (
        frame[inside]
        .groupby(["dataset", "method", "bin"], sort=False)["success"]
        .agg(n_trials="size", n_success="sum")
    )
    rows = []
    for dataset, method in pairs.itertuples(index=False):
        for b in range(n_bins):
            key = (dataset, method, b)
            n = int(counts.at[key, "n_trials"]) if key in counts.index else 0
            k = int(counts.at[key, "n_success"]) if key in counts.index else 0
            rate = k / n if n else np.nan
            rows.append((dataset, method, edges[b], edges[b + 1], n, k, rate))
    columns = ["dataset", "method", "bin_lo_m", "bin_hi_m", "n_trials", "n_success"]
    return pd.DataFrame(rows, columns=[*columns, "success_rate"])


def draw_success_vs_initial_error(rates: pd.DataFrame) -> Figure:
    """Success rate (%) against initial position error, one line per method, a panel per dataset."""
    datasets = list(dict.fromkeys(rates["dataset"]))
    fig = _new_figure(SUCCESS_VS_INITIAL_ERROR, len(datasets))
    axes = fig.subplots(1, max(1, len(datasets)), squeeze=False, sharey=True).ravel()
    colours = method_colours(rates["method"])
    for ax, dataset in zip(axes, datasets, strict=True):
        part = rates[rates["dataset"] == dataset]
        for method, rows in part.groupby("method", sort=False):
            centres = (rows["bin_lo_m"] + rows["bin_hi_m"]) / 2.0
            ax.plot(
                centres, 100.0 * rows["success_rate"], "-o", color=colours[method], label=method
            )
        edges = np.unique(np.concatenate([part["bin_lo_m"], part["bin_hi_m"]]))
        ax.set_xticks(edges)
        ax.set_xlim(edges[0], edges[-1])
        ax.set_ylim(-3.0, 103.0)
        ax.set_xlabel("initial position error (m)")
        ax.set_title(str(dataset), fontsize=10)
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("success rate (%)")
    axes[0].legend(fontsize=8, loc="lower left")
    return fig


# --------------------------------------------------------------------------- all at once


def evaluation_figures(
    table: pd.DataFrame,
    segments_world: np.ndarray | None = None,
    items: Sequence[SurveyedScan] | None = None,
    pose_id: int | None = None,
    window_deg: float = 20.0,
    *,
    flagged: np.ndarray | None = None,
) -> dict[str, Callable[[], Figure]]:
    """The figures of one evaluated run, by name, each drawn when called (``io/figures``
    writes them).

    ``table`` is a ``evaluate.table1`` result. ``TABLE_FIGURES`` are always drawn;
    ``flagged`` (N,) bool, one per table row, marks the poses that failed the gates in
    them (default: those whose status is not accepted). With the global map
    ``segments_world`` (M, 4) and the run's ``items`` (``surveyed_scans``) all of
    ``EVALUATION_FIGURES`` are drawn, the accumulator and the coarse-to-fine tracks for
    ``pose_id`` (default: ``stage_pose``'s choice).
    """
    figures: dict[str, Callable[[], Figure]] = {}
    if segments_world is not None and items:
        segments_world = np.asarray(segments_world, dtype=float)
        item, status = stage_pose(items, table, pose_id)
        figures = {
            OVERLAY: lambda: _overlay_figure(segments_world, items, table),
            HEADING_BY_VOTE: lambda: draw_heading_by_vote(
                heading_errors_by_vote(segments_world, items, window_deg), window_deg
            ),
            ACCUMULATOR: lambda: _accumulator_figure(segments_world, item, status, window_deg),
            COARSE_TO_FINE: lambda: _coarse_to_fine_figure(segments_world, item, status),
        }
    figures[ERRORS] = lambda: draw_errors(errors_by_pose(table), flagged=flagged)
    figures[ERRORS_OVER_TIME] = lambda: draw_error_trend(table, "time", flagged)
    figures[ERRORS_OVER_DISTANCE] = lambda: draw_error_trend(table, "distance", flagged)
    return figures


def stage_pose(
    items: Sequence[SurveyedScan], table: pd.DataFrame, pose_id: int | None = None
) -> tuple[SurveyedScan, str]:
    """The pose the accumulator and stage-2 figures show, and the words for its status.

    ``pose_id``'s item when given (ValueError when it is not among ``items``); else the
    first item whose status in ``table`` (a ``table1`` result) is ok, else the first item,
    its status then saying that no pose is ok.
    """
    if not items:
        raise ValueError("no surveyed scan to choose from")
    status = dict(zip(table["pose_id"].astype(int), table["status"].astype(str), strict=True))
    if pose_id is not None:
        chosen = [item for item in items if item.pose_id == pose_id]
        if not chosen:
            raise ValueError(f"pose {pose_id} is not among the surveyed scans")
        return chosen[0], status.get(pose_id, "not in the table")
    for item in items:
        if status.get(item.pose_id) == STATUS_OK:
            return item, STATUS_OK
    first = items[0]
    return first, f"{status.get(first.pose_id, 'not in the table')}; no pose is {STATUS_OK}"


def _accumulator_figure(
    segments_world: np.ndarray, item: SurveyedScan, status: str, window_deg: float
) -> Figure:
    curves = [
        accumulator_curves(segments_world, item, window_deg),
        accumulator_curves(segments_world, item, None),
    ]
    titles = [f"±{window_deg:g}° around the initial heading", "whole circle"]
    fig = draw_accumulator(curves, titles)
    fig.suptitle(f"Stage-1 votes of pose {item.pose_id} ({status}), weighted and unweighted")
    return fig


def _coarse_to_fine_figure(segments_world: np.ndarray, item: SurveyedScan, status: str) -> Figure:
    tracks = coarse_to_fine_tracks(segments_world, item.segments_robot, ring_guesses(item.truth))
    fig = draw_coarse_to_fine(segments_world, tracks, item.truth)
    fig.suptitle(
        f"Stage 2 from {tracks['guess'].nunique()} guesses around pose {item.pose_id} ({status})"
    )
    return fig
