"""Real-log benchmark (`make bench-real`): segloc on the public Radish logs.

For each dataset, through the command line exactly as a user would run it:

(a) Perturbation protocol. The SLAM-corrected CARMEN log is imported with its
    poses as the reference; a map is built from every scan except every 10th;
    each left-out scan is localized from its reference pose plus uniform
    errors in ±1.5 m, ±1.5 m, ±20° (seeded). Success: within 10 cm and 1°.
(b) Tracking protocol. The raw log (ROS bag, or CARMEN .clf) is localized with
    --track against the map of (a), seeded with (0, 0, 0) at its first scan
    (the corrected log's frame starts at the raw run's first pose), and scored
    with the relation metric of Kümmerle et al. (2009), next to the published
    graph-mapping errors. The estimate of every scan the corrected log holds
    (found in the raw log by its readings) is compared with its reference pose,
    and the reference poses themselves are scored on the relations beside
    segloc's tracked poses.
(c) Precision protocol (``precision.py``). The relations' end scans, held out of
    a map of their own, each localized from a perturbed guess and scored on the
    ground-truth relations.

The confidence column of (a) and the global runs is checked for calibration (a
reliability table and figure). Writes a markdown report with every figure and the
commands behind it.
Usage: python benchmarks/real_logs.py [--datasets DIR] [--only intel,aces] [--work DIR] [--out FILE]
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pandas as pd
from precision import ImportedLogs, precision, precision_section
from protocol import (
    DATASETS,
    HELD_OUT_ALONE,
    HOLD_OUT_EVERY,
    OWN_SCAN_ONLY,
    PERTURB_SEED,
    PERTURB_THETA_DEG,
    PERTURB_XY_M,
    PLACE_DEG,
    PLACE_M,
    SUCCESS_DEG,
    SUCCESS_M,
    HeldOutSplit,
    RawLog,
    chosen_logs,
    commands_section,
    distances,
    errors_against_truth,
    is_right,
    is_right_place,
    log_arguments,
    mean_sd,
    percent,
    perturbed_guesses,
    pose_errors,
    prepare_held_out,
    prepare_raw_log,
    raw_held_out,
    reliability_rows,
    rows_by_pose_id,
    run_segloc,
    same_scans,
    stage2_answers,
    truth_rows,
)

from segloc_cli.estimates import PoseTable
from segloc_cli.geometry import Pose2
from segloc_cli.io.maps import read_map
from segloc_cli.io.tables import read_estimates, read_pose_table, write_pose_table

TRACK_LIMIT_M = 1.0


def localize_held_out(split: HeldOutSplit, log: list[str], *options: object, out: Path) -> None:
    """Localize the held-out scans in the map of ``split`` with ``options``, into ``out``: the
    guesses or poses ``options`` pass with ``--initial`` each seed only their own scan."""
    run_segloc(
        log, "localize", split.log_path, "--map", split.map_path, *HELD_OUT_ALONE, *options,
        "--out", out,
    )  # fmt: skip


def perturbation(name: str, split: HeldOutSplit, work: Path, log: list[str]) -> dict:
    """Protocol (a): the held-out scans localized from their reference poses plus uniform errors."""
    log.append(f"# guesses.csv: reference + uniform errors, seed {PERTURB_SEED}")
    truth = split.held_out_reference()
    n = len(truth)
    write_pose_table(work / "guesses.csv", perturbed_guesses(truth))
    t0 = time.perf_counter()
    localize_held_out(split, log, "--initial", work / "guesses.csv", out=work / "perturb.csv")
    elapsed = time.perf_counter() - t0
    est = read_estimates(work / "perturb.csv")
    scored = _scored(est, truth)
    stage2 = _scored(stage2_answers(est), truth)
    segments = read_map(split.map_path)
    scans = _held_out_scans(split.log_path, truth)
    failures_figure(name, segments, scans, est, truth, scored)
    return {
        "scans": len(split.reference),
        "held_out": n,
        "localized": len(est),
        "map_segments": len(segments),
        **scored["summary"],
        "success_stage2": stage2["summary"]["success"],
        "median_pos_stage2_m": stage2["summary"]["median_pos_m"],
        "reference_fit": reference_fit(segments, scans, truth),
        "median_local_segments": float(est["n_local_segments"].median()),
        "median_ms": float(est["runtime_ms"].median()),
        "wall_s": elapsed,
    }


CARTOGRAPHER = {
    "intel": (0.0229, 0.453),
    "aces": (0.0375, 0.373),
    "fr079": (0.0452, 0.538),
    "mit-csail": (0.0319, 0.369),
}
"""Cartographer's mean relation errors (m, °) on the same relations: Hess et al., Real-time
loop closure in 2D LIDAR SLAM, ICRA 2016, Table II."""


LISTED = 5
"""Hypotheses listed per scan in the global runs (``--hypotheses``): all the search finds."""


def global_localization(split: HeldOutSplit, work: Path, log: list[str]) -> dict:
    """The left-out scans localized with no initial pose (``--global``), every distinct
    hypothesis listed; ``truth_listed`` is the share of the ambiguous answers among whose
    hypotheses one is within ``PLACE_M`` and ``PLACE_DEG`` of the reference."""
    out = work / "global.csv"
    localize_held_out(
        split, log, "--global", "--hypotheses", LISTED, "--initial", split.held_out_path,
        out=out,
    )  # fmt: skip
    est = read_estimates(out)
    # The poses as the command read them (the file holds headings in degrees).
    truth = read_pose_table(split.held_out_path)
    listed = truth_listed(out, est, truth)
    found = listed["listed"] / listed["ambiguous"] if listed["ambiguous"] else float("nan")
    return {
        **_scored(est, truth)["summary"],
        "truth_listed": found,
        "ambiguous": listed["ambiguous"],
        "median_ms": float(est["runtime_ms"].median()),
    }


LOCAL_MAPS = {"single scan": ("--window-m", "0"), "window": ()}
"""The two ways the odometry protocol localizes each held-out scan: alone, and with the
neighbours the raw log's odometry places around it (segloc's default where a log has
odometry)."""


def odometry_protocol(
    name: str, split: HeldOutSplit, raw: RawLog, work: Path, log: list[str], trials: list
) -> dict[str, dict[str, dict]]:
    """The held-out scans found in the raw log, localized there from the perturbation
    protocol's guesses and with ``--global``, alone and with their windows
    (``LOCAL_MAPS``); the raw log is stripped of the map's scans first
    (``protocol.raw_held_out``), so that no window holds one. Scored in the convergence view
    (``convergence``); returns {protocol: {local map: figures}}, and adds each run's
    ``verdict_trials`` to ``trials``."""
    held = raw_held_out(split, raw, work, log)
    log.append(f"# raw-guesses.csv: {held.truth_path.name} + uniform errors, seed {PERTURB_SEED}")
    guesses = held.log_path.with_name("raw-guesses.csv")
    write_pose_table(guesses, perturbed_guesses(held.truth))
    segments = read_map(held.map_path)
    from segloc_cli.io.mcap_log import read_log

    scans = _held_out_scans(held.log_path, held.truth, read_log(held.log_path))
    results: dict[str, dict[str, dict]] = {"perturbation": {}, "global": {}}
    for local, options in LOCAL_MAPS.items():
        tag = local.split()[0]
        folder = held.log_path.parent
        perturb, globally = folder / f"perturb-{tag}.csv", folder / f"global-{tag}.csv"
        localize_held_out_raw(held, log, "--initial", guesses, *options, out=perturb)
        localize_held_out_raw(
            held, log, "--global", "--hypotheses", LISTED, "--initial", held.truth_path,
            *options, out=globally,
        )  # fmt: skip
        for protocol, out in (("perturbation", perturb), ("global", globally)):
            est = read_estimates(out)
            figures = convergence(est, held.truth, segments, scans)
            trials.append(verdict_trials(name, f"{protocol}, raw log", local, est, held.truth))
            if protocol == "global":
                figures["truth_listed"] = truth_listed(out, est, held.truth)
            results[protocol][local] = figures | {"map_left_out": held.left_out_near}
    return results


RAW_OWN_SCAN_ONLY = ("--tolerance-ms", "0.01")
"""How held-out scans pair with their poses in a raw log: at their very time. The raw bags
stamp scans in bursts a millisecond apart, so 1 ms would pair a pose with its neighbours."""


def localize_held_out_raw(held, log: list[str], *options, out: Path):
    """``segloc localize`` of the raw held-out log in its map (``protocol.RawHeldOut``), each
    pose of ``options``' --initial file seeding only its own scan."""
    run_segloc(
        log, "localize", held.log_path, "--map", held.map_path, *RAW_OWN_SCAN_ONLY, *options,
        "--out", out,
    )  # fmt: skip


