"""A run from inputs to results, as plain functions the commands call.

Each function takes what was read (logs, maps, pose tables) and a ``Config``,
and returns results or an iterator of estimates rows; none prints or parses
options. Bad input raises ``InputError`` naming the file.

- ``paired_guesses``: which scans of a log have an initial guess, and which.
- ``localizer_for``: the matcher a configuration asks for, on a map.
- ``localize_log``: the rows of one log, batch, global or tracked.
- ``localize_guessed``: the rows of chosen scans of a log, from their guesses or global.
- ``build_map``: a segment map from surveyed scans.
- ``read_plan``, ``write_plan``: a segment map from a building plan or grid, or as one.
- ``simulate_log``: a simulated log of a world at given poses.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from segloc_cli.config import Config
from segloc_cli.errors import InputError
from segloc_cli.estimates import EstimateRow, PoseTable
from segloc_cli.geometry import Pose2
from segloc_cli.io.log import Log
from segloc_cli.progress import ProgressFactory, silent
from segloc_cli.timing import pair_by_time, time_range
from segloc_cli.wording import counted, plural, with_article

RUN_MODES = ("guided", "global", "track")
"""How a log is localized: each scan from its own guess, each with none, or along a track."""

GUESSES_WITHOUT_ODOMETRY = (
    "; pass --global (no initial pose needed), or --initial FILE.csv with a guess per scan "
    "(pose_id,time_s,x_m,y_m,theta_deg)"
)
"""How an error about a log without odometry to take guesses from ends: what works instead."""


def odometry_rows(log: Log, log_path: Path, tolerance_s: float, missing: str) -> np.ndarray:
    """Index of the /odom message nearest each scan in time (−1 where none is close enough).

    Two /odom messages at the time nearest a scan, or two scans at one time, are refused;
    a log without /odom is refused with "the log has no /odom messages" + ``missing``.
    """
    if log.odom_times_s.size == 0:
        raise InputError(f"the log has no /odom messages{missing}", path=log_path)
    return pair_by_time(
        log.scan_times_s,
        log.odom_times_s,
        tolerance_s,
        query_path=log_path,
        ref_path=log_path,
        query_label="scan",
        ref_label="/odom message",
    )


@dataclass(frozen=True)
class Guesses:
    """The scans of a log that have an initial guess: their indices in the log, the guesses
    (world frame) and the pose ids of their rows."""

    index: np.ndarray
    poses: list[Pose2]
    pose_ids: np.ndarray


def paired_guesses(
    log: Log,
    log_path: Path,
    initial: Path | Pose2 | None,
    tolerance_ms: float,
    selected: np.ndarray | None = None,
) -> Guesses:
    """Initial guesses for the scans ``selected`` (indices in ``log``; None: every scan): from
    the log's /odom (``initial`` None) or from a pose table (a path), nearest in time within
    ``tolerance_ms``; or, ``initial`` a pose, that of the first selected scan, carried to the
    others by the odometry (``seeded_guesses``).

    Pose ids come from the table's rows, or are the scans' own numbers
    (``Log.scan_numbers``) for /odom guesses. A guess shared by two rows of equal time, or
    two scans at one time, is refused rather than paired silently.
    """
    from segloc_cli.io.tables import read_pose_table

    selected = np.arange(len(log.scans)) if selected is None else selected
    if isinstance(initial, Pose2):
        return seeded_guesses(log, log_path, initial, tolerance_ms, selected)
    tolerance_s = tolerance_ms / 1e3
    if initial is None:
        missing = f" to take initial guesses from{GUESSES_WITHOUT_ODOMETRY}"
        rows = odometry_rows(log, log_path, tolerance_s, missing)
        ref_times, ref_poses, ref_ids = log.odom_times_s, log.odom_poses, None
    else:
        table = read_pose_table(initial)
        ref_times, ref_poses, ref_ids = table.time_s, table.poses, table.pose_id
        rows = pair_by_time(
            log.scan_times_s,
            table.time_s,
            tolerance_s,
            query_path=log_path,
            ref_path=initial,
            query_label="scan",
        )
    paired = rows[selected] >= 0
    index, rows = selected[paired], rows[selected][paired]
    if index.size == 0:
        source = "/odom" if initial is None else str(initial)
        raise InputError(
            f"{_no_guess(log, selected, tolerance_ms)}, the guesses of {source} "
            f"{time_range(ref_times)}; or give the first scan's pose: --initial X,Y,THETA_DEG",
            path=log_path,
        )
    poses = [Pose2(*ref_poses[r]) for r in rows]
    ids = log.scan_numbers[index] if ref_ids is None else ref_ids[rows]
    return Guesses(index, poses, ids)


def _no_guess(log: Log, selected: np.ndarray, tolerance_ms: float) -> str:
    """The start of the error of a run whose scans ``selected`` have no guess: the tolerance,
    the scans' times and the log's first scan's."""
    times = log.scan_times_s
    some = "selected " if selected.size < times.size else ""
    return (
        f"no {some}scan has an initial guess within {tolerance_ms:g} ms (--tolerance-ms): the "
        f"log's first scan is at {times.min():.3f} s, its {some}scans span "
        f"{time_range(times[selected])}"
    )


