"""Figures (`make figures`): the method at work on a dataset, and success against initial error.

1. Through the command line, as a user would run it: every scan of the
   dataset is localized from its initial guess in the dataset's map (built
   from a mapping run of its own, not from these scans), and
   `segloc evaluate --plots` draws the figures of the run into OUT/<dataset>/.
2. The run view of that run (`segloc localize --mcap`), read back from the file and
   drawn as it shows in Foxglove, seen from above: the map, every scan placed at its
   estimate, and the initial guesses (OUT/<dataset>/run-view.png).
3. When the trials table of the peer comparison exists (default
   benchmarks/peers-trials.csv), the success rate against the initial position
   error is drawn into OUT/.

Usage: python benchmarks/figures.py [--dataset DIR] [--trials CSV] [--out DIR]
"""

from __future__ import annotations

import argparse
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from protocol import segloc_argv

from segloc_cli.geometry import Pose2, quaternion_to_heading, transform_points
from segloc_cli.io.figures import save_figure
from segloc_cli.scoring.plots import (
    SUCCESS_VS_INITIAL_ERROR,
    draw_success_vs_initial_error,
    success_rates,
)

ROOT = Path(__file__).resolve().parents[1]
RUN_VIEW = "run-view"


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
        estimates, view = Path(work) / "estimates.csv", Path(work) / "run.mcap"
        run("localize", log, "--map", map_path, "--out", estimates, "--mcap", view)
        run("evaluate", estimates, "--survey", survey, "--plots", out_dir,
            "--map", map_path, "--log", log, "--force")  # fmt: skip
        for path in save_figure(draw_run_view(view), out_dir, RUN_VIEW):
            print(f"wrote {path}")


def _decoded(view: Path) -> dict[str, list]:
    """The run view's messages by topic, decoded with the schemas the file carries."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    by_topic: dict[str, list] = {}
    with open(view, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, record, message in reader.iter_decoded_messages(log_time_order=True):
            by_topic.setdefault(channel.topic, []).append((record.log_time, message))
    return by_topic


def _planar(translation, rotation) -> tuple[float, float, float]:
    heading = quaternion_to_heading(rotation.x, rotation.y, rotation.z, rotation.w)
    return translation.x, translation.y, heading


def draw_run_view(view: Path):
    """The run view seen from above: map lines, the scans' points placed through the file's
    transforms (world → base_link → laser) at their times, and arrows from each initial
    guess to its estimate."""
    import matplotlib.pyplot as plt

    messages = _decoded(view)
    fig, ax = plt.subplots(figsize=(8.0, 5.5), layout="constrained")
    for line in messages["/map"][0][1].entities[0].lines:
        ends = np.array([(p.x, p.y) for p in line.points]).reshape(-1, 2, 2)
        for (x1, y1), (x2, y2) in ends:
            ax.plot([x1, x2], [y1, y2], color="0.35", lw=1.2, solid_capstyle="butt")
    chains = {time: message.transforms for time, message in messages["/tf"]}
    for time, scan in messages["/scan"]:
        if time not in chains:
            continue
        robot, laser = (Pose2(*_planar(t.translation, t.rotation)) for t in chains[time])
        angles = np.linspace(scan.start_angle, scan.end_angle, len(scan.ranges))
        ranges = np.array(scan.ranges)
        hit = ranges > 0
        local = np.column_stack([ranges * np.cos(angles), ranges * np.sin(angles)])[hit]
        points = transform_points(local, robot.compose(laser))
        ax.scatter(points[:, 0], points[:, 1], s=1.5, color="#e8a200", linewidths=0)
    poses = {}
    for topic in ("/guess", "/estimate"):
        poses[topic] = np.array([_planar(m.pose.position, m.pose.orientation)
                                 for _, m in messages.get(topic, [])]).reshape(-1, 3)  # fmt: skip
    if len(poses["/guess"]) == len(poses["/estimate"]):  # pair each guess with its answer
        for (gx, gy, _), (ex, ey, _) in zip(poses["/guess"], poses["/estimate"], strict=True):
            ax.plot([gx, ex], [gy, ey], color="0.5", lw=0.8, ls=":")
    for topic, color, label in (("/guess", "#1f77b4", "initial guess"),
                                ("/estimate", "#2ca02c", "estimate")):  # fmt: skip
        x, y, heading = poses[topic].T
        ax.quiver(x, y, np.cos(heading), np.sin(heading), color=color, angles="xy",
                  scale=25, width=0.004, label=label)  # fmt: skip
    ax.scatter([], [], s=8, color="#e8a200", label="scans at their estimates")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, world)")
    ax.set_ylabel("y (m, world)")
    ax.set_title(f"{view.name}: the run view read back, seen from above")
    ax.legend(loc="upper right", fontsize=8)
    return fig


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
