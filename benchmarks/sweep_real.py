"""Sweep benchmark (`make bench-sweep`): `segloc sweep` over the shared real logs.

Each log is split as in `real_logs.py`'s perturbation protocol (``prepare_held_out``: the
corrected log imported, the map built without every 10th scan, whose reference poses are
the survey). One spec holds the four logs, each with its own map and survey, the guesses
drawn uniformly in ±1.5 m, ±1.5 m, ±20° per seed (1, 2), and a grid of three search
windows (``search-half-width-m`` 1, 2, 3 m); the held-out scans are paired with their
poses within 1 ms (``OWN_SCAN_ONLY``). The sweep runs twice, on a local cluster of one
worker and of two, each into a fresh table: the report gives both wall times and their
ratio, says whether the two tables agree but for ``runtime_ms``, and scores each log ×
window from the table, misses included.

Usage: python benchmarks/sweep_real.py [--datasets DIR] [--only intel,fr079] [--work DIR]
       [--out FILE]
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from protocol import (
    HOLD_OUT_EVERY,
    OWN_SCAN_ONLY,
    PERTURB_THETA_DEG,
    PERTURB_XY_M,
    SUCCESS_DEG,
    SUCCESS_M,
    HeldOutSplit,
    MeasuredRun,
    chosen_logs,
    commands_section,
    log_arguments,
    percent,
    prepare_held_out,
    run_segloc_measured,
)

from segloc_cli.estimates import ESTIMATED
from segloc_cli.scoring.gates import Gates, failing_mask

GRID_KEY = "search-half-width-m"
HALF_WIDTHS_M = (1.0, 2.0, 3.0)
"""The grid: half side (m) of the square of positions searched around each guess."""
SEEDS = (1, 2)
INIT_ERRORS = f"uniform:{PERTURB_XY_M:g},{PERTURB_THETA_DEG:g}"
"""The guesses: each reference pose minus uniform errors, the perturbation protocol's bounds."""
JOBS = (1, 2)
"""Worker processes of the local cluster, one sweep each."""
SPEC_NAME = "sweep.toml"
TASK_FAILED = "task failed"
"""The status of a failed task's one row (``segloc_cli.estimates.STATUS_TASK_FAILED``)."""


@dataclass(frozen=True)
class SweptLog:
    """A dataset in the spec: its name, its label there (the log's path relative to the
    spec, as the table's ``log`` column names it) and its held-out scans."""

    name: str
    label: str
    held_out: int


def relative(path: Path) -> str:
    """``path`` as the report shows it: relative to the current folder, never absolute."""
    return os.path.relpath(path) if path.is_absolute() else str(path)


# --- the spec ----------------------------------------------------------------------


def spec_text(splits: dict[str, HeldOutSplit], folder: Path) -> str:
    """The sweep's spec (TOML) for the held-out splits of ``splits``, paths relative to
    ``folder`` (where it is written)."""

    def rel(path: Path) -> str:
        return Path(os.path.relpath(path, folder)).as_posix()

    option, value = OWN_SCAN_ONLY
    logs = [
        f'  {{path = "{rel(s.log_path)}", map = "{rel(s.map_path)}", '
        f'survey = "{rel(s.held_out_path)}"}},'
        for s in splits.values()
    ]
    return "\n".join(
        [
            "# Written by benchmarks/sweep_real.py: the held-out scans of each log in its own map.",
            f"{option.removeprefix('--')} = {value}   # each pose pairs with its own scan only",
            "window-m = 0   # alone: a held-out scan's neighbours are scans of the map",
            f'init-errors = "{INIT_ERRORS}"',
            f"seeds = [{', '.join(map(str, SEEDS))}]",
            "logs = [",
            *logs,
            "]",
            "",
            "[grid]",
            f"{GRID_KEY} = [{', '.join(map(str, HALF_WIDTHS_M))}]",
            "",
        ]
    )


def swept_logs(splits: dict[str, HeldOutSplit], folder: Path) -> list[SweptLog]:
    """Each split as the spec written in ``folder`` names it, with its held-out count."""
    return [
        SweptLog(name, Path(os.path.relpath(s.log_path, folder)).as_posix(), int(s.held_out.sum()))
        for name, s in splits.items()
    ]


# --- the runs ----------------------------------------------------------------------


@dataclass(frozen=True)
class SweepRun:
    """One sweep: its worker count, the command's run and the table it wrote."""

    jobs: int
    run: MeasuredRun
    table: pd.DataFrame


def run_sweep(spec: Path, jobs: int, work: Path, commands: list[str]) -> SweepRun:
    """``segloc sweep`` of ``spec`` on a local cluster of ``jobs`` workers, into a table of
    its own in ``work`` (replaced if there: ``--force``), timed."""
    out = work / f"results-jobs{jobs}.parquet"
    run = run_segloc_measured(commands, "sweep", spec, "--out", out, "--jobs", jobs)
    return SweepRun(jobs, run, pd.read_parquet(out))


