"""Fit the verdict's confidence model (`make calibrate`) and write it beside the code.

The confidence of an answer is the probability that it is the right place: within
``PLACE_M`` and ``PLACE_DEG`` of the truth. It is predicted by a logistic model of the
``Evidence`` a fit leaves behind (``segloc_cli/method/confidence.py``), fitted here on trials of two
kinds, none of which the benchmarks score:

* simulated: rooms without symmetry (``sim.random_world``), and places that no scan can tell
  from another, a room with a half-turn symmetry (``sim.symmetric_room``) and a corridor of
  doors at one period (``sim.repeating_corridor``), scanned by a 256-reading scanner with
  range noise, dropouts, glass and clutter, the world's own walls as the map;
* real: each shared log's *calibration split*, every 10th scan from the 6th held out of the map
  (the benchmarks hold out every 10th from the 1st, so no scan scored there is fitted here,
  and the maps differ).

The real held-out scans are found in each log's raw log (by their readings) and localized
there, alone and with their windows (``window.py``: the neighbours the raw odometry places
around them), in a map built without them and without the scans of their windows, the map's
own scans stripped from the raw log (``protocol.raw_held_out``); a simulated scan's window
holds scans along its line of travel placed by the true motion plus odometry noise. Each
held-out scan is localized from two guesses drawn as in the perturbation protocol
(±1.5 m, ±20°), one from a wider draw (±3 m, ±45°) and, for up to ``GLOBAL_PER_LOG`` scans per
log, with no guess at all (``--global``). A model per kind of local map
(``confidence.LOCAL_MAPS``) is fitted on the trials whose searched area holds the truth
(``FITTED_KINDS``), and also once per group (each real log; the simulated worlds as one) with
that group left out, which gives each trial
a prediction from a model that never saw its group: the report's reliability, flag and
threshold tables come from those.

Writes ``segloc_cli/method/confidence_model.json`` (the models and where they came from) and
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
    prepare_raw_log,
    raw_held_out,
    reliability_rows,
)
from sklearn.linear_model import LogisticRegression
from sklearn.preprocessing import StandardScaler

from segloc_cli.config import ConfidenceParams, Config, TrackParams, WindowParams
from segloc_cli.geometry import Pose2
from segloc_cli.io.maps import read_map
from segloc_cli.io.mcap_log import read_log
from segloc_cli.method.confidence import (
    FEATURES,
    LOCAL_MAPS,
    MODEL_PATH,
    UNINFORMED,
    ConfidenceModel,
)
from segloc_cli.method.localize import Localizer, localize_scan
from segloc_cli.method.window import Windows
from segloc_cli.runs.pipeline import scan_windows
from segloc_cli.sim import (
    SensorModel,
    free_space_mask,
    random_free_poses,
    random_world,
    repeating_corridor,
    simulate_scan,
    symmetric_room,
)
from segloc_cli.timing import nearest_by_time
from segloc_cli.world import World

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


def _trial(source: str, kind: str, mode: str, est, truth: np.ndarray) -> dict | None:
    """One trial's row: its source, kind of guess, mode (a single scan or a window), evidence
    features and whether it is the right place (None when no evidence was measured, e.g. no
    pose found)."""
    if est.evidence is None:
        return None
    pos, head = pose_errors(est.pose.x - truth[0], est.pose.y - truth[1], est.pose.theta - truth[2])
    right = bool(np.isfinite(pos) and is_right_place(pos, head))
    features = est.evidence.features()
    return {"source": source, "kind": kind, "mode": mode, "right": right, **features}


def localize_trials(
    source: str,
    localizer: Localizer,
    scans: list,
    truths: np.ndarray,
    rng: np.random.Generator,
    windows: Windows | None = None,
) -> list[dict]:
    """Every kind of trial on each scan with its true pose (rows of ``truths``, radians):
    the scan alone and, with ``windows`` (one per scan), from the same guess with its
    neighbours."""
    modes = {"single": None} if windows is None else {"single": None, "window": windows}

    def trials(kind: str, i: int, guess: Pose2 | None) -> list[dict | None]:
        rows = []
        for mode, around in modes.items():
            neighbours = () if around is None else around.neighbours[i]
            est, _ = localize_scan(localizer, scans[i], guess, None, neighbours, around)
            rows.append(_trial(source, kind, mode, est, truths[i]))
        return rows

    rows = []
    for kind, (xy_m, theta_deg) in GUESSES.items():
        for i, truth in enumerate(truths):
            offset = [*rng.uniform(-xy_m, xy_m, 2), np.deg2rad(rng.uniform(-theta_deg, theta_deg))]
            rows += trials(kind, i, Pose2(*(truth + offset)))
    for i in np.flatnonzero(evenly_spread(len(scans), GLOBAL_PER_LOG)):
        rows += trials("global", i, None)
    return [row for row in rows if row is not None]


def real_trials(name: str, datasets: Path, work: Path, rng: np.random.Generator) -> list[dict]:
    """Trials on the calibration split of shared log ``name``: its held-out scans found in
    the raw log, alone and with their neighbours there (none of them a scan of the map)."""
    split = prepare_held_out(name, datasets, work, [], first=CALIBRATION_FIRST)
    raw = raw_held_out(split, prepare_raw_log(name, datasets, work, []), work, [])
    log = read_log(raw.log_path)
    # The held-out scans' times are the raw log's own, as written to the CSV.
    index = nearest_by_time(raw.truth.time_s, log.scan_times_s, SAME_TIME_S)
    localizer = Localizer.on_map(read_map(raw.map_path), global_search=True, model=UNINFORMED)
    windows = scan_windows(log, raw.log_path, index, localizer, Config())
    scans = [log.scans[i] for i in index]
    return localize_trials(name, localizer, scans, raw.truth.poses, rng, windows)


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
    """Trials at ``SIM_POSES`` random free poses of ``world``, its walls as the map, each
    scan alone and with neighbours on its line of travel (``_simulated_windows``)."""
    truths = random_free_poses(world, SIM_POSES, rng)
    scans = [simulate_scan(world, Pose2(*p), SIM_SENSOR, rng, float(k)) for k, p in
             enumerate(truths)]  # fmt: skip
    windows = _simulated_windows(world, truths, rng)
    localizer = Localizer.on_map(world.segments, global_search=True, model=UNINFORMED)
    return localize_trials(source, localizer, scans, truths, rng, windows)


SIM_STEPS_M = (-0.75, -0.5, -0.25, 0.25, 0.5, 0.75)
"""Where a simulated window's neighbours stand: this far ahead of the scan (behind where
negative) along its heading, where the floor is free."""


def _simulated_windows(world: World, truths: np.ndarray, rng: np.random.Generator) -> Windows:
    """For each true pose, scans along its line of travel at ``SIM_STEPS_M`` where the floor
    is free, each placed by the true motion plus odometry noise of half the spread tracking
    allows for that motion (``TrackParams.prior``)."""
    odometry = TrackParams()
    neighbours = []
    for k, truth in enumerate(truths):
        pose = Pose2(*truth)
        around = []
        for step in SIM_STEPS_M:
            turn = np.deg2rad(rng.uniform(-10.0, 10.0))
            motion = Pose2(step, 0.0, turn)
            there = pose.compose(motion)
            if not free_space_mask(world, np.array([[there.x, there.y]]), 0.3)[0]:
                continue
            sigma_m, sigma_deg = odometry.prior(motion)
            noise = [*rng.normal(0.0, sigma_m / 2, 2), np.deg2rad(rng.normal(0.0, sigma_deg / 2))]
            measured = Pose2(*(motion.as_array() + noise))
            around.append((simulate_scan(world, there, SIM_SENSOR, rng, float(k)), measured))
        neighbours.append(sorted(around, key=lambda item: abs(item[1].x)))
    return Windows(neighbours, WindowParams(), odometry)


FITTED_KINDS = ("perturbation-1", "perturbation-2", "global")
"""The trials the model is fitted on: those whose searched area holds the truth. A guess
3 m off lies beyond the ±2 m the search covers, so no evidence of the scan can tell whether
the truth was among the poses compared; those trials are reported, not fitted."""


def group_of(source: str) -> str:
    """The group a source is left out with: each real log alone, the simulated worlds as one
    (they share a scanner and a maker, as no unseen log shares them)."""
    return "simulated" if source.startswith("simulated") else source


def fitted_rows(trials: pd.DataFrame) -> np.ndarray:
    """(N,) bool: the trials a model is fitted on: ``FITTED_KINDS`` and not lost (a lost
    answer's status does not depend on its confidence)."""
    lost = trials["own_inlier_ratio"] < ConfidenceParams().min_inlier_ratio
    return (trials["kind"].isin(FITTED_KINDS) & ~lost).to_numpy()


def fit(trials: pd.DataFrame) -> ConfidenceModel:
    """The logistic model of ``right`` on the ``FEATURES`` of the ``fitted_rows`` of
    ``trials``."""
    features = list(FEATURES)
    chosen = trials[fitted_rows(trials)]
    scaler = StandardScaler().fit(chosen[features])
    model = LogisticRegression(C=REGULARIZATION_C, max_iter=1000)
    model.fit(scaler.transform(chosen[features]), chosen["right"])
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
    """Each trial's probability from a model fitted without its group (``group_of``)."""
    predicted = np.full(len(trials), np.nan)
    groups = trials["source"].map(group_of)
    for group in groups.unique():
        mine = (groups == group).to_numpy()
        predicted[mine] = predict(fit(trials[~mine]), trials[mine])
    return predicted


def flagged(trials: pd.DataFrame, confidence: np.ndarray, threshold: float) -> np.ndarray:
    """(N,) bool: the trials whose status would not be ok: lost, too loosely held, or below
    ``threshold``."""
    params = ConfidenceParams()
    lost = (trials["own_inlier_ratio"] < params.min_inlier_ratio).to_numpy()
    loose = (np.expm1(trials["log_hold_points"]) < params.min_hold_points).to_numpy()
    return lost | loose | (confidence < threshold)


def flag_rows(trials: pd.DataFrame, confidence: np.ndarray, threshold: float) -> list[list[str]]:
    """Per left-out group and kind of guess: trials, right share, and the shares of wrong and of
    right answers flagged at ``threshold``, and of silent ones (wrong yet ok)."""
    rows = []
    groups = trials["source"].map(group_of)
    for (group, kind), chosen in trials.groupby([groups, "kind"], sort=False):
        flags = flagged(chosen, confidence[chosen.index.to_numpy()], threshold)
        right = chosen["right"].to_numpy()
        wrong_flagged = f"{flags[~right].mean():.1%}" if (~right).any() else "—"
        rows.append([group, kind, str(len(chosen)), f"{right.mean():.1%}", wrong_flagged,
                     f"{flags[right].mean():.1%}", f"{(~flags & ~right).mean():.1%}"])  # fmt: skip
    return rows


THRESHOLDS = (0.5, 0.7, 0.8, 0.85, 0.9, 0.95, 0.98)


def threshold_rows(trials: pd.DataFrame, confidence: np.ndarray) -> list[list[str]]:
    """Silent and right-flagged shares of the ``FITTED_KINDS`` trials at each of
    ``THRESHOLDS``: pooled, and the worst left-out group's."""
    chosen = trials[trials["kind"].isin(FITTED_KINDS)]
    groups = chosen["source"].map(group_of)
    rows = []
    for threshold in THRESHOLDS:
        cells = []
        for name, rows_of in [("all", chosen), *chosen.groupby(groups)]:
            flags = flagged(rows_of, confidence[rows_of.index.to_numpy()], threshold)
            right = rows_of["right"].to_numpy()
            cells.append(((~flags & ~right).mean(), flags[right].mean(), name))
        pooled, per_group = cells[0], cells[1:]
        worst_silent = max(per_group, key=lambda c: c[0])
        worst_flagged = max(per_group, key=lambda c: c[1])
        rows.append([f"{threshold:g}", f"{pooled[0]:.1%}", f"{pooled[1]:.1%}",
                     f"{worst_silent[0]:.1%} ({worst_silent[2]})",
                     f"{worst_flagged[1]:.1%} ({worst_flagged[2]})"])  # fmt: skip
    return rows


CURVE_FIGURE = Path("benchmarks/figures/threshold-curve.png")


def threshold_figure(trials: pd.DataFrame, left_out: np.ndarray) -> None:
    """Silent failures against flagged right answers as the threshold runs from 0.05 to 0.995,
    per mode, from the left-out predictions of the ``FITTED_KINDS`` trials: pooled (line) and
    per left-out group (thin lines); the default threshold marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    thresholds = np.concatenate([np.linspace(0.05, 0.95, 19), [0.97, 0.98, 0.99, 0.995]])
    default = ConfidenceParams().min_confidence
    fig, axes = plt.subplots(
        1, len(LOCAL_MAPS), figsize=(5.5 * len(LOCAL_MAPS), 4.5), squeeze=False
    )
    for ax, mode in zip(axes[0], LOCAL_MAPS, strict=True):
        mine = (trials["mode"] == mode).to_numpy() & trials["kind"].isin(FITTED_KINDS).to_numpy()
        chosen = trials[mine]
        groups = chosen["source"].map(group_of)
        for name, rows in [("pooled", chosen), *chosen.groupby(groups)]:
            right = rows["right"].to_numpy()
            p = left_out[rows.index.to_numpy()]
            points = [flagged(rows, p, t) for t in (*thresholds, default)]
            silent = [100 * np.mean(~f & ~right) for f in points]
            right_flagged = [100 * np.mean(f[right]) for f in points]
            style = {"lw": 2.0, "color": "k"} if name == "pooled" else {"lw": 0.8, "alpha": 0.7}
            (line,) = ax.plot(right_flagged[:-1], silent[:-1], label=name, **style)
            ax.plot(right_flagged[-1], silent[-1], "o", color=line.get_color())
        ax.set_xlabel("right answers flagged (%)")
        ax.set_ylabel("silent failures: wrong yet ok (%)")
        ax.set_title(f"{mode}: threshold 0.05–0.995, dots at {default:g}")
        ax.legend(fontsize=8)
    fig.tight_layout()
    CURVE_FIGURE.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(CURVE_FIGURE, dpi=80)
    plt.close(fig)


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


def mode_section(mode: str, trials: pd.DataFrame, model: ConfidenceModel, left_out) -> list[str]:
    """The report's part on one mode: the model, its reliability and flags on left-out
    groups, and silent against right flagged by threshold."""
    threshold = ConfidenceParams().min_confidence
    fitted = fitted_rows(trials)
    return [
        f"## {'A scan alone' if mode == 'single' else 'A window of scans'} (`{mode}`)",
        "",
        f"Fitted on {int(fitted.sum())} trials. P(right) = 1 / (1 + exp(−z)), "
        "z = bias + Σ weight · (feature − mean) / scale.",
        "",
        *_table(["feature", "mean", "scale", "weight"], _weight_rows(model)),
        "",
        f"Bias {model.bias:+.3f}.",
        "",
        "**Reliability**, each trial predicted by a model fitted without its group "
        "(fitted kinds, not lost):",
        "",
        *_table(
            ["confidence", "trials", "mean predicted", "observed right"],
            reliability_rows(left_out[fitted], trials["right"].to_numpy()[fitted]),
        ),
        "",
        f"**Flags at the default threshold ({threshold:g})**, left-out predictions; a trial is "
        "flagged when lost, loosely held or below the threshold:",
        "",
        *_table(
            ["left out", "guesses", "trials", "right", "wrong flagged", "right flagged", "silent"],
            flag_rows(trials, left_out, threshold),
        ),
        "",
        "**Silent against right flagged by threshold** (fitted kinds, left-out predictions): "
        f"pooled, and the worst left-out group; figure: [{CURVE_FIGURE.name}]"
        f"(figures/{CURVE_FIGURE.name}):",
        "",
        *_table(
            ["threshold", "silent", "right flagged", "worst silent", "worst right flagged"],
            threshold_rows(trials, left_out),
        ),
        "",
    ]


def report(trials: pd.DataFrame, models: dict, left_out: np.ndarray) -> str:
    """The markdown report: what was fitted on, and per mode the weights and how the
    left-out predictions bear out."""
    counts = trials.groupby(["source", "mode"])["right"].agg(["size", "mean"])
    lines = [
        "# Calibrating the verdict",
        "",
        "Generated by `make calibrate` (`benchmarks/calibrate.py`), which also writes "
        f"`segloc_cli/method/confidence_model.json`. Right: within {PLACE_M * 100:.0f} cm and "
        f"{PLACE_DEG:g}° of the truth. The trials are described in the script's docstring; "
        "none of them is scored by `make bench-real`. Each mode's model is fitted on the "
        f"trials whose guesses leave the truth inside the searched area ({', '.join(FITTED_KINDS)})"
        " and whose answers are not lost; the wide guesses (±3 m, ±45°) are reported beside. "
        "Left out in turn: each real log, and the simulated worlds as one group.",
        "",
        "## Trials",
        "",
        *_table(
            ["source", "mode", "trials", "right"],
            [[s, m, str(int(r["size"])), f"{r['mean']:.1%}"] for (s, m), r in counts.iterrows()],
        ),
        "",
    ]
    for mode, model in models.items():
        mine = (trials["mode"] == mode).to_numpy()
        chosen = trials[mine].reset_index(drop=True)
        lines += mode_section(mode, chosen, model, left_out[mine])
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--datasets", type=Path, default=DATASETS_DIR)
    parser.add_argument("--work", type=Path, default=Path("out/calibrate"))
    parser.add_argument("--only", default=",".join(DATASETS))
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results-calibration.md"))
    parser.add_argument(
        "--trials",
        type=Path,
        default=None,
        help="refit on the trials an earlier run wrote (WORK/trials.csv) instead of making them",
    )
    args = parser.parse_args()
    if args.trials is not None:
        write_models(pd.read_csv(args.trials), args.out, args.work)
        return
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
    write_models(pd.DataFrame(rows), args.out, args.work)


def write_models(trials: pd.DataFrame, out: Path, work: Path) -> None:
    """Fit a model per mode on ``trials``, write them to ``MODEL_PATH``, the report to ``out``
    and the trials with their left-out predictions to ``work/trials.csv``."""
    models, left_out = {}, np.full(len(trials), np.nan)
    for mode in LOCAL_MAPS:
        mine = (trials["mode"] == mode).to_numpy()
        chosen = trials[mine].reset_index(drop=True)
        models[mode] = fit(chosen)
        left_out[mine] = left_out_predictions(chosen)
    fitted = trials[fitted_rows(trials)]
    sources = fitted.groupby(["mode", "source"])["right"].agg(["size", "sum"])
    provenance = {
        "fitted_by": "benchmarks/calibrate.py",
        "right": f"within {PLACE_M * 100:.0f} cm and {PLACE_DEG:g} degrees of the truth",
        "trials": {
            mode: {
                s: {"trials": int(r["size"]), "right": int(r["sum"])}
                for (m, s), r in sources.iterrows()
                if m == mode
            }
            for mode in LOCAL_MAPS
        },
    }
    document = {"models": {m: model.as_dict() for m, model in models.items()}}
    MODEL_PATH.write_text(
        json.dumps(document | {"provenance": provenance}, indent=2) + "\n", encoding="utf-8"
    )
    out.write_text(report(trials, models, left_out), encoding="utf-8")
    threshold_figure(trials, left_out)
    work.mkdir(parents=True, exist_ok=True)
    trials.assign(left_out=left_out).to_csv(work / "trials.csv", index=False)
    print(f"wrote {MODEL_PATH} and {out}")


if __name__ == "__main__":
    main()