REFERENCE_AGREES_M, REFERENCE_AGREES_DEG = 0.01, 0.1
"""Two single-scan fits of one scan this close (m, °) have found the same pose."""


def reference_disagrees(
    est: pd.DataFrame, truth: PoseTable, segments: np.ndarray, scans: list
) -> np.ndarray:
    """(N,) bool: rows whose answer is beyond the place bound of the reference, yet where the
    scan alone, fitted to the map from its reference pose, lands within
    ``REFERENCE_AGREES_M`` and ``REFERENCE_AGREES_DEG`` of the scan alone fitted from the
    answer: the map's best fit near the reference is the answer's, so the reference, not the
    answer, is off."""
    from segloc_cli.method.refine import refine_pose
    from segloc_cli.method.spatial import NEAR_CELL_M, SegmentGrid

    pos, head = errors_against_truth(est, truth)
    beyond = ~is_right_place(pos, head) & np.isfinite(pos)
    out = np.zeros(len(est), dtype=bool)
    if not beyond.any():
        return out
    index = SegmentGrid(segments, cell_m=NEAR_CELL_M)
    rows = truth_rows(est, truth)
    for k in np.flatnonzero(beyond):
        scan = scans[rows[k]]
        answer = Pose2.from_deg(*est.iloc[k][["x_m", "y_m", "theta_deg"]])
        from_reference = refine_pose(scan.points(), segments, Pose2(*truth.poses[rows[k]]),
                                     index=index).pose  # fmt: skip
        from_answer = refine_pose(scan.points(), segments, answer, index=index).pose
        apart_m, apart_deg = pose_errors(
            from_reference.x - from_answer.x,
            from_reference.y - from_answer.y,
            from_reference.theta - from_answer.theta,
        )
        out[k] = apart_m <= REFERENCE_AGREES_M and apart_deg <= REFERENCE_AGREES_DEG
    return out