def compare_tables(first: pd.DataFrame, second: pd.DataFrame) -> str | None:
    """None if the tables are identical but for ``runtime_ms``, else how they differ."""
    try:
        pd.testing.assert_frame_equal(
            first.drop(columns="runtime_ms"), second.drop(columns="runtime_ms")
        )
    except AssertionError as exc:
        return " ".join(str(exc).split())
    return None


# --- scoring the table -------------------------------------------------------------


def within_gates(rows: pd.DataFrame) -> np.ndarray:
    """(N,) bool: within ``SUCCESS_M`` and ``SUCCESS_DEG`` with an accepted status, by
    ``segloc evaluate``'s gate; no estimate fails."""
    return ~failing_mask(rows, Gates(axis_cm=SUCCESS_M * 100, deg=SUCCESS_DEG))


def padded_median(values: np.ndarray, expected: int) -> float:
    """Median of ``values`` with a miss (NaN, or a scan short of ``expected``) as infinite."""
    values = np.where(np.isfinite(values), values, np.inf)
    padded = np.concatenate([values, np.full(max(0, expected - values.size), np.inf)])
    return float(np.median(padded)) if padded.size else float("nan")


def scored(rows: pd.DataFrame, expected: int) -> dict:
    """The figures of one log × window (or pooled): ``expected`` scans (held out × seeds),
    a scan without a row or in a failed task counted a miss."""
    failed = rows["status"] == TASK_FAILED
    scans = rows[~failed]
    return {
        "expected": expected,
        "rows": len(scans),
        "failed_tasks": int(rows.loc[failed, "task"].nunique()),
        "within": int(within_gates(scans).sum()) / expected if expected else float("nan"),
        "no_estimate": int((~np.isfinite(scans["err_xy_cm"].to_numpy(float))).sum()),
        "not_accepted": int((~scans["status"].isin(ESTIMATED)).sum()),
        "median_cm": padded_median(scans["err_xy_cm"].to_numpy(float), expected),
        "median_deg": padded_median(np.abs(scans["err_theta_deg"].to_numpy(float)), expected),
        "median_ms": float(scans["runtime_ms"].median()) if len(scans) else float("nan"),
    }


def per_log(table: pd.DataFrame, logs: list[SweptLog]) -> list[tuple[str, float, dict]]:
    """(dataset, half width, figures) for each log × window, then each window pooled."""
    out = []
    for width in HALF_WIDTHS_M:
        of_width = table[table[GRID_KEY] == width]
        for log in logs:
            rows = of_width[of_width["log"] == log.label]
            out.append((log.name, width, scored(rows, log.held_out * len(SEEDS))))
    for width in HALF_WIDTHS_M:
        expected = sum(log.held_out for log in logs) * len(SEEDS)
        out.append(("all", width, scored(table[table[GRID_KEY] == width], expected)))
    return out


def pooled_agrees(table: pd.DataFrame, figures: list[tuple[str, float, dict]]) -> bool:
    """Whether the sweep's own summary of ``table`` gives each window the pooled share within
    the gates computed here (it scores the rows the table holds, so they agree only when no
    scan is missing)."""
    from segloc_cli.runs.sweep import summary

    theirs = summary(table, (GRID_KEY,), SUCCESS_M * 100, SUCCESS_DEG)
    ours = {width: f["within"] * 100 for name, width, f in figures if name == "all"}
    return all(
        np.isclose(row["within gates %"], ours[row[GRID_KEY]]) for _, row in theirs.iterrows()
    )


# --- the report --------------------------------------------------------------------


def _number(value: float, digits: int) -> str:
    """``value`` with ``digits`` decimals; ∞ for a median that is a miss, a dash for none."""
    if np.isnan(value):
        return "—"
    return "∞" if np.isinf(value) else f"{value:.{digits}f}"


def wall_time_section(runs: list[SweepRun], difference: str | None) -> list[str]:
    """The wall times of the first and last run, their ratio, and whether their tables
    agree; tasks and rows are the last run's."""
    base, other = runs[0], runs[-1]
    tasks = other.table["task"].nunique()
    lines = [
        "## Wall time",
        "",
        "Wall time of the whole command (start of the local cluster and reading the logs "
        "included); ratio: the first run's time over the second's.",
        "",
        f"| {base.jobs} worker | {other.jobs} workers | ratio | tasks | rows |",
        "|---:|---:|---:|---:|---:|",
        f"| {base.run.wall_s:.1f} s | {other.run.wall_s:.1f} s | "
        f"{base.run.wall_s / other.run.wall_s:.2f} | {tasks} | {len(other.table)} |",
        "",
    ]
    if difference is None:
        lines.append(
            f"The tables of the two runs are identical but for `runtime_ms` "
            f"(`pandas.testing.assert_frame_equal` after dropping it): {len(base.table)} rows each."
        )
    else:
        lines.append(f"**The tables of the two runs differ** (beyond `runtime_ms`): {difference}")
    return [*lines, ""]