def seeded_guesses(
    log: Log, log_path: Path, seed: Pose2, tolerance_ms: float, selected: np.ndarray
) -> Guesses:
    """The guesses of ``--initial X,Y,THETA_DEG``: the first of the scans ``selected``
    (indices in ``log``, in log order) at ``seed`` (world frame), and every other one at
    ``seed`` moved by the odometry from the first scan to it (its /odom nearest in time within
    ``tolerance_ms``; those without are left out).

    Refused, saying what works instead, when several scans are selected and the log has no
    odometry, or the first has no /odom message.
    """
    from segloc_cli.geometry import transform_points, wrap_angle

    first = selected[:1]
    if selected.size == 1:
        return Guesses(first, [seed], log.scan_numbers[first])
    reason = no_odometry(log)
    carry = "to carry --initial X,Y,THETA_DEG from the first scan to the others"
    if reason is not None:
        # A simulated log's /odom holds a guess per scan: the default takes them.
        instead = "; --initial odom takes its guesses" if log.odom_times_s.size else ""
        raise InputError(f"{reason} {carry}{instead}{GUESSES_WITHOUT_ODOMETRY}", path=log_path)
    rows = odometry_rows(log, log_path, tolerance_ms / 1e3, "")[selected]
    if rows[0] < 0:
        raise InputError(
            f"the first scan ({log.scan_times_s[first[0]]:.3f} s) has no /odom message within "
            f"{tolerance_ms:g} ms {carry}",
            path=log_path,
        )
    paired = rows >= 0
    odometry = log.odom_poses[rows[paired]]
    # The one rigid motion that takes the first scan's odometry pose to the seed.
    anchor = seed.compose(Pose2(*odometry[0]).inverse())
    xy = transform_points(odometry[:, :2], anchor)
    theta = wrap_angle(odometry[:, 2] + anchor.theta)
    index = selected[paired]
    poses = [Pose2(float(x), float(y), float(t)) for (x, y), t in zip(xy, theta, strict=True)]
    return Guesses(index, poses, log.scan_numbers[index])


def localizer_for(segments_world: np.ndarray, config: Config, mode: str):
    """The ``ScanMatcher`` of ``config.method`` on a map (M, 4), world frame, for a run in
    ``mode`` (one of ``RUN_MODES``). The two-stage method's map is prepared here, all of it the
    mode runs (``prepared.prepare_map``), so that no scan's time includes building it."""
    if config.method == "two-stage":
        from segloc_cli.method.localize import Localizer

        return Localizer.on_map(segments_world, config.localize, global_search=mode == "global")
    from segloc_cli.peers import peer_localizer

    options = {"variant": config.icp_variant} if config.method == "icp" else {}
    return peer_localizer(config.method, segments_world, **options)


