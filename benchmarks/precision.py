"""Precision protocol: segloc's single-scan answers scored on the datasets' ground-truth relations.

For each dataset, through the command line exactly as a user would run it:

(c) Precision protocol. The relations files (``t1 t2 dx dy dz roll pitch yaw``, times on the
    raw log's clock, motion in the frame of the pose at t1) are the datasets' ground truth.
    The relations whose two ends are both scans of the SLAM-corrected log are kept; the
    corrected log's scans are placed on the relations' clock by finding each of them in the
    raw log by its identical readings (``protocol.same_scans``). Every end scan of those
    relations is held out of the map, which is built from the corrected log's other scans at
    their reference poses; each end scan is localized on its own from its reference pose plus
    uniform errors in ±1.5 m, ±1.5 m, ±20° (seeded, ``protocol.perturbed_guesses``), and the
    answers are scored on the kept relations with the relation metric of ``segloc evaluate
    --relations`` (Kümmerle et al. 2009), next to the published graph-mapping figures.

Unlike the perturbation protocol of ``real_logs.py``, nothing here is scored against the
corrected log's poses: they only place the map's scans and seed the guesses.

Usage: python benchmarks/precision.py [--datasets DIR] [--only intel,aces] [--work DIR]
       [--tracking out/real/results.json]
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from protocol import (
    DATASETS,
    DATASETS_DIR,
    HELD_OUT_ALONE,
    OWN_SCAN_ONLY,
    PERTURB_SEED,
    PERTURB_THETA_DEG,
    PERTURB_XY_M,
    RawLog,
    map_without,
    mean_sd,
    percent,
    perturbed_guesses,
    prepare_raw_log,
    run_segloc,
    same_scans,
    subset_poses,
)

from segloc_cli.estimates import PoseTable, Relations
from segloc_cli.io.maps import read_map
from segloc_cli.io.mcap_log import read_log
from segloc_cli.io.relations import read_relations
from segloc_cli.io.tables import read_estimates, read_pose_table, write_pose_table
from segloc_cli.scoring.relations import PUBLISHED, published_json
from segloc_cli.timing import nearest_by_time

SAME_TIME_S = 1e-3
"""A relation's time names the raw-log scan nearest it within this (seconds). The relations'
times are the raw scans' own (within 0.2 µs in the bags, 5 µs in mit-csail's .clf, which
prints fewer digits), so the bound only absorbs printing. Intel's bag stamps its scans in
bursts microseconds apart, so the nearest scan is taken, never any scan within the bound."""

NEAR_S = 0.05
"""The default pairing tolerance of ``segloc evaluate`` (seconds), used only to count the
relations that a pairing by time alone would have let in (``relations_within_50ms``)."""


# --- the split: relation end scans out of the map ---------------------------------


@dataclass(frozen=True)
class RelationSplit:
    """A corrected log imported as ``log_path``, its map built without the relation end scans.

    ``reference`` holds every corrected scan's reference pose (world frame, metres and
    radians), row k for scan k of ``log_path``; ``relation_time_s`` (N,) the time of the same
    scan on the relations' (raw log's) clock, NaN for a scan not found in the raw log;
    ``held_out`` (N,) bool marks the end scans, left out of the map at ``map_path``.
    ``ends`` (R, 2) holds, for each relation of ``relations``, the corrected scans at its
    t1 and t2 (−1 where that time is no corrected scan); ``kept`` (R,) bool the relations
    whose two ends are both corrected scans, written alone to ``relations_path``.
    """

    log_path: Path
    map_path: Path
    reference: PoseTable
    relation_time_s: np.ndarray
    held_out: np.ndarray
    relations: Relations
    ends: np.ndarray
    kept: np.ndarray
    relations_path: Path
    raw_scans: int


def relation_ends(
    relations: Relations, raw_index: np.ndarray, raw_times_s: np.ndarray
) -> np.ndarray:
    """(R, 2) int64: the corrected scan at each relation's t1 and t2, −1 where there is none.

    A relation time names the raw scan nearest it within ``SAME_TIME_S``; that end is a
    corrected scan only when the very same raw scan is one (``raw_index`` (N,) the raw scan
    of each corrected scan, −1 for none, as ``protocol.same_scans`` gives it; ``raw_times_s``
    (M,) every raw scan's time, seconds). A corrected scan merely close in time is a
    different scan.
    """
    scan_of_raw = np.full(len(raw_times_s), -1, dtype=np.int64)
    found = raw_index >= 0
    scan_of_raw[raw_index[found]] = np.flatnonzero(found)
    ends = np.full((len(relations), 2), -1, dtype=np.int64)
    for column, times in enumerate((relations.t1_s, relations.t2_s)):
        raw = nearest_by_time(times, raw_times_s, SAME_TIME_S)
        ends[raw >= 0, column] = scan_of_raw[raw[raw >= 0]]
    return ends


def write_relations_subset(source: Path, kept: np.ndarray, out: Path) -> None:
    """Copy the relation lines of ``source`` where ``kept`` ((R,) bool, one per relation in
    file order, as ``read_relations`` reads them) holds, verbatim, to ``out``."""
    lines = [
        line
        for line in source.read_text(encoding="utf-8-sig").splitlines()
        if line.split("#", 1)[0].strip()
    ]
    if len(lines) != len(kept):
        raise ValueError(f"{source}: {len(lines)} relation lines, expected {len(kept)}")
    out.write_text("".join(line + "\n" for line, keep in zip(lines, kept, strict=True) if keep))


@dataclass(frozen=True)
class ImportedLogs:
    """A dataset's corrected log, imported as ``log_path`` with its reference poses at
    ``reference_path``, and its raw log."""

    log_path: Path
    reference_path: Path
    raw: RawLog


def import_logs(name: str, datasets: Path, work: Path, commands: list[str]) -> ImportedLogs:
    """Import dataset ``name``'s corrected and raw logs into ``work``; the commands run are
    appended to ``commands``."""
    log_path, reference_path = work / "corrected.mcap", work / "reference.csv"
    run_segloc(
        commands, "import", "carmen", datasets / name / DATASETS[name][0], "--out", log_path,
        "--survey-out", reference_path,
    )  # fmt: skip
    return ImportedLogs(log_path, reference_path, prepare_raw_log(name, datasets, work, commands))


def prepare_relation_split(
    name: str, datasets: Path, work: Path, commands: list[str], logs: ImportedLogs
) -> RelationSplit:
    """Choose the relations of dataset ``name`` whose two ends are scans of its corrected log
    (``logs``) and build the map in ``work`` without those end scans; the commands run are
    appended to ``commands``.

    The map is built as ``protocol.map_without`` builds the other benchmarks' maps.
    """
    relations_source = datasets / name / DATASETS[name][2]
    log_path, reference_path, raw = logs.log_path, logs.reference_path, logs.raw
    corrected_scans = read_log(log_path).scans
    raw_scans = read_log(raw.log_path).scans
    reference = read_pose_table(reference_path)
    scan_times = np.array([s.time_s for s in corrected_scans], dtype=float)
    if len(reference) != len(scan_times) or not np.allclose(
        reference.time_s, scan_times, rtol=0, atol=1e-6
    ):
        raise SystemExit(f"{reference_path}: the reference poses are not the log's scans")

    # Each corrected scan on the relations' clock: the time of the same scan in the raw log.
    raw_index = same_scans(corrected_scans, raw_scans)
    raw_times = np.array([s.time_s for s in raw_scans], dtype=float)
    rel_time = np.where(raw_index >= 0, raw_times[np.maximum(raw_index, 0)], np.nan)
    relations = read_relations(relations_source)
    ends = relation_ends(relations, raw_index, raw_times)
    kept = np.all(ends >= 0, axis=1)
    held_out = np.zeros(len(reference), dtype=bool)
    held_out[ends[kept].ravel()] = True

    commands.append(
        f"# {DATASETS[name][2]} → end_relations.relations: the relations whose two times are "
        f"scans of {log_path.name} (found in {raw.log_path.name} by identical readings); "
        "map_poses.csv, end_scans.csv: the other scans and those end scans, at their reference "
        f"poses; written by {Path(sys.argv[0]).name}"
    )
    relations_path = work / "end_relations.relations"
    write_relations_subset(relations_source, kept, relations_path)
    map_path, _ = map_without(log_path, reference, held_out, work, commands, "end_scans.csv")
    return RelationSplit(
        log_path, map_path, reference, rel_time, held_out, relations, ends, kept,
        relations_path, len(raw_scans),
    )  # fmt: skip


def within(relations: Relations, times_s: np.ndarray, tolerance_s: float) -> int:
    """How many relations have both times within ``tolerance_s`` (s) of one of ``times_s``."""
    times_s = times_s[np.isfinite(times_s)]
    first = nearest_by_time(relations.t1_s, times_s, tolerance_s)
    second = nearest_by_time(relations.t2_s, times_s, tolerance_s)
    return int(np.sum((first >= 0) & (second >= 0)))


# --- localizing and scoring -------------------------------------------------------


def write_on_relation_clock(estimates_path: Path, split: RelationSplit, out: Path) -> pd.DataFrame:
    """Copy the estimates CSV at ``estimates_path`` to ``out`` with each row's ``time_s``
    replaced by its scan's time on the relations' clock (seconds, the raw log's), so that
    ``segloc evaluate --relations`` pairs them; every other field is copied verbatim.

    Rows are found by ``pose_id``, the reference row's id the guess carried. Returns the
    estimates as ``read_estimates`` reads ``out``.
    """
    time_of_id = {
        int(pid): float(t)
        for pid, t in zip(split.reference.pose_id, split.relation_time_s, strict=True)
    }
    with estimates_path.open(newline="", encoding="utf-8") as source:
        rows = list(csv.reader(source))
    header = rows[0]
    time_col, id_col = header.index("time_s"), header.index("pose_id")
    for row in rows[1:]:
        row[time_col] = repr(time_of_id[int(row[id_col])])
    with out.open("w", newline="", encoding="utf-8") as target:
        csv.writer(target, lineterminator="\n").writerows(rows)
    return read_estimates(out)


def _evaluate(commands: list[str], estimates: Path, relations: Path, *options: str) -> dict:
    """``segloc evaluate ESTIMATES --relations RELATIONS`` as JSON: its ``summary`` (and
    ``published`` when ``options`` ask for it)."""
    proc = run_segloc(
        commands, "evaluate", estimates, "--relations", relations, *OWN_SCAN_ONLY, *options,
        "--format", "json",
    )  # fmt: skip
    return json.loads(proc.stdout)


def _both_ends(relations: Relations, est: pd.DataFrame, mask: np.ndarray) -> int:
    """How many relations have rows of ``est`` (times on the relations' clock) where ``mask``
    holds at both of their times (within ``SAME_TIME_S``)."""
    times = est["time_s"].to_numpy(dtype=float)[mask]
    return within(relations, times, SAME_TIME_S)


def precision(
    name: str, datasets: Path, work: Path, commands: list[str], logs: ImportedLogs | None = None
) -> dict:
    """The precision protocol for dataset ``name`` (see the module docstring), in ``work``.

    ``datasets`` holds a folder per dataset (``protocol.DATASETS``); ``logs`` are its logs as
    already imported (imported into ``work`` when None); the commands run are appended to
    ``commands``. Returns a JSON-able dict: counts of relations (in the file;
    ``relations_available`` with both ends corrected scans; ``relations_used`` scored),
    ``end_scans`` held out and ``map_scans``; the relation errors of all the answers,
    whatever their status, ``trans_mean_m``/``trans_std_m`` (metres) and
    ``rot_mean_deg``/``rot_std_deg`` (degrees, sample std), with the full ``relations``
    summary of ``segloc evaluate``; ``only_ok``, the same on the answers with status ok
    (None when no relation has two); ``reference``, the same for the end scans' reference
    poses (``reference_on_relations``); ``ok_share`` (0–1), ``statuses``, ``median_ms`` per
    scan, ``wall_s`` (seconds, the localize command; ``total_wall_s`` the whole protocol)
    and ``published``: {method: {"trans_m"|"rot_deg": {"mean", "std"}}}.
    """
    start = time.perf_counter()
    work.mkdir(parents=True, exist_ok=True)
    logs = logs or import_logs(name, datasets, work, commands)
    split = prepare_relation_split(name, datasets, work, commands, logs)
    truth = subset_poses(split.reference, split.held_out)
    commands.append(
        f"# guesses.csv: end scans' reference + uniform errors (±{PERTURB_XY_M} m, "
        f"±{PERTURB_THETA_DEG:g}°), seed {PERTURB_SEED}"
    )
    guesses_path, estimates_path = work / "guesses.csv", work / "estimates.csv"
    write_pose_table(guesses_path, perturbed_guesses(truth))
    t0 = time.perf_counter()
    run_segloc(
        commands, "localize", split.log_path, "--map", split.map_path, *HELD_OUT_ALONE,
        "--initial", guesses_path, "--out", estimates_path,
    )  # fmt: skip
    wall_s = time.perf_counter() - t0

    commands.append(
        "# estimates_relation_clock.csv: estimates.csv with time_s on the relations' clock "
        f"(the raw-log time of each scan), written by {Path(sys.argv[0]).name}"
    )
    on_clock_path = work / "estimates_relation_clock.csv"
    est = write_on_relation_clock(estimates_path, split, on_clock_path)
    relations = read_relations(split.relations_path)
    ok = (est["status"] == "ok").to_numpy()
    finite = np.isfinite(est[["x_m", "y_m", "theta_deg"]].to_numpy(dtype=float)).all(axis=1)

    metric: dict = {"summary": None, "published": None}
    if _both_ends(relations, est, finite):
        metric = _evaluate(commands, on_clock_path, split.relations_path, "--published", name)
    only_ok = None
    if _both_ends(relations, est, ok & finite):
        only_ok = _evaluate(commands, on_clock_path, split.relations_path, "--only-ok")
        only_ok = {"used": only_ok["summary"]["used"], **_flat(only_ok["summary"])}

    summary = metric["summary"]
    reference = reference_on_relations(split, relations)
    return {
        "dataset": name,
        "scans": len(split.reference),
        "raw_scans": split.raw_scans,
        "scans_found_in_raw": int(np.isfinite(split.relation_time_s).sum()),
        "relations_total": len(split.relations),
        "relations_available": int(split.kept.sum()),
        "relations_within_50ms": within(split.relations, split.relation_time_s, NEAR_S),
        "relations_used": 0 if summary is None else summary["used"],
        "end_scans": int(split.held_out.sum()),
        "map_scans": int((~split.held_out).sum()),
        "map_segments": len(read_map(split.map_path)),
        **_flat(summary),
        "relations": summary,
        "only_ok": only_ok,
        "reference": reference,
        "localized": len(est),
        "ok_share": float(ok.mean()) if len(est) else math.nan,
        "statuses": {str(k): int(v) for k, v in est["status"].value_counts().items()},
        "median_ms": float(est["runtime_ms"].median()),
        "wall_s": wall_s,
        "total_wall_s": time.perf_counter() - start,
        # None of a dataset's relations scored, evaluate did not run: the figures still show.
        "published": metric.get("published") or published_json(PUBLISHED.get(name, {})) or None,
    }


def reference_on_relations(split: RelationSplit, relations: Relations) -> dict:
    """The corrected log's own reference poses of the end scans scored on ``relations`` (the
    kept ones), as a check of what the map's poses themselves miss: {"used", "trans_mean_m",
    "trans_std_m" (m), "rot_mean_deg", "rot_std_deg" (°)}."""
    from segloc_cli.scoring.relations import relation_errors

    rows = np.flatnonzero(split.held_out)
    errors = relation_errors(
        split.relation_time_s[rows], split.reference.poses[rows], relations, SAME_TIME_S
    )
    return {"used": errors.used, **_flat(errors.summary())}


def _flat(summary: dict | None) -> dict:
    """The headline figures of a ``segloc evaluate --relations`` JSON summary (NaN for None):
    translation (m) and rotation (°) error mean and sample std."""
    s = summary or {}

    def get(error: str, stat: str) -> float:
        value = (s.get(error) or {}).get(stat)
        return math.nan if value is None else float(value)

    return {
        "trans_mean_m": get("trans_m", "mean"),
        "trans_std_m": get("trans_m", "std"),
        "rot_mean_deg": get("rot_deg", "mean"),
        "rot_std_deg": get("rot_deg", "std"),
    }


# --- the report -------------------------------------------------------------------


def _error_cells(figures: dict | None, with_used: bool) -> list[str]:
    """Cells of a ``_flat``-shaped dict (plus "used"): [relations used,] translation (m) and
    rotation (°) error mean ± std; dashes for None."""
    f = figures or {}
    used = [str(f.get("used", 0))] if with_used else []
    return [
        *used,
        mean_sd({"mean": f.get("trans_mean_m"), "std": f.get("trans_std_m")}, 3),
        mean_sd({"mean": f.get("rot_mean_deg"), "std": f.get("rot_std_deg")}, 2),
    ]


def precision_section(
    results: dict[str, dict], tracking: dict[str, dict] | None = None
) -> list[str]:
    """Markdown lines of the section "(c) Precision protocol": a paragraph on the protocol
    and a row per dataset of ``results`` (``precision``'s dicts).

    ``tracking``, when given, is {name: {"trans_m": ..., "rot_deg": ...}}, each a
    {"mean", "std"} dict, a (mean, std) pair or a mean (metres, degrees): segloc's
    tracking-protocol figures, shown beside the precision figures.
    """
    lines = [
        "## (c) Precision protocol",
        "",
        "The datasets' ground-truth relations scored on single-scan answers. The relations "
        "whose two times are both scans of the corrected log are kept (the corrected log's "
        "scans are placed on the relations' clock by finding each in the raw log by its "
        "identical readings; a corrected scan merely close in time to a relation's is a "
        "different scan and does not count). Every end scan of those relations is left out of "
        "the map, which is built from the corrected log's other scans at their reference poses; "
        "each end scan is localized on its own, from its reference pose plus uniform errors in "
        f"±{PERTURB_XY_M} m, ±{PERTURB_XY_M} m, ±{PERTURB_THETA_DEG:g}° (seed {PERTURB_SEED}), "
        "and the answers, whatever their status, are scored on the kept relations with the "
        "relation metric of Kümmerle et al. (2009): the error of the relative motion between "
        "the two answers, mean ± standard deviation over the relations. No answer is scored "
        "against the corrected log's poses. Ok only: the same, on the relations whose two "
        "answers both have status ok. Reference: the corrected log's own poses of the end "
        "scans scored on the same relations; the map is built at poses of that solution, so "
        "its errors are in every answer too. The relations reach few corrected scans on some "
        "logs, so those rows rest on a handful of relations. The published figures are graph "
        "SLAM over whole runs with no map given, scored on every relation; they are there for "
        "scale, not as a like-for-like comparison."
        + (
            " Tracking: the tracking protocol (b) on all of the dataset's relations."
            if tracking
            else ""
        ),
        "",
    ]
    header = (
        "| dataset | relations used | end scans | map scans | status ok | trans. error (m) "
        "| rot. error (°) | ok only: relations | ok only: trans. (m) | ok only: rot. (°) "
        "| reference: trans. (m) | reference: rot. (°) | published (m) | published (°) |"
    )
    rule = "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    if tracking:
        header += " tracking (m) | tracking (°) |"
        rule += "---:|---:|"
    lines += [header + " ms/scan |", rule + "---:|"]
    for name, r in results.items():
        pub = (r.get("published") or {}).get("GraphMapping", {})
        cells = [
            name,
            f"{r['relations_used']} of {r['relations_total']}",
            str(r["end_scans"]),
            str(r["map_scans"]),
            percent(r["ok_share"]),
            mean_sd({"mean": r["trans_mean_m"], "std": r["trans_std_m"]}, 3),
            mean_sd({"mean": r["rot_mean_deg"], "std": r["rot_std_deg"]}, 2),
            *_error_cells(r.get("only_ok"), with_used=True),
            *_error_cells(r.get("reference"), with_used=False),
            mean_sd(pub.get("trans_m"), 3),
            mean_sd(pub.get("rot_deg"), 2),
        ]
        if tracking:
            t = tracking.get(name) or {}
            cells += [mean_sd(t.get("trans_m"), 3), mean_sd(t.get("rot_deg"), 2)]
        cells.append(f"{r['median_ms']:.1f}")
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def tracking_figures(results_json: Path) -> dict[str, dict]:
    """The tracking protocol's relation figures from ``real_logs.py``'s ``results.json``:
    {name: {"trans_m": {"mean", "std"} (m), "rot_deg": {"mean", "std"} (°)}}."""
    results = json.loads(results_json.read_text(encoding="utf-8"))
    out = {}
    for name, r in results.items():
        rel = (r.get("tracking") or {}).get("relations")
        if rel:
            out[name] = {"trans_m": rel["trans_m"], "rot_deg": rel["rot_deg"]}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", type=Path, default=DATASETS_DIR)
    parser.add_argument("--only", default=",".join(DATASETS))
    parser.add_argument("--work", type=Path, default=Path("out/precision"))
    parser.add_argument(
        "--tracking",
        type=Path,
        default=None,
        help="results.json of real_logs.py, for the tracking protocol's figures",
    )
    args = parser.parse_args()
    results, commands = {}, {}
    for name in args.only.split(","):
        log: list[str] = []
        print(f"{name}: precision protocol", file=sys.stderr, flush=True)
        results[name] = precision(name, args.datasets, args.work / name, log)
        print(f"  {json.dumps(results[name])}", file=sys.stderr, flush=True)
        commands[name] = log
    tracking = None if args.tracking is None else tracking_figures(args.tracking)
    args.work.mkdir(parents=True, exist_ok=True)
    document = {"results": results, "commands": commands}
    (args.work / "results.json").write_text(json.dumps(document, indent=2), encoding="utf-8")
    print("\n".join(precision_section(results, tracking)))


if __name__ == "__main__":
    main()
