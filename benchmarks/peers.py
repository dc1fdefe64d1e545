"""Comparison benchmark (`make bench-peers`): the two-stage method against ICP and correlative
matching, on the same scans from the same seeded initial guesses.

Datasets: the shipped hall (its 10 scans, scored against the survey) and the
public Radish logs as in `real_logs.py` (map from the corrected log without
every 10th scan; the held-out scans scored against their reference poses).

Initial errors fall in eight bins: position error 0–0.5, 0.5–1, 1–1.5,
1.5–2 m (uniform magnitude, uniform direction) crossed with heading error
0–10, 10–20° (uniform magnitude, random sign). Each bin holds the same
trials for every method. A trial succeeds when the answer is within 10 cm
and 1° of the truth, whatever status the method gave it.

Every method runs through `segloc localize` as a user would run it; the
commands are in the report. "two-stage, stage 2 (paper)" is the stage-2 pose
of the two-stage runs: the paper's answer before the search and refinement.

Usage: python benchmarks/peers.py [--datasets DIR] [--only hall,intel] [--trials 40] [--jobs 2]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
from protocol import (
    DATASETS,
    DATASETS_DIR,
    HELD_OUT_ALONE,
    SUCCESS_DEG,
    SUCCESS_M,
    commands_section,
    errors_against_truth,
    is_right,
    prepare_held_out,
    run_segloc,
    stage2_answers,
    subset_poses,
    truth_rows,
)

from segloc_cli.estimates import PoseTable
from segloc_cli.io.tables import read_estimates, read_pose_table, write_pose_table

SEED = 2010
POSITION_BINS_M = ((0.0, 0.5), (0.5, 1.0), (1.0, 1.5), (1.5, 2.0))
HEADING_BINS_DEG = ((0.0, 10.0), (10.0, 20.0))
BINS = [(p, h) for h in HEADING_BINS_DEG for p in POSITION_BINS_M]
METHODS = {
    "two-stage": (),
    "icp (GICP)": ("--method", "icp"),
    "icp (point-to-plane)": ("--method", "icp", "--icp-variant", "plane"),
    "correlative (Karto)": ("--method", "correlative"),
}
STAGE2 = "two-stage, stage 2 (paper)"
HALL = Path("datasets/hall")


def bin_label(position_m: tuple[float, float], heading_deg: tuple[float, float]) -> str:
    """The bin's name in the tables: its position (m) and heading (°) error ranges."""
    return f"{position_m[0]:g}–{position_m[1]:g} m, {heading_deg[0]:g}–{heading_deg[1]:g}°"


def draw_guesses(truth: PoseTable, position_m, heading_deg, rng) -> PoseTable:
    """The truth moved by errors whose sizes are uniform within one bin (metres, degrees)."""
    n = len(truth)
    distance = rng.uniform(*position_m, n)
    direction = rng.uniform(0.0, 2.0 * np.pi, n)
    turn = np.deg2rad(rng.uniform(*heading_deg, n)) * rng.choice([-1.0, 1.0], n)
    offsets = np.column_stack([distance * np.cos(direction), distance * np.sin(direction), turn])
    return PoseTable(truth.pose_id, truth.time_s, truth.poses + offsets)


def _trial_rows(dataset, method, label, est, guesses: PoseTable, truth: PoseTable) -> pd.DataFrame:
    """One row per estimate: its initial and final errors (m, °), success, status and time."""
    pos, head = errors_against_truth(est, truth)
    # The guesses were drawn row for row from the truth: one index serves both.
    rows = truth_rows(est, truth)
    init = guesses.poses[rows] - truth.poses[rows]
    return pd.DataFrame(
        {
            "dataset": dataset,
            "method": method,
            "bin": label,
            "pose_id": est["pose_id"].to_numpy(),
            "init_err_m": np.hypot(init[:, 0], init[:, 1]),
            "init_err_deg": np.abs(np.rad2deg(init[:, 2])),
            "err_m": pos,
            "err_deg": head,
            "success": is_right(pos, head),
            "status": est["status"].to_numpy(),
            "runtime_ms": est["runtime_ms"].to_numpy(),
        }
    )


def run_dataset(name, log_path, map_path, truth, work: Path, trials: int, jobs: int, commands):
    """Every method on every bin; one row per trial."""
    rng = np.random.default_rng(SEED)
    repeats = max(1, math.ceil(trials / len(truth)))
    if len(truth) > trials:  # evenly spread over the run
        truth = subset_poses(
            truth, np.isin(np.arange(len(truth)), np.linspace(0, len(truth) - 1, trials).round())
        )
    commands.append(f"# guesses-*.csv: truth + errors drawn uniformly in each bin, seed {SEED}")
    frames = []
    for repeat in range(repeats):
        for position_m, heading_deg in BINS:
            label = bin_label(position_m, heading_deg)
            tag = f"r{repeat}-p{position_m[1]:g}-h{heading_deg[1]:g}"
            guesses = draw_guesses(truth, position_m, heading_deg, rng)
            write_pose_table(work / f"guesses-{tag}.csv", guesses)
            for method, extra in METHODS.items():
                out = work / f"est-{tag}-{method.split()[0]}{len(extra)}.csv"
                run_segloc(
                    commands, "localize", log_path, "--map", map_path, *HELD_OUT_ALONE,
                    "--initial", work / f"guesses-{tag}.csv", "--out", out, "--jobs", jobs, *extra,
                )  # fmt: skip
                est = read_estimates(out)
                frames.append(_trial_rows(name, method, label, est, guesses, truth))
                if method == "two-stage":
                    stage2 = stage2_answers(est)
                    frames.append(_trial_rows(name, STAGE2, label, stage2, guesses, truth))
            print(f"  {name} {tag}", flush=True)
    return pd.concat(frames, ignore_index=True)