@dataclass(frozen=True)
class LogRun:
    """One log's part of a run: its estimates rows, made as they are read, and the scans
    they cover."""

    path: Path
    rows: Iterator[EstimateRow]
    times_s: np.ndarray
    """Times (s) of the scans localized."""
    skipped: int
    """Scans of the log left out (no initial guess, or no odometry when tracking)."""
    local_maps: str = ""
    """How each scan's local map was made, in words (``window_note``); empty for a track."""


def localize_log(
    log: Log,
    log_path: Path,
    localizer,
    mode: str,
    initial: Path | Pose2 | None,
    config: Config,
    stop: Callable[[], bool] = lambda: False,
    selected: np.ndarray | None = None,
) -> LogRun:
    """Plan the localization of one log; its rows are made as ``LogRun.rows`` is read.

    ``mode`` is one of ``RUN_MODES``. Only the scans ``selected`` (indices in log order;
    None: every scan) get rows; the others still give the selected ones their odometry and
    windows. Guided runs localize the scans with a guess from ``initial`` (None: the log's
    /odom; a path: a pose table; a pose: the first scan's, ``seeded_guesses``); global runs
    every scan, or with ``initial`` only the scans it lists; a track starts at the first
    scan with a guess (a pose: the first scan) and follows the odometry. ``stop`` is asked
    between blocks of scans on worker processes.
    """
    if mode not in RUN_MODES:
        raise ValueError(f"mode {mode!r} is not one of {', '.join(RUN_MODES)}")
    selected = np.arange(len(log.scans)) if selected is None else selected
    if mode == "global" and initial is None:
        guesses = Guesses(selected, [], log.scan_numbers[selected])
    elif mode == "track" and isinstance(initial, Pose2):
        guesses = Guesses(selected[:1], [initial], log.scan_numbers[selected[:1]])
    else:
        guesses = paired_guesses(log, log_path, initial, config.tolerance_ms, selected)
    if mode == "track":
        index, rows = _track(log, log_path, localizer, guesses, config, selected)
        return LogRun(log_path, rows, log.scan_times_s[index], selected.size - index.size)
    run = localize_guessed(log, log_path, localizer, guesses, config, stop, mode == "guided")
    return replace(run, skipped=selected.size - guesses.index.size)


def localize_guessed(
    log: Log,
    log_path: Path,
    localizer,
    guesses: Guesses,
    config: Config,
    stop: Callable[[], bool] = lambda: False,
    guided: bool = True,
) -> LogRun:
    """Plan the localization of the scans ``guesses.index`` of ``log``, each from its guess
    (world frame) when ``guided``, else by a global search, its row under its pose id, with
    its window where the log has odometry (``scan_windows``), on ``config.jobs`` processes
    (``stop`` is asked between blocks of scans); the rows are made as ``LogRun.rows`` is
    read."""
    from segloc_cli.runs.parallel import localize_scans_parallel

    index = guesses.index
    scans = [log.scans[i] for i in index]
    windows = scan_windows(log, log_path, index, localizer, config)
    rows = localize_scans_parallel(
        scans,
        guesses.poses if guided else None,
        guesses.pose_ids,
        localizer,
        config.jobs,
        config.extract,
        stop=stop,
        windows=windows,
    )
    note = window_note(log, localizer, config, windows)
    return LogRun(log_path, rows, log.scan_times_s[index], len(log.scans) - index.size, note)


def scan_odometry(log: Log, log_path: Path, tolerance_s: float) -> np.ndarray:
    """The odometry pose (S, 3: x m, y m, θ rad) at each scan of ``log``, the /odom message
    nearest in time within ``tolerance_s``; NaN where there is none."""
    rows = odometry_rows(log, log_path, tolerance_s, "")
    odometry = np.full((len(log.scans), 3), np.nan)
    odometry[rows >= 0] = log.odom_poses[rows[rows >= 0]]
    return odometry


