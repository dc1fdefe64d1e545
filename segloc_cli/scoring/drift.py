"""Error growth along the path: relative-pose error over indoor lengths travelled.

As evo's RPE with ``--delta_unit m`` does in 3D, each pose i of the true path is paired
with the first later pose j at least a length L further along it, and the motion the
estimates make from i to j is compared with the true one in SE(2):
e = (T_i⁻¹ T_j)_true⁻¹ (T_i⁻¹ T_j)_est. Only relative motions enter, so a constant offset
or rotation of the whole estimated trajectory leaves every error unchanged; what remains
is how far the estimates wander from each other over L. Every function here is pure.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from segloc_cli.geometry import relative_motion

DRIFT_LENGTHS_M = (1.0, 2.0, 5.0, 10.0)
"""Lengths travelled (m) over which drift is measured: room and corridor scales."""

DRIFT_COLUMNS = (
    "length_m",
    "n_pairs",
    "trans_mean_cm",
    "trans_rms_cm",
    "trans_max_cm",
    "trans_pct",
    "rot_mean_deg",
    "rot_max_deg",
    "rot_deg_per_m",
)
"""Columns of ``drift_per_length``, in order."""

# Cumulative sums of steps such as 0.1 m land a few ulps off the sums they stand for; a
# pair exactly L apart must not lose its end to that rounding.
_LENGTH_SLACK_M = 1e-9

# Columns shown by ``format_drift_md``: decimals and headers.
_DISPLAY = (
    ("length_m", 1, "length (m)"),
    ("n_pairs", 0, "pairs"),
    ("trans_mean_cm", 1, "mean (cm)"),
    ("trans_rms_cm", 1, "RMS (cm)"),
    ("trans_max_cm", 1, "max (cm)"),
    ("trans_pct", 2, "drift (%)"),
    ("rot_mean_deg", 2, "rot mean (°)"),
    ("rot_max_deg", 2, "rot max (°)"),
    ("rot_deg_per_m", 2, "rot (°/m)"),
)
_MISSING = "—"


def _as_poses(poses: np.ndarray, name: str) -> np.ndarray:
    poses = np.asarray(poses, dtype=float)
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise ValueError(f"{name} must be (N, 3) x_m, y_m, theta_rad, got shape {poses.shape}")
    return poses


def travelled_m(truth: np.ndarray) -> np.ndarray:
    """(N,) cumulative path length in metres along the true poses ``truth`` (N, 3: x m,
    y m, θ rad, world frame) in time order, 0 at the first; turning on the spot adds
    nothing. Raises ValueError when a true pose is not finite."""
    truth = _as_poses(truth, "truth")
    if not np.all(np.isfinite(truth)):
        raise ValueError("truth must hold finite poses")
    steps_m = np.hypot(np.diff(truth[:, 0]), np.diff(truth[:, 1]))
    return np.concatenate(([0.0], np.cumsum(steps_m)))[: truth.shape[0]]


def _length_row(
    length_m: float, trans_m: np.ndarray, rot_rad: np.ndarray, true_m: np.ndarray
) -> dict[str, float]:
    if trans_m.size == 0:
        return {"length_m": length_m, "n_pairs": 0} | {c: np.nan for c in DRIFT_COLUMNS[2:]}
    mean_true_m = float(np.mean(true_m))
    rot_mean_deg = float(np.rad2deg(np.mean(rot_rad)))
    return {
        "length_m": length_m,
        "n_pairs": int(trans_m.size),
        "trans_mean_cm": 100.0 * float(np.mean(trans_m)),
        "trans_rms_cm": 100.0 * float(np.sqrt(np.mean(trans_m**2))),
        "trans_max_cm": 100.0 * float(np.max(trans_m)),
        "trans_pct": 100.0 * float(np.mean(trans_m)) / mean_true_m,
        "rot_mean_deg": rot_mean_deg,
        "rot_max_deg": float(np.rad2deg(np.max(rot_rad))),
        "rot_deg_per_m": rot_mean_deg / mean_true_m,
    }


def drift_per_length(
    truth: np.ndarray,
    estimates: np.ndarray,
    lengths_m: tuple[float, ...] = DRIFT_LENGTHS_M,
) -> pd.DataFrame:
    """Relative-pose error of ``estimates`` over each length travelled in ``lengths_m`` (m).

    ``truth`` and ``estimates`` are (N, 3) poses ``x_m, y_m, theta_rad`` of the same
    instants in time order, each in its own world frame; ``estimates`` may hold NaN rows
    (failed poses), and pairs touching one are left out. Each start pose i is paired with
    the first j whose travelled length (``travelled_m``) exceeds i's by at least L; starts
    with no such j are left out. One row per length, columns ``DRIFT_COLUMNS``:
    ``n_pairs``; the translational error |e.xy| of the pairs as mean, RMS and max in cm,
    and ``trans_pct``, its mean over the pairs' mean true length travelled, in %; the
    rotational error |e.θ| as mean and max in degrees, and ``rot_deg_per_m``, its mean
    over the pairs' mean true length travelled. A length with no pair has ``n_pairs`` 0
    and NaN errors.
    """
    truth = _as_poses(truth, "truth")
    estimates = _as_poses(estimates, "estimates")
    if estimates.shape != truth.shape:
        raise ValueError(
            f"estimates ({estimates.shape[0]} poses) and truth ({truth.shape[0]}) must pair up"
        )
    lengths = np.asarray(lengths_m, dtype=float).reshape(-1)
    if not np.all(lengths > 0.0):
        raise ValueError(f"lengths_m must be positive, got {tuple(lengths)}")
    travelled = travelled_m(truth)
    has_estimate = np.all(np.isfinite(estimates), axis=1)
    starts = np.arange(truth.shape[0])

    rows = []
    for length in lengths:
        ends = np.searchsorted(travelled, travelled + length - _LENGTH_SLACK_M, side="left")
        keep = ends < truth.shape[0]
        i, j = starts[keep], ends[keep]
        both = has_estimate[i] & has_estimate[j]
        i, j = i[both], j[both]
        motion_true = relative_motion(truth[i], truth[j])
        motion_est = relative_motion(estimates[i], estimates[j])
        error = relative_motion(motion_true, motion_est)
        rows.append(
            _length_row(
                float(length),
                np.hypot(error[:, 0], error[:, 1]),
                np.abs(error[:, 2]),
                travelled[j] - travelled[i],
            )
        )
    frame = pd.DataFrame(rows, columns=list(DRIFT_COLUMNS))
    frame["n_pairs"] = frame["n_pairs"].astype(np.int64)
    return frame


def _cell(value: float, decimals: int) -> str:
    if not np.isfinite(value):
        return _MISSING
    text = f"{value:.{decimals}f}"
    # "-0.0" reads as a sign that the precision shown does not support.
    return text[1:] if text.startswith("-") and float(text) == 0.0 else text


def format_drift_md(frame: pd.DataFrame) -> str:
    """A ``drift_per_length`` result as a Markdown table: one row per length, errors in cm
    to 0.1, degrees and % to 0.01, "—" where a length has no pair."""
    headers = [header for _, _, header in _DISPLAY]
    cells = [
        [_cell(float(row[column]), decimals) for column, decimals, _ in _DISPLAY]
        for _, row in frame.iterrows()
    ]
    table = pd.DataFrame(cells, columns=headers)
    return (
        table.to_markdown(index=False, disable_numparse=True, colalign=("right",) * len(headers))
        + "\n"
    )