def convergence(est: pd.DataFrame, truth: PoseTable, segments: np.ndarray, scans: list) -> dict:
    """The convergence view of one run: right = within ``PLACE_M`` and ``PLACE_DEG`` of the
    reference; rows where the reference disagrees (``reference_disagrees``) are counted
    apart and are neither right nor wrong."""
    pos, head = errors_against_truth(est, truth)
    disagrees = reference_disagrees(est, truth, segments, scans)
    right = is_right_place(pos, head) & ~disagrees
    wrong = ~right & ~disagrees
    ok = (est["status"] == "ok").to_numpy()
    judged = ~disagrees

    def share(mask, within):
        return float(mask[within].mean()) if within.any() else float("nan")

    return {
        "scans": len(est),
        "reference_disagrees": int(disagrees.sum()),
        "right": share(right, judged),
        "silent": share(wrong & ok, judged),
        "right_flagged": share(~ok, right),
        "wrong_flagged": share(~ok, wrong),
        "wrong": int(wrong.sum()),
        "within_10cm_1deg": float(np.mean(is_right(pos, head))),
        "median_pos_m": float(np.median(pos[np.isfinite(pos)])) if np.isfinite(pos).any() else
        float("nan"),
        "median_window_scans": float(est["window_scans"].median()),
        "median_ms": float(est["runtime_ms"].median()),
    }  # fmt: skip


def truth_listed(out: Path, est: pd.DataFrame, truth: PoseTable) -> dict:
    """Of a global run's ambiguous answers, how many list a hypothesis at the right place
    (the run's .hypotheses.csv beside ``out``)."""
    listed = pd.read_csv(out.with_name(out.stem + ".hypotheses.csv"))
    ambiguous = est[est["status"] == "ambiguous"]
    found = [
        bool(np.any(is_right_place(*errors_against_truth(listed[listed["pose_id"] == pid], truth))))
        for pid in ambiguous["pose_id"]
    ]
    return {"ambiguous": len(found), "listed": int(np.sum(found))}


def odometry_section(results: dict) -> list[str]:
    """The odometry protocol's table: per dataset, protocol and local map."""
    lines = [
        "",
        "## Single scan and window, on the raw logs' odometry",
        "",
        "Each held-out scan of (a) found in the raw log by its identical readings, and "
        "localized there from the same perturbed guesses as (a), and with `--global`: alone "
        "(`--window-m 0`), and with its window, the scans within 1 m of odometry travel before "
        "and after it placed by the raw log's odometry and fitted to each other (the default "
        "where a log has odometry). So that no window meets the map, the map is built anew "
        "for this protocol without the held-out scans and without every corrected scan in "
        "one's window (*left out near*), and the raw log is stripped of every scan that map "
        "was built from. Right: within "
        f"{PLACE_M * 100:.0f} cm and {PLACE_DEG:g}° of the reference. Reference disagrees: "
        "answers beyond that bound where the scan alone, fitted to the map from its reference "
        f"pose, lands within {REFERENCE_AGREES_M * 100:g} cm and {REFERENCE_AGREES_DEG:g}° of the "
        "scan alone fitted from the answer; they count neither as right nor as wrong. Silent: "
        "wrong yet ok. Right flagged / wrong flagged: of the right / wrong answers, the share "
        "whose status is not ok. Truth listed: of the ambiguous answers, those with a listed "
        f"hypothesis ({LISTED} at most) at the right place. Within 10 cm / 1°: against the "
        "reference, every answer counted (the raw bags' beam angles follow the bag, the maps "
        "the corrected logs' CARMEN rule, which fits these scans up to half a degree better).",
        "",
        "| dataset | protocol | local map | scans | left out near | right | silent "
        "| right flagged | wrong flagged | reference disagrees | truth listed "
        "| within 10 cm / 1° | median pos (cm) | scans per window | ms/scan |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
        "| target (window) | | | | | ≥ 99 % (global ≥ 97 %) | ≤ 1 % | ≤ 5 % | ≥ 90 % | "
        "| all | | | | |",
    ]
    for name, r in results.items():
        for protocol, by_map in (r.get("odometry") or {}).items():
            for local, f in by_map.items():
                listed = f.get("truth_listed")
                shown = "" if listed is None else f"{listed['listed']} of {listed['ambiguous']}"
                lines.append(
                    f"| {name} | {protocol} | {local} | {f['scans']} | {f['map_left_out']} | "
                    f"{percent(f['right'])} | "
                    f"{percent(f['silent'])} | {percent(f['right_flagged'])} | "
                    f"{percent(f['wrong_flagged'])} ({f['wrong']}) | "
                    f"{f['reference_disagrees']} | {shown} | {percent(f['within_10cm_1deg'])} | "
                    f"{f['median_pos_m'] * 100:.1f} | {f['median_window_scans']:g} | "
                    f"{f['median_ms']:.1f} |"
                )
    return lines