def scan_windows(log: Log, log_path: Path, index: np.ndarray, localizer, config: Config):
    """The ``Windows`` of the scans ``index`` of ``log``: each one's neighbours placed by the
    log's odometry (``window.py``); None when each scan is to be localized alone (the
    window is off, the matcher takes single scans, ``--no-refine`` asks for the paper's
    method, or the log has no odometry)."""
    from segloc_cli.method.window import Windows, neighbour_indices, relative_pose

    if alone_because(log, localizer, config) is not None:
        return None
    odometry = scan_odometry(log, log_path, config.tolerance_ms / 1e3)
    times = log.scan_times_s
    neighbours = [
        [
            (log.scans[j], relative_pose(odometry, i, j))
            for j in neighbour_indices(odometry, times, i, config.window)
        ]
        for i in index
    ]
    return Windows(neighbours, config.window, config.track)


def no_odometry(log: Log) -> str | None:
    """Why ``log`` has no odometry to place windows by, or None when it has."""
    if log.has_odometry:
        return None
    if log.odom_times_s.size:
        return "the log's /odom holds simulated initial guesses, not odometry"
    return "the log has no /odom odometry"


def alone_because(log: Log, localizer, config: Config) -> str | None:
    """Why a guided or global run localizes each scan of ``log`` alone, or None when it gives
    them windows."""
    if config.window.travel_m <= 0:
        return "--window-m 0"
    if not localizer.supports_window:
        return f"--method {config.method} takes single scans"
    if config.localize.refine is None:
        return "--no-refine: the paper's method, one scan a local map"
    return no_odometry(log)


def window_note(log: Log, localizer, config: Config, windows) -> str:
    """How a guided or global run made each scan's local map, in words."""
    if windows is None:
        return f"each scan alone ({alone_because(log, localizer, config)})"
    held = [len(n) + 1 for n in windows.neighbours]
    median = float(np.median(held)) if held else 1.0
    return (
        f"each scan with its neighbours within {config.window.travel_m:g} m of odometry "
        f"travel (window of {median:g} {plural(median, 'scan')}, median)"
    )


def _track(
    log: Log, log_path: Path, localizer, guesses: Guesses, config: Config, selected: np.ndarray
):
    """(scan indices, rows) of a track along the scans ``selected`` (indices, in log order)
    from the first guessed scan, carried by the odometry from each to the next."""
    from segloc_cli.method.tracking import track_scans

    tolerance_s = config.tolerance_ms / 1e3
    missing = "; tracking needs odometry between scans (--global localizes each without it)"
    odom_rows = odometry_rows(log, log_path, tolerance_s, missing)
    first = guesses.index[0]
    chosen = np.zeros(len(log.scans), dtype=bool)
    chosen[selected] = True
    index = np.flatnonzero((odom_rows >= 0) & chosen & (np.arange(len(log.scans)) >= first))
    if index.size == 0:
        raise InputError(
            f"no scan from the first guess on has odometry within {config.tolerance_ms:g} ms; "
            "tracking needs /odom at the scans",
            path=log_path,
        )
    odometry = [Pose2(*log.odom_poses[r]) for r in odom_rows[index]]
    scans = [log.scans[i] for i in index]
    rows = track_scans(
        scans,
        odometry,
        guesses.poses[0],
        log.scan_numbers[index],
        localizer,
        config.extract,
        config.track,
    )
    return index, rows


def overlapping_logs(runs: list[LogRun]) -> list[str]:
    """A warning for each two logs whose localized scans overlap in time: their rows share a
    time span, and scoring them against one survey would pair rows it cannot tell apart."""
    spans = sorted(
        ((run.path, run.times_s.min(), run.times_s.max()) for run in runs if run.times_s.size),
        key=lambda span: span[1],
    )
    return [
        f"{first} and {second} overlap in time ({start:.3f}–{end:.3f} s); their rows in the "
        "estimates cannot be told apart by time (evaluate will refuse them)"
        for (first, _, end), (second, start, _) in itertools.pairwise(spans)
        if start <= end
    ]


MAX_GLOBAL_AREA_M2 = 250_000.0
"""Largest area (m²) a global search covers: a map's bounding box, or its ``--region``. At
about 2·10⁻⁴ s per m² on one core (the shared logs), more is no answer a user waits for."""