def per_log_section(figures: list[tuple[str, float, dict]], agrees: bool) -> list[str]:
    """The table of each log × window (from the first run's Parquet)."""
    lines = [
        "## Per log and search window",
        "",
        f"From the `--jobs {JOBS[0]}` run's table. Scans: held-out scans × {len(SEEDS)} seeds. "
        f"Within: |err_x|, |err_y| ≤ {SUCCESS_M * 100:.0f} cm, |err_θ| ≤ {SUCCESS_DEG:g}° "
        f"and status {' or '.join(ESTIMATED)}, over all the scans, a scan without a row, "
        "without an estimate or in a failed task counted as a miss; the medians count such "
        "a miss as infinitely wrong (∞: more than half are). Not accepted: rows whose status "
        "is neither (ambiguous, lost, too few segments...), estimate or not.",
        "",
        f"| dataset | {GRID_KEY} | scans | rows | failed tasks | within {SUCCESS_M * 100:.0f} cm "
        f"/ {SUCCESS_DEG:g}° | no estimate | not accepted | median pos err (cm) "
        "| median abs θ err (°) | median ms/scan |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, width, f in figures:
        shown = f"**{name}**" if name == "all" else name
        lines.append(
            f"| {shown} | {width:.1f} | {f['expected']} | {f['rows']} | {f['failed_tasks']} | "
            f"{percent(f['within'])} | {f['no_estimate']} | {f['not_accepted']} | "
            f"{_number(f['median_cm'], 1)} | {_number(f['median_deg'], 2)} | "
            f"{_number(f['median_ms'], 1)} |"
        )
    verdict = "agrees" if agrees else "**does not agree**"
    lines += [
        "",
        f"The pooled share within the gates (rows *all*) {verdict} with the sweep's own summary "
        "of the same table.",
        "",
    ]
    return lines


def report(
    spec: str,
    runs: list[SweepRun],
    logs: list[SweptLog],
    difference: str | None,
    commands: dict[str, list[str]],
) -> str:
    """The markdown report: the spec, the wall times, the sweep's summary, each log × window
    and every command."""
    figures = per_log(runs[0].table, logs)
    lines = [
        "# segloc sweep on real logs",
        "",
        "Generated by `make bench-sweep` (`benchmarks/sweep_real.py`). Each log split as in "
        f"the perturbation protocol of [results-real.md](results-real.md): the map built from "
        f"the corrected log without every {HOLD_OUT_EVERY}th scan, each held-out scan "
        f"localized from its reference pose plus uniform errors in ±{PERTURB_XY_M:g} m, "
        f'±{PERTURB_XY_M:g} m, ±{PERTURB_THETA_DEG:g}° (`init-errors = "{INIT_ERRORS}"`, '
        f"drawn per seed and log by the sweep, seeds {', '.join(map(str, SEEDS))}) with each "
        f"search window of the grid, the other settings the defaults. "
        f"Held-out scans: " + ", ".join(f"{log.name} {log.held_out}" for log in logs) + ".",
        "",
        "## The spec",
        "",
        "```toml",
        spec.rstrip("\n"),
        "```",
        "",
        *wall_time_section(runs, difference),
        "## The sweep's summary",
        "",
        f"As `segloc sweep --jobs {runs[0].jobs}` printed it: per combination, the "
        f"{len(logs)} logs pooled; a pose without an estimate counts as infinitely wrong in "
        "its medians and 95th percentiles, and as a miss in its share within the gates.",
        "",
        runs[0].run.stdout.rstrip("\n"),
        "",
        *per_log_section(figures, pooled_agrees(runs[0].table, figures)),
        *commands_section(commands),
    ]
    return "\n".join(lines) + "\n"


def main() -> None:
    args = log_arguments(__doc__, "out/sweep", "benchmarks/results-sweep.md").parse_args()
    names = chosen_logs(args.only)
    splits, commands = {}, {}
    for name in names:
        work = args.work / name
        work.mkdir(parents=True, exist_ok=True)
        commands[name] = []
        print(f"{name}: held-out split", flush=True)
        splits[name] = prepare_held_out(name, args.datasets, work, commands[name])
    spec_path = args.work / SPEC_NAME
    spec = spec_text(splits, args.work)
    spec_path.write_text(spec, encoding="utf-8")
    logs = swept_logs(splits, args.work)
    commands["sweep"] = [f"# {relative(spec_path)}: written by {Path(__file__).name}"]
    runs = []
    for jobs in JOBS:
        print(f"sweep: --jobs {jobs}", flush=True)
        runs.append(run_sweep(spec_path, jobs, args.work, commands["sweep"]))
        print(f"  {runs[-1].run.wall_s:.1f} s, {len(runs[-1].table)} rows", flush=True)
    difference = compare_tables(runs[0].table, runs[-1].table)
    text = report(spec, runs, logs, difference, commands)
    args.out.write_text(text, encoding="utf-8")
    print(text, end="")
    print(f"wrote {args.out}")
    if difference is not None:
        raise SystemExit("the tables of the two runs differ beyond runtime_ms")


if __name__ == "__main__":
    main()