def _scored(est: pd.DataFrame, truth: PoseTable) -> dict:
    """Success, confidence and error figures of estimates against their reference poses.

    Right: within ``SUCCESS_M`` and ``SUCCESS_DEG`` whatever the status; a
    silent failure is a wrong answer with status ok. Gross: beyond ``PLACE_M`` or
    ``PLACE_DEG`` (a wrong place, not an imprecise one). The ``*_place`` figures are the
    convergence view: right = within ``PLACE_M`` and ``PLACE_DEG``, a bound the reference
    poses (SLAM output, not ground truth) can support.
    """
    pos, head = errors_against_truth(est, truth)
    right = is_right(pos, head)
    place = is_right_place(pos, head)
    gross = ~place
    ok = (est["status"] == "ok").to_numpy()
    finite = np.isfinite(pos)

    def percentile(values, q):
        return float(np.percentile(values[finite], q)) if finite.any() else float("nan")

    def share(mask, within=None):
        within = np.ones_like(mask) if within is None else within
        return float(mask[within].mean()) if within.any() else float("nan")

    return {
        "right": right,
        "pos_m": pos,
        "head_deg": head,
        "summary": {
            "success": share(right),
            "success_ok": share(right & ok),
            "statuses": est["status"].value_counts().to_dict(),
            "silent": share(~right & ok),
            "silent_gross": share(gross & ok),
            "wrong_flagged": share(~ok, ~right),
            "gross_flagged": share(~ok, gross),
            "right_flagged": share(~ok, right),
            "success_place": share(place),
            "silent_place": share(gross & ok),
            "wrong_flagged_place": share(~ok, gross),
            "right_flagged_place": share(~ok, place),
            "median_pos_m": percentile(pos, 50),
            "p95_pos_m": percentile(pos, 95),
            "median_head_deg": percentile(head, 50),
            "p95_head_deg": percentile(head, 95),
        },
    }


def _held_out_scans(log_path: Path, truth: PoseTable, log=None) -> list:
    """The scan of the log at ``log_path`` (read there unless ``log`` is given) at each
    reference time (None where there is none)."""
    from segloc_cli.io.mcap_log import read_log
    from segloc_cli.timing import nearest_by_time

    scans = (log or read_log(log_path)).scans
    rows = nearest_by_time(truth.time_s, np.array([s.time_s for s in scans]), 1e-3)
    return [scans[r] if r >= 0 else None for r in rows]


def reference_fit(segments: np.ndarray, scans: list, truth: PoseTable) -> float:
    """Share of left-out scans that refinement started at their reference pose keeps right.

    The map and the reference poses come from the same SLAM solution but do
    not agree exactly: this is how often the best fit of a scan to the map
    lies within the success bounds of its own reference, a ceiling for any
    method scored against that reference.
    """
    from segloc_cli.method.refine import refine_pose

    have = [k for k, scan in enumerate(scans) if scan is not None]
    fits = [refine_pose(scans[k].points(), segments, Pose2(*truth.poses[k])).pose for k in have]
    fitted = pd.DataFrame(
        {
            "x_m": [f.x for f in fits],
            "y_m": [f.y for f in fits],
            "theta_deg": [f.theta_deg for f in fits],
        }
    )
    pos, head = distances(fitted, truth.poses[have])
    return float(np.mean(is_right(pos, head)))


FIGURES = Path("benchmarks/figures")
FIGURE_PANELS = 6