def check_global_extent(
    segments_world: np.ndarray, map_path: Path, region: tuple[float, ...] | None
) -> None:
    """Refuse a global search of an area too large to search in reasonable time, or of a
    region that does not meet the map."""
    lo, hi = segments_world.reshape(-1, 2).min(axis=0), segments_world.reshape(-1, 2).max(axis=0)
    if region is not None:
        x0, y0, x1, y1 = region
        if x1 < lo[0] or x0 > hi[0] or y1 < lo[1] or y0 > hi[1]:
            raise InputError(
                f"--region {x0:g},{y0:g},{x1:g},{y1:g} does not meet the map, which spans "
                f"{lo[0]:.1f}..{hi[0]:.1f} m × {lo[1]:.1f}..{hi[1]:.1f} m",
                path=map_path,
            )
        lo, hi = np.array([x0, y0]), np.array([x1, y1])
    width, height = hi - lo
    if width * height > MAX_GLOBAL_AREA_M2:
        what = "--region" if region is not None else "this map"
        raise InputError(
            f"--global searches {what}, which spans {width:.0f} m × {height:.0f} m, more than "
            f"the {MAX_GLOBAL_AREA_M2:,.0f} m² it searches in about a minute per scan; give "
            "initial guesses (--initial) or the area the robot is in (--region X0,Y0,X1,Y1)",
            path=map_path,
        )


@dataclass(frozen=True)
class BuiltMap:
    """A segment map (M, 4), world frame, and what it was made of: the log's scans with a
    survey row (their indices), each one's surveyed pose and its local map (robot frame);
    ``dropped`` (D, 4) holds the fused segments left out: seen through from more poses than
    saw them where ``dropped_seen_through`` (D,) is True, else seen from too few poses."""

    segments: np.ndarray
    scan_index: np.ndarray
    poses: list[Pose2]
    local_maps: list[np.ndarray]
    dropped: np.ndarray
    dropped_seen_through: np.ndarray

    @property
    def scans_used(self) -> int:
        return int(self.scan_index.size)

    @property
    def local_segments(self) -> int:
        return sum(local.shape[0] for local in self.local_maps)


def build_map(
    log: Log,
    log_path: Path,
    survey: PoseTable,
    survey_path: Path,
    config: Config,
    progress: ProgressFactory = silent,
    selected: np.ndarray | None = None,
) -> BuiltMap:
    """Fuse the local maps of the scans ``selected`` (indices in log order; None: every scan)
    that have a survey row, each placed at its pose (after ``config.fuse.polish_rounds``
    rounds of ``maps.fusion.polish_poses``, if any; ``BuiltMap.poses`` holds the poses used),
    and keep the segments seen from at least ``config.fuse.min_observations`` survey rows
    and, unless ``config.fuse.seen_through`` is "keep", not seen through from more survey
    rows than saw them (``maps.carving``); the extraction (scans), polishing (rounds), fusion
    (segments compared) and carving (one pass) report to ``progress``."""
    from segloc_cli.method.extract import extract_segments

    times = log.scan_times_s
    selected = np.arange(times.size) if selected is None else selected
    rows = pair_by_time(
        times,
        survey.time_s,
        config.tolerance_ms / 1e3,
        query_path=log_path,
        ref_path=survey_path,
        query_label="scan",
    )
    used = selected[rows[selected] >= 0]
    if used.size == 0:
        some = "selected " if selected.size < times.size else ""
        raise InputError(
            f"no {some}scan is within {config.tolerance_ms:g} ms of a survey row ({some}scans "
            f"{time_range(times[selected])}, survey {time_range(survey.time_s)}); check the "
            "time base or --tolerance-ms",
            path=survey_path,
        )
    local_maps = []
    with progress("extracting segments", used.size, "scan") as shown:
        for i in used:
            local_maps.append(extract_segments(log.scans[i], config.extract))
            shown.advance()
    poses = [Pose2(*survey.poses[rows[i]]) for i in used]
    return fused_map(log, log_path, used, poses, local_maps, config, progress, rows[used])


