"""Relative-pose error against reference relations (Kümmerle et al. 2009).

The metric of R. Kümmerle, B. Steder, C. Dornhege, M. Ruhnke, G. Grisetti,
C. Stachniss and A. Kleiner, "On measuring the accuracy of SLAM algorithms",
Autonomous Robots 27(4):387–407, 2009. A relation says how the robot moved from
its pose at time t1 to its pose at time t2, expressed in the frame of the pose
at t1: δ*_ij = x_i⁻¹ ⊕ x_j for the reference trajectory. The same motion of an
estimated trajectory, δ_ij = x_i⁻¹ ⊕ x_j (the paper's x_j ⊖ x_i), is compared
with it through e_ij = δ*_ij⁻¹ ⊕ δ_ij (the paper's δ_ij ⊖ δ*_ij):

- translational error |e_ij.xy| in metres (equal to |δ_ij.xy − δ*_ij.xy|, as
  rotating a vector keeps its length);
- rotational error |wrap(e_ij.θ)| in degrees.

The paper's ε(δ) = 1/N Σ trans(e_ij)² + rot(e_ij)²; its tables, and this module,
report the absolute and the squared errors separately, each as mean ± standard
deviation over the relations. Only relative motions enter, so the score does
not depend on the world frame the trajectory is expressed in: any rigid
transform of the whole trajectory leaves every error unchanged.

The relations are read by ``io/relations.py``; every function here is pure.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from functools import partial

import numpy as np
import pandas as pd

from segloc_cli.config import TIME_TOLERANCE_MS
from segloc_cli.errors import InputError
from segloc_cli.estimates import ESTIMATE_COLUMNS, ESTIMATED, Relations
from segloc_cli.geometry import relative_motion, wrap_angle
from segloc_cli.latex import latex_text, with_needs
from segloc_cli.markdown import cell
from segloc_cli.numbers import json_text, number_text, unit_of
from segloc_cli.scoring.evaluate import FORMATS
from segloc_cli.timing import pair_by_time

PUBLISHED_SOURCE = (
    "Graph Mapping results of Kümmerle et al., On measuring the accuracy of SLAM algorithms, "
    "Autonomous Robots 27(4), 2009, as quoted in Hess et al., Real-Time Loop Closure in 2D "
    "LIDAR SLAM, ICRA 2016, Table II"
)
"""Where the numbers of ``PUBLISHED`` come from, in one line (for table notes)."""

PUBLISHED: dict[str, dict[str, dict[str, tuple[float, float]]]] = {
    "aces": {"GraphMapping": {"trans_m": (0.044, 0.044), "rot_deg": (0.4, 0.4)}},
    "fr079": {"GraphMapping": {"trans_m": (0.056, 0.042), "rot_deg": (0.6, 0.6)}},
    "intel": {"GraphMapping": {"trans_m": (0.031, 0.026), "rot_deg": (1.3, 4.7)}},
    "mit-csail": {"GraphMapping": {"trans_m": (0.004, 0.009), "rot_deg": (0.05, 0.08)}},
    "mit-killian-court": {"GraphMapping": {"trans_m": (0.050, 0.056), "rot_deg": (0.5, 0.5)}},
}
"""Published relative-pose errors: dataset → method → error → (mean, standard deviation).