def dataset_table(trials: pd.DataFrame) -> str:
    """One markdown table: success per bin for each method, then median errors and time."""
    labels = [bin_label(p, h) for p, h in BINS]
    methods = [*METHODS, STAGE2]
    head = ["method", *labels, "all", "median pos (cm)", "median θ (°)", "ms/pose"]
    lines = ["| " + " | ".join(head) + " |", "|---|" + "---:|" * (len(head) - 1)]
    best = {b: trials[trials["bin"] == b].groupby("method")["success"].mean().max() for b in labels}
    for method in methods:
        rows = trials[trials["method"] == method]
        cells = [method]
        for b in labels:
            share = rows.loc[rows["bin"] == b, "success"].mean()
            text = f"{share * 100:.0f} %"
            cells.append(f"**{text}**" if np.isclose(share, best[b]) else text)
        cells.append(f"{rows['success'].mean() * 100:.1f} %")
        cells.append(f"{np.median(rows['err_m']) * 100:.1f}")
        cells.append(f"{np.median(rows['err_deg']):.2f}")
        time_ms = "—" if method == STAGE2 else f"{rows['runtime_ms'].median():.1f}"
        cells.append(time_ms)
        lines.append("| " + " | ".join(cells) + " |")
    n = trials.groupby(["method", "bin"]).size()
    lines.append("")
    lines.append(
        f"Trials per bin: {int(n.min())}" + ("" if n.min() == n.max() else f"–{int(n.max())}")
    )
    return "\n".join(lines)


def report(trials: pd.DataFrame, commands: dict, jobs: int) -> str:
    """The markdown report: how trials were scored, a table per dataset, every command."""
    lines = [
        "# segloc against ICP and correlative matching",
        "",
        "Produced by `make bench-peers` (`benchmarks/peers.py`). Success: within "
        f"{SUCCESS_M * 100:.0f} cm and {SUCCESS_DEG:g}° of the truth (survey or reference pose), "
        "whatever the status. Bins: initial position error (uniform size, uniform direction) × "
        f"initial heading error (uniform size, random sign); seed {SEED}. Bold: the best "
        "method in the bin. Median errors over all trials, misses included; ms/pose: median "
        f"run time per scan as `segloc localize` measures it (--jobs {jobs}, one core each).",
        "",
        "Methods: **two-stage** is `segloc localize` with its defaults; **stage 2 (paper)** is the "
        "stage-2 pose of the same runs; **icp** is small-gicp registering the scan's points to "
        "points every 2.5 cm along the map's segments (1 m correspondence distance); "
        "**correlative** is Karto's correlative scan matcher searching ±2.1 m and ±20° on a 2 cm "
        "grid against virtual scans of the map.",
        "",
    ]
    for name, group in trials.groupby("dataset", sort=False):
        lines += [f"## {name}", "", dataset_table(group), ""]
    return "\n".join([*lines, *commands_section(commands)]) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", type=Path, default=DATASETS_DIR)
    parser.add_argument("--only", default=",".join(["hall", *DATASETS]))
    parser.add_argument("--work", type=Path, default=Path("out/peers"))
    parser.add_argument("--trials", type=int, default=40, help="trials per bin and method")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results-peers.md"))
    parser.add_argument("--trials-out", type=Path, default=Path("benchmarks/peers-trials.csv"))
    args = parser.parse_args()
    frames, commands = [], {}
    for name in args.only.split(","):
        work = args.work / name
        work.mkdir(parents=True, exist_ok=True)
        log: list[str] = []
        t0 = time.perf_counter()
        if name == "hall":
            log_path, map_path = HALL / "log.mcap", HALL / "map.json"
            truth = read_pose_table(HALL / "survey.csv")
        elif name in DATASETS:
            split = prepare_held_out(name, args.datasets, work, log)
            log_path, map_path = split.log_path, split.map_path
            truth = split.held_out_reference()
        else:
            sys.exit(f"unknown dataset {name!r}; expected hall or one of {', '.join(DATASETS)}")
        print(f"{name}: {len(truth)} scans", flush=True)
        trials = run_dataset(name, log_path, map_path, truth, work, args.trials, args.jobs, log)
        frames.append(trials)
        commands[name] = log
        print(f"{name}: done in {time.perf_counter() - t0:.0f} s", flush=True)
        print(dataset_table(trials), flush=True)
    trials = pd.concat(frames, ignore_index=True)
    trials.to_csv(args.trials_out, index=False, float_format="%.6g")
    args.out.write_text(report(trials, commands, args.jobs), encoding="utf-8")
    print(f"wrote {args.out} and {args.trials_out}")


if __name__ == "__main__":
    main()
