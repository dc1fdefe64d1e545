"""Fit the verdict's confidence model (`make calibrate`) and write it beside the code.

The confidence of an answer is the probability that it is the right place: within
``PLACE_M`` and ``PLACE_DEG`` of the truth. It is predicted by a logistic model of the
``Evidence`` a fit leaves behind (``segloc_cli/confidence.py``), fitted here on trials of two
kinds, none of which the benchmarks score:

* simulated: rooms without symmetry (``sim.random_world``), and places that no scan can tell
  from another, a room with a half-turn symmetry (``sim.symmetric_room``) and a corridor of
  doors at one period (``sim.repeating_corridor``), scanned by a 256-reading scanner with
  range noise, dropouts, glass and clutter, the world's own walls as the map;
* real: each shared log's *calibration split*, every 10th scan from the 6th held out of the map
  (the benchmarks hold out every 10th from the 1st, so no scan scored there is fitted here,
  and the maps differ).

Each held-out scan is localized from two guesses drawn as in the perturbation protocol
(±1.5 m, ±20°), one from a wider draw (±3 m, ±45°) and, for up to ``GLOBAL_PER_LOG`` scans per
log, with no guess at all (``--global``). The model is fitted on every trial, and also once
per source with that source left out, which gives each trial a prediction from a model that
never saw its source: the report's reliability and flag tables come from those.

Writes ``segloc_cli/confidence_model.json`` (the model and where it came from) and
``benchmarks/results-calibration.md``. Needs scikit-learn (in the ``dev`` extra).
Usage: python benchmarks/calibrate.py [--datasets DIR] [--work DIR] [--only intel,aces]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pandas as pd
from protocol import (
    DATASETS,
    DATASETS_DIR,
    PLACE_DEG,
    PLACE_M,
    evenly_spread,
    is_right_place,
    pose_errors,
    prepare_held_out,
    reliability_rows,
)
from sklearn.linear_model import LogisticRegression
from sklearn.preprocessing import StandardScaler

from segloc_cli.confidence import FEATURES, MODEL_PATH, UNINFORMED, ConfidenceModel
from segloc_cli.config import ConfidenceParams
from segloc_cli.extract import extract_segments
from segloc_cli.geometry import Pose2
from segloc_cli.io.maps import World, read_map
from segloc_cli.io.mcap_log import read_log
from segloc_cli.io.tables import nearest_by_time
from segloc_cli.localize import Localizer
from segloc_cli.sim import (
    SensorModel,
    random_free_poses,
    random_world,
    repeating_corridor,
    simulate_scan,
    symmetric_room,
)

CALIBRATION_FIRST = 5
"""The calibration split holds out every 10th scan from this one (0-based)."""
GUESSES = {
    # trial kind: (half range of the position error per axis (m), of the heading error (°))
    "perturbation-1": (1.5, 20.0),
    "perturbation-2": (1.5, 20.0),
    "wide": (3.0, 45.0),
}
SAME_TIME_S = 1e-6
GLOBAL_PER_LOG = 100
"""Held-out scans per log (or simulated world) also localized with no guess."""
SIM_WORLDS = {"random": 12, "symmetric": 4, "corridor": 4}
"""Simulated worlds of each kind (``random_world``, ``symmetric_room``, ``repeating_corridor``)."""
SIM_POSES = 40
SIM_SENSOR = SensorModel(readings=256)
SEED = 77
REGULARIZATION_C = 1.0
"""Inverse strength of the logistic fit's L2 penalty on standardized features."""


def _trial(source: str, kind: str, est, truth: np.ndarray) -> dict | None:
    """One trial's row: its source, kind, evidence features and whether it is the right place
    (None when no evidence was measured, e.g. no pose found)."""
    if est.evidence is None:
        return None
    pos, head = pose_errors(est.pose.x - truth[0], est.pose.y - truth[1], est.pose.theta - truth[2])
    right = bool(np.isfinite(pos) and is_right_place(pos, head))
    return {"source": source, "kind": kind, "right": right, **est.evidence.features()}