def failures_figure(
    name: str,
    segments: np.ndarray,
    scans: list,
    est: pd.DataFrame,
    truth: PoseTable,
    scored: dict,
) -> None:
    """Plot the first few wrong answers: the map, the scan at the answer and at the reference.

    ``scans`` holds the left-out scan of each row of ``truth``; ``scored`` is
    what ``_scored`` made of ``est``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from segloc_cli.geometry import transform_points

    wrong = np.flatnonzero(~scored["right"])[:FIGURE_PANELS]
    if wrong.size == 0:
        return
    row_of = rows_by_pose_id(truth.pose_id)
    cols = 3
    rows = -(-wrong.size // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5 * cols, 5 * rows), squeeze=False)
    for ax in axes.ravel()[wrong.size :]:
        ax.axis("off")
    for ax, k in zip(axes.ravel(), wrong, strict=False):
        r = est.iloc[k]
        reference = truth.poses[row_of[int(r["pose_id"])]]
        scan = scans[row_of[int(r["pose_id"])]]
        answer = Pose2(r["x_m"], r["y_m"], np.deg2rad(r["theta_deg"]))
        for seg in segments:
            ax.plot(seg[0::2], seg[1::2], color="0.6", lw=0.8)
        points = scan.points()
        at_ref = transform_points(points, Pose2(*reference))
        ax.plot(*at_ref.T, ".", ms=2, color="tab:green", label="scan at reference")
        if np.isfinite(answer.x):
            at_answer = transform_points(points, answer)
            ax.plot(*at_answer.T, ".", ms=2, color="tab:red", label="scan at segloc's answer")
        centre = reference[:2]
        ax.set_xlim(centre[0] - 8, centre[0] + 8)
        ax.set_ylim(centre[1] - 8, centre[1] + 8)
        ax.set_aspect("equal")
        pos, head = scored["pos_m"][k], scored["head_deg"][k]
        ax.set_title(
            f"pose {int(r['pose_id'])}: {r['status']}, {pos * 100:.0f} cm, {head:.1f}°\n"
            f"inliers {r['inlier_ratio']:.2f}, runner-up {r['runner_up_ratio']:.2f}, "
            f"{int(r['n_local_segments'])} local segments",
            fontsize=9,
        )
    axes.ravel()[0].legend(loc="lower left", fontsize=8)
    fig.suptitle(f"{name}: wrong answers (> {SUCCESS_M * 100:.0f} cm or > {SUCCESS_DEG:g}°)")
    fig.tight_layout()
    FIGURES.mkdir(parents=True, exist_ok=True)
    fig.savefig(FIGURES / f"{name}-failures.png", dpi=80)
    plt.close(fig)


def tracking(
    name: str, split: HeldOutSplit, raw: RawLog, data: Path, work: Path, log: list[str]
) -> dict:
    """Protocol (b): the raw log ``raw`` tracked in the map of ``split`` from (0, 0, 0) at its
    start."""
    relations_name = DATASETS[name][2]
    from segloc_cli.io.mcap_log import read_log

    raw_log = read_log(raw.log_path)
    t0 = time.perf_counter()
    run_segloc(
        log,
        "localize",
        raw.log_path,
        "--map",
        split.map_path,
        "--track",
        "--initial",
        raw.first_pose_path,
        "--out",
        work / "track.csv",
    )
    elapsed = time.perf_counter() - t0
    proc = run_segloc(
        log,
        "evaluate",
        work / "track.csv",
        "--relations",
        data / name / relations_name,
        "--published",
        name,
        "--format",
        "json",
    )
    metric = json.loads(proc.stdout)
    est = read_estimates(work / "track.csv")
    counts = est["status"].value_counts().to_dict()

    result = {
        "scans": len(est),
        "statuses": counts,
        "relations": metric["summary"],
        "published": metric.get("published"),
        "median_ms": float(est["runtime_ms"].median()),
        "wall_s": elapsed,
        "polished": polished_tracking(split, raw, data / name / relations_name, work, log),
    }
    # Each reference pose against the estimate for the very same scan: the
    # corrected log's scans are found in the raw log by their readings. (On a
    # shifted clock the raw scan nearest in time is not always the same scan:
    # raw stamps come in bursts a millisecond apart.)
    ref = split.reference
    raw_index = same_scans(read_log(split.log_path).scans, raw_log.scans)
    found = raw_index >= 0
    row_of = rows_by_pose_id(est["pose_id"])
    rows = np.array([row_of.get(int(i) + 1, -1) for i in raw_index[found]])
    pos, head = distances(est.iloc[rows[rows >= 0]], ref.poses[found][rows >= 0])
    result.update(
        paired=int(pos.size),
        unpaired=int(len(ref) - pos.size),
        median_dist_m=float(np.median(pos)),
        p95_dist_m=float(np.percentile(pos, 95)),
        max_dist_m=float(pos.max()),
        over_1m=int(np.sum(pos > TRACK_LIMIT_M)),
        median_head_deg=float(np.median(head)),
        max_head_deg=float(head.max()),
        reference_check=reference_check(
            data / name / relations_name,
            np.array([raw_log.scans[i].time_s for i in raw_index[found]]),
            ref.poses[found],
            est,
        ),
    )
    return result


POLISH_ROUNDS = 2
"""Rounds of ``map build --polish`` for the polished-map track."""


def polished_tracking(split: HeldOutSplit, raw, relations: Path, work: Path, log: list) -> dict:
    """The track of protocol (b) again, in the map of ``split`` built with ``--polish``: its
    segment count and relation summary."""
    polished_map, out = work / "map-polished.json", work / "track-polished.csv"
    run_segloc(
        log, "map", "build", split.log_path, "--survey", work / "map_poses.csv", *OWN_SCAN_ONLY,
        "--polish", POLISH_ROUNDS, "--out", polished_map,
    )  # fmt: skip
    run_segloc(
        log, "localize", raw.log_path, "--map", polished_map, "--track",
        "--initial", raw.first_pose_path, "--out", out,
    )  # fmt: skip
    proc = run_segloc(log, "evaluate", out, "--relations", relations, "--format", "json")
    return {
        "segments": len(read_map(polished_map)),
        "map_segments": len(read_map(split.map_path)),
        "relations": json.loads(proc.stdout)["summary"],
    }


def reference_check(relations_path: Path, times_s: np.ndarray, poses: np.ndarray, est) -> dict:
    """The reference poses and segloc's tracked poses scored on the same relations.

    The perturbation protocol scores against the corrected log's poses; the
    relations are the datasets' ground truth for relative motion. Scoring the
    reference trajectory itself (``poses`` at the raw-log times ``times_s`` of
    the same scans) on the relations both of them reach tells how far a 1°
    success bound against the reference can be trusted.
    """
    from segloc_cli.io.relations import read_relations
    from segloc_cli.scoring.relations import relation_errors, trajectory_from_estimates

    relations = read_relations(relations_path)
    reference = relation_errors(times_s, poses, relations)
    tracked = relation_errors(*trajectory_from_estimates(est), relations)
    _, a, b = np.intersect1d(reference.index, tracked.index, return_indices=True)

    def summary(errors, rows) -> dict:
        rot = errors.rot_deg[rows]
        return {
            "rot_mean_deg": float(np.mean(rot)) if rot.size else float("nan"),
            "rot_over_1deg": float(np.mean(rot > SUCCESS_DEG)) if rot.size else float("nan"),
            "trans_mean_m": float(np.mean(errors.trans_m[rows])) if rot.size else float("nan"),
        }

    return {
        "relations": int(a.size),
        "reference": summary(reference, a),
        "segloc": summary(tracked, b),
    }


VERDICT_HEADER = (
    "right | right and ok | silent | silent, gross | wrong flagged | gross flagged | right flagged"
)
VERDICT_KEYS = (
    "success",
    "success_ok",
    "silent",
    "silent_gross",
    "wrong_flagged",
    "gross_flagged",
    "right_flagged",
)


def _verdict_cells(summary: dict) -> str:
    """The ``VERDICT_HEADER`` cells of one ``_scored`` summary, as percentages."""
    return " | ".join(percent(summary[key]) for key in VERDICT_KEYS)


CONVERGENCE_KEYS = ("success_place", "silent_place", "wrong_flagged_place", "right_flagged_place")
CONVERGENCE_TARGETS = ("≥ 99 %", "≤ 1 %", "≥ 95 %", "≤ 5 %")
"""What the verdict and the search aim at in the convergence view, in ``CONVERGENCE_KEYS``
order."""


def convergence_section(results: dict) -> list[str]:
    """The convergence view of both protocols: right = within ``PLACE_M`` and ``PLACE_DEG``
    of the reference, beside the targets, from the same runs as the tables above."""
    lines = [
        "",
        f"## Convergence view: right = within {PLACE_M * 100:.0f} cm and {PLACE_DEG:g}°",
        "",
        "The same runs scored with a bound the reference poses can support: they are SLAM "
        "output and miss the datasets' ground-truth relations by more than 1° on 24–38 % of "
        "them (see *How exact are the reference poses?*), so within 10 cm and 1° counts some "
        "right answers as wrong. Silent: beyond the bound yet ok. Wrong flagged: the share of "
        "answers beyond the bound whose status is not ok; right flagged: of those within it. "
        f"Truth listed: of the global runs' ambiguous answers, the share among whose {LISTED} "
        "listed hypotheses (`--hypotheses`) one is within the bound.",
        "",
        "| dataset | protocol | right | silent | wrong flagged | right flagged | truth listed |",
        "|---|---|---:|---:|---:|---:|---:|",
        "| target | | " + " | ".join(CONVERGENCE_TARGETS) + " | 100 % |",
    ]
    for name, r in results.items():
        for protocol, key in (("perturbation", "perturbation"), ("global", "global")):
            if r.get(key) is None:
                continue
            cells = " | ".join(percent(r[key][k]) for k in CONVERGENCE_KEYS)
            listed = r[key].get("truth_listed")
            shown = "" if listed is None else f"{percent(listed)} of {r[key]['ambiguous']}"
            lines.append(f"| {name} | {protocol} | {cells} | {shown} |")
    return lines


def verdict_trials(
    name: str, protocol: str, mode: str, est: pd.DataFrame, truth: PoseTable
) -> pd.DataFrame:
    """Each estimate row's confidence and whether it found the right place, under its
    dataset, protocol and mode (``single scan`` or ``window``)."""
    pos, head = errors_against_truth(est, truth)
    return pd.DataFrame(
        {
            "dataset": name,
            "protocol": protocol,
            "mode": mode,
            "confidence": est["confidence"].to_numpy(dtype=float),
            "right": is_right_place(pos, head),
        }
    )


RELIABILITY_FIGURE = FIGURES / "reliability.png"


def reliability_figure(trials: pd.DataFrame) -> None:
    """Observed share right against the confidence, per bin and protocol, with the diagonal
    a calibrated confidence lies on."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    modes = list(dict.fromkeys(trials["mode"]))
    fig, axes = plt.subplots(1, len(modes), figsize=(5.5 * len(modes), 5), squeeze=False)
    for ax, (mode, of_mode) in zip(axes[0], trials.groupby("mode", sort=False), strict=True):
        ax.plot([0, 1], [0, 1], color="0.6", lw=1, label="calibrated")
        for (protocol, group), marker in zip(of_mode.groupby("protocol"), "osD^", strict=False):
            rows = reliability_rows(group["confidence"].to_numpy(), group["right"].to_numpy())
            shown = [(float(r[2]), float(r[3]), int(r[1])) for r in rows if r[2] != "—"]
            x, y, n = (np.array(v) for v in zip(*shown, strict=True))
            ax.scatter(x, y, s=20 + 200 * n / n.max(), marker=marker, alpha=0.7, label=protocol)
        ax.set_xlabel("confidence (mean of the bin)")
        ax.set_ylabel(f"share right (within {PLACE_M * 100:.0f} cm and {PLACE_DEG:g}°)")
        ax.set_xlim(0, 1.02)
        ax.set_ylim(0, 1.02)
        ax.legend(loc="lower right", fontsize=8)
        ax.set_title(f"{mode}: reliability (marker area: trials)")
    fig.tight_layout()
    FIGURES.mkdir(parents=True, exist_ok=True)
    fig.savefig(RELIABILITY_FIGURE, dpi=80)
    plt.close(fig)