def slam_map(
    log: Log,
    log_path: Path,
    config: Config,
    progress: ProgressFactory = silent,
    selected: np.ndarray | None = None,
    initial: Pose2 | None = None,
):
    """``map build`` without a survey: the poses of the scans ``selected`` (None: every scan)
    by segment SLAM (``maps.slam``) from their odometry (none: scan to map alone), the first
    at ``initial`` (world frame; None: the origin), then the map of every scan's local map
    at its pose (``fused_map``): a keyframe's solved, another's fitted from its keyframe's.
    Returns the ``BuiltMap`` and the ``SlamResult``."""
    from segloc_cli.maps.slam import WORLD_ORIGIN, odometry_at, run_slam
    from segloc_cli.method.extract import extract_segments

    selected = np.arange(len(log.scans)) if selected is None else selected
    if selected.size < 2:
        raise InputError(
            f"a map built without --survey needs at least two scans, the log gives "
            f"{selected.size}; give a longer log, or the scans' poses with --survey",
            path=log_path,
        )
    scans = [log.scans[i] for i in selected]
    times = log.scan_times_s[selected]
    odometry = None
    if log.has_odometry:
        odometry = odometry_at(times, log.odom_times_s, log.odom_poses)
    with progress("mapping", selected.size, "scan") as shown:

        def advance(done: int, counts: dict[str, int]) -> None:
            shown.count(counts)
            shown.advance(done - shown.done)

        result = run_slam(
            scans, odometry, config.slam, initial=initial or WORLD_ORIGIN,
            extract_params=config.extract,
            refine_params=config.localize.refine, fuse_params=config.fuse, advance=advance,
        )  # fmt: skip
    # Every scan's local map at its pose, keyframes' and the others' alike, so that the
    # poses written (--poses-out) given back as a survey build this same map.
    local_maps = [np.zeros((0, 4))] * selected.size
    for k, i in enumerate(result.keyframes):
        local_maps[i] = result.local_maps[k]
    others = np.setdiff1d(np.arange(selected.size), result.keyframes)
    with progress("extracting segments", others.size, "scan") as shown:
        for i in others:
            local_maps[i] = extract_segments(scans[i], config.extract)
            shown.advance()
    poses = [Pose2(*pose) for pose in result.poses]
    built = fused_map(
        log, log_path, selected, poses, local_maps, config, progress,
        placed_by="the scans' poses",
    )  # fmt: skip
    return built, result


def fused_map(
    log: Log,
    log_path: Path,
    used: np.ndarray,
    poses: list[Pose2],
    local_maps: list[np.ndarray],
    config: Config,
    progress: ProgressFactory = silent,
    viewpoints: np.ndarray | None = None,
    placed_by: str = "surveyed poses",
) -> BuiltMap:
    """The map of the local maps (robot frame) of the scans ``used`` (indices in log order)
    at ``poses`` (world frame), polished, fused, counted and carved as ``build_map`` says;
    ``viewpoints`` labels the scans seen from one place alike (None: each its own);
    ``placed_by`` names the poses in errors."""
    from segloc_cli.maps.carving import free_length, mostly_free
    from segloc_cli.maps.fusion import observed_map, polish_poses
    from segloc_cli.method.freespace import SHORTEN_M

    labels = np.arange(used.size) if viewpoints is None else viewpoints
    carve = config.fuse.seen_through == "drop"
    points = [log.scans[i].points() for i in used] if config.fuse.polish_rounds or carve else []
    if config.fuse.polish_rounds:
        with progress("polishing poses", config.fuse.polish_rounds, "round") as shown:
            poses = polish_poses(local_maps, points, poses, config.fuse, shown)
    segments, seen = observed_map(local_maps, poses, config.fuse, progress, labels)
    if segments.shape[0] == 0:
        raise InputError(
            f"no segments could be extracted from the scans at {placed_by}", path=log_path
        )
    kept = seen >= config.fuse.min_observations
    if not kept.any():
        raise InputError(
            f"no segment was seen from {config.fuse.min_observations} {placed_by}; lower "
            "--min-observations",
            path=log_path,
        )
    through = np.zeros_like(kept)
    if carve:
        with progress("carving free space", None, "pass") as shown:
            margin_m = config.fuse.offset_m
            free_m = free_length(segments, seen, points, poses, labels, margin_m, SHORTEN_M)
            through = kept & mostly_free(segments, free_m, margin_m)
            shown.advance()
    if not (kept & ~through).any():
        raise InputError(
            f"every segment is seen through from more {placed_by} than saw it; check the "
            "poses, or keep them with --seen-through keep",
            path=log_path,
        )
    return BuiltMap(
        segments[kept & ~through], used, poses, local_maps, segments[~kept | through],
        through[~kept | through],
    )  # fmt: skip


