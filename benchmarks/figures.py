"""Figures (`make figures`): the method at work on a dataset, and success against initial error.

1. Through the command line, as a user would run it: every scan of the
   dataset is localized from its initial guess in the dataset's map (built
   from a mapping run of its own, not from these scans), and
   `segloc evaluate --plots` draws the figures of the run into OUT/<dataset>/.
2. When the trials table of the peer comparison exists (default
   benchmarks/peers-trials.csv), the success rate against the initial position
   error is drawn into OUT/.

Usage: python benchmarks/figures.py [--dataset DIR] [--trials CSV] [--out DIR]
"""

from __future__ import annotations

import argparse
import subprocess
import tempfile
from pathlib import Path

import pandas as pd
from protocol import segloc_argv

from segloc_cli.plots import (
    SUCCESS_VS_INITIAL_ERROR,
    draw_success_vs_initial_error,
    save_figure,
    success_rates,
)

ROOT = Path(__file__).resolve().parents[1]


def run(*args: object) -> None:
    """Run ``segloc ARGS``; its messages pass through, a failure ends the script."""
    argv = segloc_argv(*args)
    print("$ " + " ".join(argv[1:]), flush=True)
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL)


def dataset_figures(dataset: Path, out_dir: Path) -> None:
    """Localize and evaluate ``dataset`` (log.mcap, survey.csv, and map.json, built from a
    mapping run of its own); figures into ``out_dir``, replacing those there."""
    log, survey, map_path = dataset / "log.mcap", dataset / "survey.csv", dataset / "map.json"
    with tempfile.TemporaryDirectory(prefix="segloc-figures-") as work:
        estimates = Path(work) / "estimates.csv"
        run("localize", log, "--map", map_path, "--out", estimates)
        run("evaluate", estimates, "--survey", survey, "--plots", out_dir,
            "--map", map_path, "--log", log, "--force")  # fmt: skip


def trials_figure(trials_csv: Path, out_dir: Path) -> None:
    """Success rate against initial position error from ``trials_csv``, if it exists."""
    if not trials_csv.is_file():
        print(f"{trials_csv} not found: {SUCCESS_VS_INITIAL_ERROR} not drawn")
        return
    rates = success_rates(pd.read_csv(trials_csv))
    out_dir.mkdir(parents=True, exist_ok=True)
    fig = draw_success_vs_initial_error(rates)
    for path in save_figure(fig, out_dir, SUCCESS_VS_INITIAL_ERROR):
        print(f"wrote {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path, default=ROOT / "datasets" / "hall")
    parser.add_argument("--trials", type=Path, default=ROOT / "benchmarks" / "peers-trials.csv")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "figures")
    args = parser.parse_args()
    dataset_figures(args.dataset, args.out / args.dataset.name)
    trials_figure(args.trials, args.out)


if __name__ == "__main__":
    main()