def verdict_section(trials: pd.DataFrame) -> list[str]:
    """How the confidence bears out on the trials above: a reliability table per protocol,
    pooled over the datasets, and its figure."""
    lines = [
        "",
        "## The confidence column",
        "",
        "Each row's `confidence` is the probability the verdict's model gives that the answer "
        "is the right place; it was fitted by `make calibrate` on other trials (see "
        "[results-calibration.md](results-calibration.md)), none of them scored here. Where "
        "the confidence is calibrated, the share right in each bin equals the bin's mean "
        "confidence (the diagonal of the figure); above it, the confidence is cautious, "
        f"below it, rash. Right: within {PLACE_M * 100:.0f} cm and {PLACE_DEG:g}° of the "
        f"reference. Figure: [reliability](figures/{RELIABILITY_FIGURE.name}).",
    ]
    for (mode, protocol), group in trials.groupby(["mode", "protocol"], sort=False):
        rows = reliability_rows(group["confidence"].to_numpy(), group["right"].to_numpy())
        lines += [
            "",
            f"**{mode}, {protocol}** ({len(group)} trials, {group['right'].mean():.1%} right)",
            "",
            "| confidence | trials | mean confidence | share right |",
            "|---|---:|---:|---:|",
            *("| " + " | ".join(row) + " |" for row in rows),
        ]
    return lines