def read_plan(
    plan_path: Path,
    kind: str,
    layers: Sequence[str] = (),
    units: str | None = None,
    scale_m: float | None = None,
    origin: tuple[float, float] = (0.0, 0.0),
):
    """The segments of a building plan or grid (an ``io/plans.Plan``) of ``kind`` "dxf" (of
    ``layers``, all when empty; in ``units`` where the drawing says none), "svg" (``scale_m``
    metres per unit, its origin at ``origin``, metres) or "nav2"."""
    if kind == "dxf":
        from segloc_cli.io.plans import read_dxf

        return read_dxf(plan_path, layers, units)
    if kind == "svg":
        from segloc_cli.io.svg import read_svg

        return read_svg(plan_path, scale_m, origin)
    from segloc_cli.io.grids import read_nav2

    return read_nav2(plan_path)


def write_plan(
    out_path: Path, segments_world: np.ndarray, kind: str, resolution_m: float | None = None
) -> str:
    """Write a segment map (M, 4; world frame) as a plan of ``kind`` "nav2" (a grid of cells of
    ``resolution_m``, its default when None, with its image beside), "svg" or "dxf"; returns
    what was written, in words after the count of segments ("as lines, in metres")."""
    if kind == "nav2":
        from segloc_cli.io.grids import DEFAULT_RESOLUTION_M, write_nav2

        res = DEFAULT_RESOLUTION_M if resolution_m is None else resolution_m
        grid = write_nav2(out_path, segments_world, res)
        columns, rows = grid.shape
        return (
            f"drawn in {counted(grid.occupied_cells, 'occupied cell')} of "
            f"{with_article(str(columns))} × {rows} grid of {res:g} m ({grid.image})"
        )
    if kind == "svg":
        from segloc_cli.io.svg import write_svg

        write_svg(out_path, segments_world)
        return "as lines, 1 unit = 1 mm"
    from segloc_cli.io.plans import write_dxf

    write_dxf(out_path, segments_world)
    return "as lines, in metres"


def simulate_log(
    log_path: Path,
    world,
    truth: PoseTable,
    init_errors: tuple[str, float, float],
    sensor,
    seed: int,
    settings: dict[str, str],
    odometry=None,
) -> None:
    """Write a simulated log of ``world``: a scan at each true pose of ``truth`` (its times
    increasing) and, as /odom, an initial guess off by ``init_errors`` ("paper": the
    paper's Table 1 errors; "uniform", XY_M, THETA_DEG: uniform within those), or, given an
    ``odometry`` drift (``sim.OdometryDrift``), wheel odometry in its own frame."""
    from segloc_cli.io.files import atomic_path
    from segloc_cli.io.mcap_log import LogWriter
    from segloc_cli.sim import drifting_odometry, initial_errors, initial_guesses, simulate_scan

    rng = np.random.default_rng(seed)
    if odometry is None:
        guesses = initial_guesses(truth.poses, initial_errors(len(truth), init_errors, rng))
    else:
        guesses = drifting_odometry(truth.poses, odometry, rng)
    with atomic_path(log_path) as partial, LogWriter(partial, settings) as log:
        for t, pose, guess in zip(truth.time_s, truth.poses, guesses, strict=True):
            log.add_odom(float(t), Pose2(*guess))
            log.add_scan(simulate_scan(world, Pose2(*pose), sensor, rng, float(t)))