def localize_trials(
    source: str, localizer: Localizer, scans: list, truths: np.ndarray, rng: np.random.Generator
) -> list[dict]:
    """Every kind of trial on each scan with its true pose (rows of ``truths``, radians)."""
    rows = []
    locals_ = [extract_segments(scan) for scan in scans]
    for kind, (xy_m, theta_deg) in GUESSES.items():
        for scan, local, truth in zip(scans, locals_, truths, strict=True):
            offset = [*rng.uniform(-xy_m, xy_m, 2), np.deg2rad(rng.uniform(-theta_deg, theta_deg))]
            guess = Pose2(*(truth + offset))
            est = localizer.localize(local, guess, scan.points())
            rows.append(_trial(source, kind, est, truth))
    chosen = np.flatnonzero(evenly_spread(len(scans), GLOBAL_PER_LOG))
    for i in chosen:
        est = localizer.localize_global(locals_[i], scans[i].points())
        rows.append(_trial(source, "global", est, truths[i]))
    return [row for row in rows if row is not None]


def real_trials(name: str, datasets: Path, work: Path, rng: np.random.Generator) -> list[dict]:
    """Trials on the calibration split of shared log ``name``."""
    split = prepare_held_out(name, datasets, work, [], first=CALIBRATION_FIRST)
    truth = split.held_out_reference()
    log = read_log(split.log_path)
    # The reference's times are the scans' own, as written to the CSV.
    rows = nearest_by_time(truth.time_s, log.scan_times_s, SAME_TIME_S)
    scans = [log.scans[i] for i in rows]
    localizer = Localizer(read_map(split.map_path), model=UNINFORMED)
    return localize_trials(name, localizer, scans, truth.poses, rng)


def simulated_trials(rng: np.random.Generator) -> list[dict]:
    """Trials in the ``SIM_WORLDS``, ``SIM_POSES`` scans in each: rooms without symmetry, and
    places no scan can tell from another (a room and its half turn, a corridor of doors at
    one period), where a tie between the answer and its twin must cost confidence."""
    makers = {"random": random_world, "symmetric": symmetric_room, "corridor": repeating_corridor}
    rows = []
    for kind, count in SIM_WORLDS.items():
        for _ in range(count):
            rows += _world_trials(f"simulated {kind}", makers[kind](rng), rng)
    return rows


def _world_trials(source: str, world: World, rng: np.random.Generator) -> list[dict]:
    """Trials at ``SIM_POSES`` random free poses of ``world``, its walls as the map."""
    truths = random_free_poses(world, SIM_POSES, rng)
    scans = [simulate_scan(world, Pose2(*p), SIM_SENSOR, rng, float(k)) for k, p in
             enumerate(truths)]  # fmt: skip
    return localize_trials(source, Localizer(world.segments, model=UNINFORMED), scans, truths, rng)


def fit(trials: pd.DataFrame) -> ConfidenceModel:
    """The logistic model of ``right`` on the ``FEATURES`` of ``trials``."""
    features = list(FEATURES)
    scaler = StandardScaler().fit(trials[features])
    model = LogisticRegression(C=REGULARIZATION_C, max_iter=1000)
    model.fit(scaler.transform(trials[features]), trials["right"])
    return ConfidenceModel(
        features=FEATURES,
        mean=tuple(float(v) for v in scaler.mean_),
        scale=tuple(float(v) for v in scaler.scale_),
        weights=tuple(float(v) for v in model.coef_[0]),
        bias=float(model.intercept_[0]),
    )


def predict(model: ConfidenceModel, trials: pd.DataFrame) -> np.ndarray:
    """The model's probability for each trial row."""
    return model.probabilities(trials[list(model.features)].to_numpy())


def left_out_predictions(trials: pd.DataFrame) -> np.ndarray:
    """Each trial's probability from a model fitted without its source."""
    predicted = np.full(len(trials), np.nan)
    for source in trials["source"].unique():
        mine = (trials["source"] == source).to_numpy()
        predicted[mine] = predict(fit(trials[~mine]), trials[mine])
    return predicted


def flag_rows(trials: pd.DataFrame, confidence: np.ndarray, threshold: float) -> list[list[str]]:
    """Per source and kind of guess: trials, right share, and the shares of wrong and of right
    answers below ``threshold``."""
    rows = []
    for (source, kind), group in trials.groupby(["source", "kind"], sort=False):
        p = confidence[group.index.to_numpy()]
        right = group["right"].to_numpy()
        flagged = p < threshold
        wrong_flagged = f"{flagged[~right].mean():.1%}" if (~right).any() else "—"
        rows.append([source, kind, str(len(group)), f"{right.mean():.1%}", wrong_flagged,
                     f"{flagged[right].mean():.1%}"])  # fmt: skip
    return rows