def report(results: dict, commands: dict, trials: pd.DataFrame | None = None) -> str:
    """The markdown report: a table per protocol, the reference check, every command."""
    lines = [
        "# segloc on real logs",
        "",
        "Generated by `make bench-real` (`benchmarks/real_logs.py`); data: the Radish logs as "
        "used by Kümmerle et al., On measuring the accuracy of SLAM algorithms, Autonomous "
        "Robots 27(4), 2009. Default settings throughout.",
        "",
        "## (a) Perturbation protocol",
        "",
        f"Map from the corrected log's scans at their poses, leaving out every "
        f"{HOLD_OUT_EVERY}th; each left-out scan localized from its reference pose plus uniform "
        f"errors in ±{PERTURB_XY_M} m, ±{PERTURB_XY_M} m, ±{PERTURB_THETA_DEG:g}° "
        f"(seed {PERTURB_SEED}), alone (`--window-m 0`: in the corrected log a held-out "
        "scan's neighbours are scans of the map; the windows are in *Single scan and window* "
        "below). "
        f"Right: within {SUCCESS_M * 100:.0f} cm and {SUCCESS_DEG:g}° of the reference pose, "
        "whatever the status. Silent: wrong but status ok. Flagged: status not ok (ambiguous, "
        "lost, too few segments). Gross: beyond 30 cm or 3°. Stage 2: the stage-2 pose of "
        "the same runs, the paper's method. Reference fit: the share of left-out scans whose "
        "refinement started at their own reference pose stays right, a ceiling for any method "
        "scored against these references (the map and the references do not agree exactly).",
        "",
        "| dataset | scans | held out | map segments | local segments (median) | "
        + VERDICT_HEADER
        + " | median pos (cm) | median θ (°) | ms/scan | stage 2: right "
        "| stage 2: median pos (cm) | reference fit |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]

    for name, r in results.items():
        a = r["perturbation"]
        lines.append(
            f"| {name} | {a['scans']} | {a['held_out']} | {a['map_segments']} | "
            f"{a['median_local_segments']:.0f} | {_verdict_cells(a)} | "
            f"{a['median_pos_m'] * 100:.1f} | {a['median_head_deg']:.2f} | "
            f"{a['median_ms']:.1f} | {percent(a['success_stage2'])} | "
            f"{a['median_pos_stage2_m'] * 100:.1f} | {percent(a['reference_fit'])} |"
        )
    lines += [
        "",
        "Figures of the first wrong answers per dataset (map grey, the scan placed at the "
        "reference pose green and at segloc's answer red): "
        + ", ".join(f"[{n}](figures/{n}-failures.png)" for n in results),
        "",
        "## Global localization",
        "",
        "The same left-out scans localized with `--global`: no initial pose, the whole map "
        "searched. Same columns as above.",
        "",
        "| dataset | " + VERDICT_HEADER + " | statuses | ms/scan |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---|---:|",
    ]
    for name, r in results.items():
        g = r.get("global")
        if g is None:
            continue
        statuses = ", ".join(f"{n} {s}" for s, n in sorted(g["statuses"].items()))
        lines.append(f"| {name} | {_verdict_cells(g)} | {statuses} | {g['median_ms']:.0f} |")
    lines += convergence_section(results)
    lines += odometry_section(results)
    tracked = {n: r["tracking"]["relations"] for n, r in results.items() if r.get("tracking")}
    tracked = {n: {"trans_m": t["trans_m"], "rot_deg": t["rot_deg"]} for n, t in tracked.items()}
    measured = {n: r["precision"] for n, r in results.items() if r.get("precision")}
    if measured:
        lines += ["", *precision_section(measured, tracked or None)]
    if trials is not None and len(trials):
        lines += verdict_section(trials)
    lines += [
        "",
        "## (b) Tracking protocol",
        "",
        "The raw log tracked with `--track` against the map of (a), seeded with (0, 0, 0) at its "
        "first scan. The relation metric counts every relation whose two times have an "
        "estimate, whatever its status (a lost scan carries its dead-reckoning pose). The "
        "distance columns compare, for every scan of the "
        "corrected log (found in the raw log by its identical readings), the tracked pose with "
        "the reference pose; a lost scan counts with the dead-reckoning pose it carries. "
        "segloc tracks in a map built from the corrected log, a prior that the SLAM systems "
        "behind the published figures did not have: those are there for scale, not as a "
        "like-for-like comparison.",
        "",
        "| dataset | scans | statuses | relations used | trans. error (m) | rot. error (°) "
        "| published (m) | published (°) | reference scans | median dist. (cm) "
        "| p95 dist. (cm) | max dist. (m) | > 1 m | max θ error (°) | ms/scan |",
        "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, r in results.items():
        b = r.get("tracking")
        if b is None:
            continue
        rel = b["relations"]
        pub = (b.get("published") or {}).get("GraphMapping", {})

        def pm(d, key, digits):
            return mean_sd(d.get(key), digits)

        statuses = ", ".join(f"{n} {s}" for s, n in sorted(b["statuses"].items()))
        lines.append(
            f"| {name} | {b['scans']} | {statuses} | {rel['used']} | {pm(rel, 'trans_m', 3)} | "
            f"{pm(rel, 'rot_deg', 2)} | {pm(pub, 'trans_m', 3)} | {pm(pub, 'rot_deg', 2)} | "
            f"{b['paired']} of {b['paired'] + b['unpaired']} | {b['median_dist_m'] * 100:.1f} | "
            f"{b['p95_dist_m'] * 100:.1f} | {b['max_dist_m']:.2f} | {b['over_1m']} | "
            f"{b['max_head_deg']:.1f} | {b['median_ms']:.1f} |"
        )
    lines += [
        "",
        f"**In a polished map** (`map build --polish {POLISH_ROUNDS}`: before fusing, each "
        "mapping scan is fitted to the map the other half of the scans make, so that the "
        "corrected log's pose errors blur the walls less), the same track:",
        "",
        "| dataset | map segments | polished map segments | trans. error (m) | rot. error (°) "
        "| Cartographer (m) | Cartographer (°) |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name, r in results.items():
        polished = (r.get("tracking") or {}).get("polished")
        if polished is None:
            continue
        rel = polished["relations"]
        carto = CARTOGRAPHER.get(name, ("—", "—"))
        lines.append(
            f"| {name} | {polished['map_segments']} | {polished['segments']} | "
            f"{mean_sd(rel['trans_m'], 3)} | {mean_sd(rel['rot_deg'], 2)} | "
            f"{carto[0]} | {carto[1]} |"
        )
    lines += [
        "",
        "## How exact are the reference poses?",
        "",
        "The perturbation protocol scores against the corrected log's poses. The relations "
        "files are the datasets' ground truth for relative motion, so the corrected log's own "
        "poses (at the raw-log times of the same scans) can be scored on them, next to "
        "segloc's tracked poses on the very same relations. Where the reference misses the "
        f"relations by more than {SUCCESS_DEG:g}° often, a {SUCCESS_DEG:g}° success bound "
        "against it counts some right answers as wrong.",
        "",
        "| dataset | relations both reach | reference: rot. error (°) | reference: share "
        f"> {SUCCESS_DEG:g}° | reference: trans. error (m) | segloc: rot. error (°) | "
        f"segloc: share > {SUCCESS_DEG:g}° | segloc: trans. error (m) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, r in results.items():
        c = (r.get("tracking") or {}).get("reference_check")
        if c is None:
            continue
        ref, ours = c["reference"], c["segloc"]
        lines.append(
            f"| {name} | {c['relations']} | {ref['rot_mean_deg']:.2f} | "
            f"{percent(ref['rot_over_1deg'])} | {ref['trans_mean_m']:.3f} | "
            f"{ours['rot_mean_deg']:.2f} | {percent(ours['rot_over_1deg'])} | "
            f"{ours['trans_mean_m']:.3f} |"
        )
    lines += ["", *commands_section(commands)]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = log_arguments(__doc__, "out/real", "benchmarks/results-real.md")
    parser.add_argument("--no-tracking", action="store_true")
    args = parser.parse_args()
    results, commands, trials = {}, {}, []
    for name in chosen_logs(args.only):
        work = args.work / name
        work.mkdir(parents=True, exist_ok=True)
        log: list[str] = []
        print(f"{name}: perturbation protocol", flush=True)
        split = prepare_held_out(name, args.datasets, work, log)
        results[name] = {"perturbation": perturbation(name, split, work, log)}
        print(f"  {json.dumps(results[name]['perturbation'])}", flush=True)
        print(f"{name}: global localization", flush=True)
        results[name]["global"] = global_localization(split, work, log)
        print(f"  {json.dumps(results[name]['global'])}", flush=True)
        truth = split.held_out_reference()
        for protocol, table in (("perturbation", "perturb.csv"), ("global", "global.csv")):
            est = read_estimates(work / table)
            trials.append(
                verdict_trials(name, f"{protocol}, corrected log", "single scan", est, truth)
            )
        raw = prepare_raw_log(name, args.datasets, work, log)
        print(f"{name}: single scan and window on the raw log", flush=True)
        results[name]["odometry"] = odometry_protocol(name, split, raw, work, log, trials)
        print(f"  {json.dumps(results[name]['odometry'])}", flush=True)
        if not args.no_tracking:
            print(f"{name}: tracking protocol", flush=True)
            results[name]["tracking"] = tracking(name, split, raw, args.datasets, work, log)
            print(f"  {json.dumps(results[name]['tracking'], default=str)}", flush=True)
        print(f"{name}: precision protocol", flush=True)
        logs = ImportedLogs(split.log_path, work / "reference.csv", raw)
        precision_work = work / "precision"
        results[name]["precision"] = precision(name, args.datasets, precision_work, log, logs)
        print(f"  {json.dumps(results[name]['precision'], default=str)}", flush=True)
        commands[name] = log
    verdict = pd.concat(trials, ignore_index=True)
    reliability_figure(verdict)
    args.out.write_text(report(results, commands, verdict), encoding="utf-8")
    (args.work / "results.json").write_text(json.dumps(results, indent=2, default=str))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