``trans_m`` is the absolute translational error in metres and ``rot_deg`` the
absolute rotational error in degrees, per relation, mean and standard deviation
over the dataset's relations. The method is Graph Mapping, the graph-based SLAM
of Kümmerle et al. (2009), "On measuring the accuracy of SLAM algorithms",
Autonomous Robots 27(4):387–407; the numbers are as quoted from that paper in
the "GM" column of Table II of W. Hess, D. Kohler, H. Rapp and D. Andor,
"Real-Time Loop Closure in 2D LIDAR SLAM", ICRA 2016 (the precision is theirs).
Dataset keys are the folder names of the shared datasets (``mit-csail`` is the
MIT CSAIL building); ``mit-killian-court`` is the separate MIT Killian Court log.
"""

MAPS_FROM_CORRECTED_LOGS = ("aces", "fr079", "intel", "mit-csail")
"""Datasets of ``PUBLISHED`` that come with a SLAM-corrected log (``<name>-corrected.log.gz``,
the run's scans at the poses of a SLAM solution of it), from which segloc's maps of them are
built: segloc localizes in a map that already holds a solution of the very run the published
graph mapping had to solve, so its row and the published ones are not like for like."""


def published_note(dataset: str, map_source: dict | None) -> str | None:
    """The line under a table of relation errors with ``dataset``'s published rows that says
    how far they compare with segloc's: not like for like where the poses were localized in
    a map built at given poses (``map_source``, the map's ``source`` record, names a
    survey: for these datasets, their corrected log). None where there is nothing to say:
    a map segloc built from the log itself (segment SLAM), or no segloc map known (the
    poses of ``map build --poses-out``, or of another localizer)."""
    if dataset not in MAPS_FROM_CORRECTED_LOGS or not map_source or "survey" not in map_source:
        return None
    return (
        f"Not like for like: segloc localized in a map built from {dataset}'s SLAM-corrected "
        f"log ({dataset}-corrected.log.gz), which holds a solution of the very run that the "
        "published graph mapping had to solve with no map given."
    )


PUBLISHED_SQUARED: dict[str, dict[str, dict[str, tuple[float, float]]]] = {
    "aces": {"GraphMapping": {"trans_sq_m2": (0.004, 0.009), "rot_sq_deg2": (0.3, 0.8)}},
    "intel": {"GraphMapping": {"trans_sq_m2": (0.002, 0.004), "rot_sq_deg2": (24.0, 166.1)}},
    "mit-csail": {"GraphMapping": {"trans_sq_m2": (0.0001, 0.0005), "rot_sq_deg2": (0.01, 0.04)}},
    "mit-killian-court": {
        "GraphMapping": {"trans_sq_m2": (0.006, 0.029), "rot_sq_deg2": (0.9, 0.9)}
    },
    "fr079": {"GraphMapping": {"trans_sq_m2": (0.005, 0.011), "rot_sq_deg2": (0.7, 1.7)}},
}
"""The squared errors of the same source and table as ``PUBLISHED``: dataset →
method → ``trans_sq_m2`` (m²) / ``rot_sq_deg2`` (deg²) → (mean, standard deviation)."""


# --- errors ---------------------------------------------------------------------------


@dataclass(frozen=True)
class RelationErrors:
    """Errors of an estimated trajectory on the relations it covers.

    ``trans_m`` (U,) absolute translational error in metres and ``rot_deg`` (U,)
    absolute rotational error in degrees, [0, 180], one per used relation, in
    file order; ``index`` (U,) the position of each used relation in the
    ``Relations``. ``used`` = U; ``skipped`` counts the relations left out
    because their t1 or t2 has no estimate within the tolerance or the nearest
    estimate is NaN (a failed pose); ``skipped_index`` (S,) their positions and
    ``skipped_why`` (S,) the reason of each in words (``no estimate within 50 ms of t2``).
    """

    trans_m: np.ndarray
    rot_deg: np.ndarray
    used: int
    skipped: int
    index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    skipped_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    skipped_why: tuple[str, ...] = ()

    def summary(self) -> dict:
        """Statistics of the errors as a plain dict.

        ``{"used", "skipped", "trans_m": {"mean", "std", "rms"}, "rot_deg": {"mean",
        "std", "rms"}, "trans_sq_m2": {"mean", "std"}, "rot_sq_deg2": {"mean",
        "std"}}``; ``*_sq_*`` are the squared errors (m², deg²). The standard
        deviation is the sample one (divisor U − 1), as in Cartographer's tool for
        this metric; it is NaN for fewer than two relations, and every statistic
        is NaN when no relation was used.
        """
        trans_m = np.asarray(self.trans_m, dtype=float)
        rot_deg = np.asarray(self.rot_deg, dtype=float)
        return {
            "used": int(self.used),
            "skipped": int(self.skipped),
            "trans_m": {**_mean_std(trans_m), "rms": _rms(trans_m)},
            "rot_deg": {**_mean_std(rot_deg), "rms": _rms(rot_deg)},
            "trans_sq_m2": _mean_std(trans_m**2),
            "rot_sq_deg2": _mean_std(rot_deg**2),
        }


def _mean_std(values: np.ndarray) -> dict[str, float]:
    mean = float(np.mean(values)) if values.size else math.nan
    std = float(np.std(values, ddof=1)) if values.size > 1 else math.nan
    return {"mean": mean, "std": std}


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values**2))) if values.size else math.nan


def relation_errors(
    times_s: np.ndarray,
    poses: np.ndarray,
    relations: Relations,
    tolerance_s: float = TIME_TOLERANCE_MS / 1e3,
    *,
    estimates_path: object = "estimates",
) -> RelationErrors:
    """Errors of the trajectory (``times_s``, ``poses``) on ``relations``.

    ``times_s`` (N,) seconds, ``poses`` (N, 3) ``x_m, y_m, theta_rad`` in any one
    world frame, NaN rows for failed poses. Each relation's t1 and t2 is paired
    with the estimate nearest in time within ``tolerance_s`` (inclusive; see
    ``timing.pair_by_time``): when that time is held by two estimates the
    pairing is refused with an ``InputError`` naming ``estimates_path`` and
    their rows (many relations may share a time; that is no collision). The
    relation is skipped when either time has no estimate or its estimate is
    not finite. For the rest the estimated motion
    δ = x(t1)⁻¹ ⊕ x(t2) is compared with the reference δ* through
    e = δ*⁻¹ ⊕ δ: translational error |e.xy| (m), rotational error
    |wrap(e.θ)| (deg).
    """
    times_s = np.asarray(times_s, dtype=float).reshape(-1)
    poses = np.asarray(poses, dtype=float)
    if poses.ndim != 2 or poses.shape[1] != 3 or len(poses) != len(times_s):
        raise ValueError(
            f"poses must be ({len(times_s)}, 3) x_m y_m theta_rad to match times_s, "
            f"got shape {poses.shape}"
        )
    pair = partial(
        pair_by_time,
        query_path="relations",
        ref_path=estimates_path,
        query_label="relation time",
        ref_label="row",
        distinct_queries=False,
    )
    first = pair(relations.t1_s, times_s, tolerance_s)
    second = pair(relations.t2_s, times_s, tolerance_s)
    matched = (first >= 0) & (second >= 0)
    finite_pose = np.all(np.isfinite(poses), axis=1)
    usable = matched.copy()
    usable[matched] = finite_pose[first[matched]] & finite_pose[second[matched]]
    index = np.flatnonzero(usable)
    skipped_index = np.flatnonzero(~usable)
    within = f"within {1e3 * tolerance_s:g} ms of"
    skipped_why = tuple(
        _why_skipped(first[i], second[i], finite_pose, within) for i in skipped_index
    )

    estimated = relative_motion(poses[first[index]], poses[second[index]])
    reference = np.asarray(relations.delta, dtype=float).reshape(-1, 3)[index]
    # e = δ*⁻¹ ⊕ δ: its translation is R(−θ*)·(δ.xy − δ*.xy), whose length needs no rotation.
    trans_m = np.hypot(estimated[:, 0] - reference[:, 0], estimated[:, 1] - reference[:, 1])
    rot_deg = np.rad2deg(np.abs(wrap_angle(estimated[:, 2] - reference[:, 2])))
    return RelationErrors(
        trans_m=trans_m,
        rot_deg=rot_deg,
        used=int(index.size),
        skipped=int(len(relations) - index.size),
        index=index.astype(np.int64),
        skipped_index=skipped_index.astype(np.int64),
        skipped_why=skipped_why,
    )


def _why_skipped(first: int, second: int, finite_pose: np.ndarray, within: str) -> str:
    """Why a relation whose ends were paired with estimate rows ``first`` and ``second`` (-1:
    none ``within`` the tolerance) has no error: the ends without an estimate, or else
    those whose estimate holds no pose."""
    ends = {"t1": first, "t2": second}
    unpaired = [end for end, row in ends.items() if row < 0]
    if unpaired:
        return f"no estimate {within} {' and '.join(unpaired)}"
    no_pose = [end for end, row in ends.items() if not finite_pose[row]]
    return f"the estimate at {' and '.join(no_pose)} has no accepted pose"


def trajectory_from_estimates(
    estimates: pd.DataFrame, only_ok: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """An estimates frame (``io.tables.read_estimates``) → (``times_s`` (N,), ``poses`` (N, 3)).

    Poses are ``x_m, y_m, theta_rad`` (world frame). With ``only_ok`` they are
    NaN in rows whose status is not an accepted estimate (``ok`` or
    ``recovered``), so that relations landing on them are skipped by
    ``relation_errors``; without it every row keeps its pose, whatever its
    status (rows without one are NaN either way).
    """
    missing = [c for c in ESTIMATE_COLUMNS if c not in estimates.columns]
    if missing:
        raise InputError(f"estimates lack the column(s) {', '.join(missing)}")
    times_s = estimates["time_s"].to_numpy(dtype=float)
    poses = np.column_stack(
        [
            estimates["x_m"].to_numpy(dtype=float),
            estimates["y_m"].to_numpy(dtype=float),
            np.deg2rad(estimates["theta_deg"].to_numpy(dtype=float)),
        ]
    )
    if only_ok:
        ok = estimates["status"].astype(str).isin(ESTIMATED).to_numpy()
        poses[~ok] = np.nan
    return times_s, poses


# --- formats --------------------------------------------------------------------------

_TRANS_DECIMALS = 3  # mm, the paper's precision in metres
_ROT_DECIMALS = 2
_MISSING_MD = "—"
_MISSING_LATEX = "--"

CSV_COLUMNS = (
    "trajectory",
    "used",
    "skipped",
    "trans_mean_m",
    "trans_std_m",
    "trans_rms_m",
    "rot_mean_deg",
    "rot_std_deg",
    "rot_rms_deg",
    "trans_sq_mean_m2",
    "trans_sq_std_m2",
    "rot_sq_mean_deg2",
    "rot_sq_std_deg2",
)
"""Columns of the csv format: one row for the estimate, one per published method."""


def _fixed(value: float, decimals: int, missing: str) -> str:
    if not math.isfinite(value):
        return missing
    text = f"{value:.{decimals}f}"
    return text[1:] if text.startswith("-") and float(text) == 0.0 else text


def _published_number(value: float) -> str:
    # Published values keep the precision they were printed with (0.05 stays 0.05, 1.3 stays 1.3).
    return f"{value:g}"


def _pm(mean: str, std: str) -> str:
    return f"{mean} ± {std}"


def _display_rows(
    summary: dict, published: dict | None, label: str, missing: str
) -> list[list[str]]:
    """Rows of text cells: trajectory, used, skipped, trans mean, trans std, rot mean, rot std."""
    rows = [
        [
            label,
            str(summary["used"]),
            str(summary["skipped"]),
            _fixed(summary["trans_m"]["mean"], _TRANS_DECIMALS, missing),
            _fixed(summary["trans_m"]["std"], _TRANS_DECIMALS, missing),
            _fixed(summary["rot_deg"]["mean"], _ROT_DECIMALS, missing),
            _fixed(summary["rot_deg"]["std"], _ROT_DECIMALS, missing),
        ]
    ]
    for method, values in (published or {}).items():
        trans_mean, trans_std = values["trans_m"]
        rot_mean, rot_std = values["rot_deg"]
        rows.append(
            [
                f"{method} (published)",
                missing,
                missing,
                *(_published_number(v) for v in (trans_mean, trans_std, rot_mean, rot_std)),
            ]
        )
    return rows


def _format_md(summary: dict, published: dict | None, label: str, caveat: str | None) -> str:
    header = ["trajectory", "relations used", "skipped", "trans. error (m)", "rot. error (°)"]
    lines = [
        "| " + " | ".join(header) + " |",
        "|:---|---:|---:|---:|---:|",
    ]
    for name, used, skipped, t_mean, t_std, r_mean, r_std in _display_rows(
        summary, published, label, _MISSING_MD
    ):
        cells = [cell(name), used, skipped, _pm(t_mean, t_std), _pm(r_mean, r_std)]
        lines.append("| " + " | ".join(cells) + " |")
    note = (
        "Absolute errors per relation, mean ± standard deviation "
        "(relative-pose metric of Kümmerle et al. 2009)."
    )
    if published:
        note += f" Published rows: {PUBLISHED_SOURCE}."
    if published and caveat:
        note += f"\n\n{caveat}"
    return "\n".join(lines) + f"\n\n{note}\n"


def _format_latex(summary: dict, published: dict | None, label: str) -> str:
    """A booktabs ``tabular``, its first line saying it needs booktabs (``latex.py``)."""
    lines = [
        r"\begin{tabular}{lrrrr}",
        r"\toprule",
        r"Trajectory & Used & Skipped & Trans.\ error (m) & Rot.\ error ($^\circ$) \\",
        r"\midrule",
    ]
    for name, used, skipped, t_mean, t_std, r_mean, r_std in _display_rows(
        summary, published, label, _MISSING_LATEX
    ):
        trans = _MISSING_LATEX if _MISSING_LATEX in (t_mean, t_std) else f"${t_mean} \\pm {t_std}$"
        rot = _MISSING_LATEX if _MISSING_LATEX in (r_mean, r_std) else f"${r_mean} \\pm {r_std}$"
        lines.append(f"{latex_text(name)} & {used} & {skipped} & {trans} & {rot} \\\\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    return with_needs("\n".join(lines))


def _csv_numbers(values: list[float | None]) -> list[str]:
    """The numeric fields of a row (the columns after ``skipped``), each rounded to the unit
    of its column; empty where a value is missing or not finite."""
    return [
        "" if v is None or not math.isfinite(v) else number_text(v, unit_of(column))
        for v, column in zip(values, CSV_COLUMNS[3:], strict=True)
    ]


def _format_csv(summary: dict, published: dict | None, label: str) -> str:
    stream = io.StringIO()
    writer = csv.writer(stream, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    numbers = [
        *(summary["trans_m"][k] for k in ("mean", "std", "rms")),
        *(summary["rot_deg"][k] for k in ("mean", "std", "rms")),
        *(summary["trans_sq_m2"][k] for k in ("mean", "std")),
        *(summary["rot_sq_deg2"][k] for k in ("mean", "std")),
    ]
    writer.writerow([label, str(summary["used"]), str(summary["skipped"]), *_csv_numbers(numbers)])
    for method, values in (published or {}).items():
        (trans_mean, trans_std), (rot_mean, rot_std) = values["trans_m"], values["rot_deg"]
        numbers = [trans_mean, trans_std, None, rot_mean, rot_std, None, *[None] * 4]
        writer.writerow([f"{method} (published)", "", "", *_csv_numbers(numbers)])
    return stream.getvalue()


def _json_ready(value: object) -> object:
    if isinstance(value, dict):
        return {str(k): _json_ready(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_ready(v) for v in value]
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def published_json(published: dict) -> dict:
    """A dataset's entry of ``PUBLISHED`` as the JSON format gives it: method → error →
    {"mean", "std"}."""
    return {
        method: {
            name: {"mean": float(values[name][0]), "std": float(values[name][1])}
            for name in ("trans_m", "rot_deg")
        }
        for method, values in published.items()
    }


def _format_json(summary: dict, published: dict | None, label: str, caveat: str | None) -> str:
    document: dict[str, object] = {"trajectory": label, "summary": _json_ready(summary)}
    if published:
        document["published"] = published_json(published)
        document["published_source"] = PUBLISHED_SOURCE
        if caveat:
            document["published_note"] = caveat
    return json_text(document, ensure_ascii=False)


def format_relations(
    summary: dict,
    fmt: str,
    published: dict | None = None,
    label: str = "segloc",
    published_caveat: str | None = None,
) -> str:
    """Render a ``RelationErrors.summary()`` as text in format ``fmt``.

    ``published``, when given, is one dataset's entry of ``PUBLISHED``
    (method → {"trans_m": (mean, std), "rot_deg": (mean, std)}) and adds a row
    per method, with ``published_caveat`` (``published_note``) under the table where
    given; ``label`` names the estimates' row (``segloc evaluate``: the estimates file's name).

    - ``md``: a Markdown table (trajectory, relations used, skipped, translational
      and rotational error mean ± std at 1 mm and 0.01°), a note on the metric and
      the published rows' source, and the caveat on its own line.
    - ``csv``: ``CSV_COLUMNS``, empty where a value is missing.
    - ``latex``: a booktabs ``tabular`` of the md content.
    - ``json``: ``{"trajectory", "summary", "published", "published_source",
      "published_note"}``, NaN written as null; the last three only with ``published``,
      the caveat only where given.

    Numbers of csv and json are rounded to the precision of their unit (``numbers.py``).
    """
    if fmt == "md":
        return _format_md(summary, published, label, published_caveat)
    if fmt == "csv":
        return _format_csv(summary, published, label)
    if fmt == "latex":
        return _format_latex(summary, published, label)
    if fmt == "json":
        return _format_json(summary, published, label, published_caveat)
    raise ValueError(f"unknown relations format {fmt!r}; choose one of {', '.join(FORMATS)}")