def _weight_rows(model: ConfidenceModel) -> list[list[str]]:
    """Each feature of ``model`` with its standardization and weight."""
    columns = zip(model.features, model.mean, model.scale, model.weights, strict=True)
    return [[f, f"{m:.4g}", f"{s:.4g}", f"{w:+.3f}"] for f, m, s, w in columns]


def _table(head: list[str], rows: list[list[str]]) -> list[str]:
    return [
        "| " + " | ".join(head) + " |",
        "|" + "|".join("---" for _ in head) + "|",
        *("| " + " | ".join(row) + " |" for row in rows),
    ]


def report(trials: pd.DataFrame, model: ConfidenceModel, left_out: np.ndarray) -> str:
    """The markdown report: what was fitted on, the weights, and how the left-out
    predictions bear out."""
    threshold = ConfidenceParams().min_confidence
    right = trials["right"].to_numpy()
    counts = trials.groupby("source")["right"].agg(["size", "mean"])
    return "\n".join(
        [
            "# Calibrating the verdict",
            "",
            "Generated by `make calibrate` (`benchmarks/calibrate.py`), which also writes "
            "`segloc_cli/confidence_model.json`. Right: within "
            f"{PLACE_M * 100:.0f} cm and {PLACE_DEG:g}° of the truth. The trials are described "
            "in the script's docstring; none of them is scored by `make bench-real`.",
            "",
            "## Trials",
            "",
            *_table(
                ["source", "trials", "right"],
                [[s, str(int(r["size"])), f"{r['mean']:.1%}"] for s, r in counts.iterrows()],
            ),
            "",
            "## The model",
            "",
            "P(right) = 1 / (1 + exp(−z)), z = bias + Σ weight · (feature − mean) / scale.",
            "",
            *_table(["feature", "mean", "scale", "weight"], _weight_rows(model)),
            "",
            f"Bias {model.bias:+.3f}.",
            "",
            "## Reliability, each source predicted by a model fitted without it",
            "",
            *_table(
                ["confidence", "trials", "mean predicted", "observed right"],
                reliability_rows(left_out, right),
            ),
            "",
            f"## Flags at the default threshold ({threshold:g}), left-out predictions",
            "",
            *_table(
                ["source", "guesses", "trials", "right", "wrong flagged", "right flagged"],
                flag_rows(trials, left_out, threshold),
            ),
            "",
        ]
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--datasets", type=Path, default=DATASETS_DIR)
    parser.add_argument("--work", type=Path, default=Path("out/calibrate"))
    parser.add_argument("--only", default=",".join(DATASETS))
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results-calibration.md"))
    args = parser.parse_args()
    rng = np.random.default_rng(SEED)
    rows = simulated_trials(rng)
    print(f"simulated: {len(rows)} trials", flush=True)
    for name in args.only.split(","):
        if not (args.datasets / name / DATASETS[name][0]).is_file():
            print(f"{name}: skipped, not found in {args.datasets}")
            continue
        work = args.work / name
        work.mkdir(parents=True, exist_ok=True)
        found = real_trials(name, args.datasets, work, rng)
        print(f"{name}: {len(found)} trials", flush=True)
        rows += found
    trials = pd.DataFrame(rows)
    model = fit(trials)
    left_out = left_out_predictions(trials)
    sources = trials.groupby("source")["right"].agg(["size", "sum"])
    provenance = {
        "fitted_by": "benchmarks/calibrate.py",
        "right": f"within {PLACE_M * 100:.0f} cm and {PLACE_DEG:g} degrees of the truth",
        "trials": {
            s: {"trials": int(r["size"]), "right": int(r["sum"])} for s, r in sources.iterrows()
        },
    }
    MODEL_PATH.write_text(
        json.dumps({"model": model.as_dict(), "provenance": provenance}, indent=2) + "\n",
        encoding="utf-8",
    )
    args.out.write_text(report(trials, model, left_out), encoding="utf-8")
    trials.assign(left_out=left_out).to_csv(args.work / "trials.csv", index=False)
    print(f"wrote {MODEL_PATH} and {args.out}")


if __name__ == "__main__":
    main()
