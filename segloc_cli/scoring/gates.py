"""CI gates on scored estimates: what each gate asked, what was measured, and whether it held.

A gate bounds either each pose (``|X|`` and ``|Y|`` each, the position error's magnitude,
``|θ|``) or a figure over all of them (RMS, mean or a percentile of the position and heading
errors, the share of poses within the per-pose limits). With relations as the truth, the
figures are over the relations' translational and rotational errors instead, and there is
no per-pose bound. ``GateOutcome`` is one gate's result, as the Markdown summary, the JUnit
file and the HTML report show it; every function here is pure.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields

import numpy as np
import pandas as pd

from segloc_cli.estimates import ESTIMATED, STATUS_NO_ESTIMATE
from segloc_cli.wording import counted

# Errors pass through degree/radian conversions; a pose exactly at a limit must not fail on
# the last bits of that round trip.
GATE_SLACK = 1e-9

_DECIMALS = {"cm": 1, "°": 2, "%": 1}


def with_unit(text: str, unit: str) -> str:
    """A number's ``text`` with its ``unit``: degrees close up (``1.5°``), others spaced
    (``1.5 cm``, ``80 %``)."""
    return text + unit if unit == "°" else f"{text} {unit}"


def _with_unit(value: float, unit: str, decimals: int | None = None) -> str:
    if not math.isfinite(value):
        return "none"
    return with_unit(f"{value:g}" if decimals is None else f"{value:.{decimals}f}", unit)


@dataclass(frozen=True)
class GateOutcome:
    """One gate's result: ``name`` says what it bounds in words (``"RMS position error"``),
    ``measured`` and ``limit`` are in ``unit`` (``"cm"``, ``"°"`` or ``"%"``), ``passed``
    whether the gate held (``at_least``: ``limit`` is a lower bound, as for the share of
    poses within limits; otherwise an upper bound). ``measured`` is NaN when nothing was
    there to measure, which fails the gate. ``per_pose``: the gate sums up the per-pose
    limits (their max, or the share of poses within them), so the poses beyond them say
    why it failed; ``coverage``: it bounds the share of the truth that has an estimate, so
    the poses (or relations) without one say why. ``detail`` holds the counts behind the
    measure (``"34 of 340"``), which change from run to run while ``title`` does not."""

    name: str
    measured: float
    limit: float
    unit: str
    passed: bool
    at_least: bool = False
    per_pose: bool = False
    coverage: bool = False
    detail: str = ""

    @property
    def bound(self) -> str:
        """The limit with its sense: ``≤ 5 cm``, ``≥ 100 %``."""
        return f"{'≥' if self.at_least else '≤'} {_with_unit(self.limit, self.unit)}"

    @property
    def title(self) -> str:
        """What the gate asks, the same in every run with the same options: ``RMS position
        error ≤ 5 cm``; the name of its JUnit test case."""
        return f"{self.name} {self.bound}"

    @property
    def holds(self) -> bool:
        """Whether ``measured`` keeps to ``limit`` (a gate may fail for another reason its
        ``detail`` gives, such as poses without an estimate)."""
        return _keeps_to(self.measured, self.limit, self.at_least)

    @property
    def result(self) -> str:
        """The measure against the limit, with the counts: ``3.2 cm ≤ 5 cm``, ``10.0 % < 100 %
        (34 of 340)``."""
        if self.at_least:
            sign = "≥" if self.holds else "<"
        else:
            sign = "≤" if self.holds else ">"
        measured = _with_unit(self.measured, self.unit, _DECIMALS.get(self.unit, 2))
        detail = f" ({self.detail})" if self.detail else ""
        return f"{measured} {sign} {_with_unit(self.limit, self.unit)}{detail}"

    @property
    def text(self) -> str:
        """The outcome in one phrase: ``RMS position error 3.2 cm ≤ 5 cm: pass``."""
        return f"{self.name} {self.result}: {'pass' if self.passed else 'FAIL'}"


def _keeps_to(measured: float, limit: float, at_least: bool) -> bool:
    """Whether ``measured`` is finite and within ``GATE_SLACK`` of keeping to ``limit``, a
    lower bound when ``at_least``, else an upper one."""
    if not math.isfinite(measured):
        return False
    return measured >= limit - GATE_SLACK if at_least else measured <= limit + GATE_SLACK


def _outcome(
    name: str,
    measured: float,
    limit: float,
    unit: str,
    at_least: bool = False,
    per_pose: bool = False,
    coverage: bool = False,
    detail: str = "",
    also: bool = True,
) -> GateOutcome:
    """The outcome of a gate that holds when ``measured`` keeps to ``limit`` and ``also``."""
    passed = _keeps_to(measured, limit, at_least) and also
    return GateOutcome(
        name,
        float(measured),
        float(limit),
        unit,
        bool(passed),
        at_least,
        per_pose,
        coverage,
        detail,
    )


@dataclass(frozen=True)
class Gates:
    """The limits asked for; None where not set.

    Per pose (survey only): ``axis_cm`` bounds |X| and |Y| each, ``xy_cm`` the position
    error's magnitude, ``deg`` |θ|; a pose fails when beyond one of them, or not accepted
    (status other than ``ok``/``recovered``), or missing a bounded error.
    ``min_within_pct`` is the share (%) of poses that must pass them (default: all).
    ``min_paired_pct`` bounds the share (%) of surveyed poses (or relations) that have an
    estimate at all (``EvaluateOptions`` sets it to 100 whenever another gate is given).
    Over all poses (or relations): ``rms_cm``, ``rms_deg``, ``mean_cm``, ``mean_deg``,
    ``percentile_cm``, ``percentile_deg`` bound the RMS, mean and ``percentile``-th
    percentile of the position (translational) error in cm and the heading (rotational)
    error in degrees.
    """

    axis_cm: float | None = None
    xy_cm: float | None = None
    deg: float | None = None
    min_within_pct: float | None = None
    min_paired_pct: float | None = None
    rms_cm: float | None = None
    rms_deg: float | None = None
    mean_cm: float | None = None
    mean_deg: float | None = None
    percentile_cm: float | None = None
    percentile_deg: float | None = None
    percentile: float = 95.0

    def __post_init__(self) -> None:
        for field in fields(self):
            value = getattr(self, field.name)
            if value is not None and not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{field.name} must be a non-negative number, got {value}")
        if not 0.0 <= self.percentile <= 100.0:
            raise ValueError(f"percentile must lie in [0, 100], got {self.percentile}")

    @property
    def per_pose(self) -> bool:
        """Whether any limit bounds each pose."""
        return any(v is not None for v in (self.axis_cm, self.xy_cm, self.deg))

    @property
    def overall(self) -> bool:
        """Whether any limit bounds a figure over all poses (or relations)."""
        figures = (self.rms_cm, self.rms_deg, self.mean_cm, self.mean_deg)
        return any(v is not None for v in (*figures, self.percentile_cm, self.percentile_deg))

    @property
    def any(self) -> bool:
        limits = (self.min_within_pct, self.min_paired_pct)
        return self.per_pose or self.overall or any(v is not None for v in limits)

    def limits_text(self) -> str:
        """The per-pose limits in words: ``|X|, |Y| ≤ 5 cm; |XY| ≤ 7 cm; |θ| ≤ 1°``."""
        parts = []
        if self.axis_cm is not None:
            parts.append(f"|X|, |Y| ≤ {_with_unit(self.axis_cm, 'cm')}")
        if self.xy_cm is not None:
            parts.append(f"|XY| ≤ {_with_unit(self.xy_cm, 'cm')}")
        if self.deg is not None:
            parts.append(f"|θ| ≤ {_with_unit(self.deg, '°')}")
        return "; ".join(parts)

    def _checks(self) -> list[tuple[str, str, float, int, str]]:
        """(label, column, limit, decimals, unit) of each per-pose bound."""
        checks = []
        if self.axis_cm is not None:
            checks += [
                ("X", "err_x_cm", self.axis_cm, 1, " cm"),
                ("Y", "err_y_cm", self.axis_cm, 1, " cm"),
            ]
        if self.xy_cm is not None:
            checks += [("XY", "err_xy_cm", self.xy_cm, 1, " cm")]
        if self.deg is not None:
            checks += [("θ", "err_theta_deg", self.deg, 2, "°")]
        return checks


def _exceeding_pair(value: float, limit: float, decimals: int) -> tuple[str, str]:
    """``value`` and ``limit`` as text, with enough decimals to show value > limit."""
    # At the table's precision 1.04 cm against a 1.0 cm gate would read "1.0 cm > 1.0 cm".
    while decimals < 9 and (
        round(value, decimals) <= round(limit, decimals) or round(limit, decimals) != limit
    ):
        decimals += 1
    return f"{value:.{decimals}f}", f"{limit:.{decimals}f}"


def beyond_mask(table: pd.DataFrame, gates: Gates) -> np.ndarray:
    """(N,) bool: the poses of a Table 1 whose error exceeds a per-pose limit."""
    beyond = np.zeros(len(table), dtype=bool)
    for _, column, limit, _, _ in gates._checks():
        values = np.abs(table[column].to_numpy(dtype=float))
        with np.errstate(invalid="ignore"):
            beyond |= np.isfinite(values) & (values > limit + GATE_SLACK)
    return beyond


def failing_mask(table: pd.DataFrame, gates: Gates) -> np.ndarray:
    """(N,) bool: the rows of a Table 1 that fail the per-pose limits, as ``pose_failures``
    says (all False without such limits); rows need not have distinct pose ids."""
    checks = gates._checks()
    if not checks:
        return np.zeros(len(table), dtype=bool)
    bounded = table[[column for _, column, *_ in checks]].to_numpy(dtype=float)
    missing = ~np.all(np.isfinite(bounded), axis=1)
    accepted = table["status"].isin(ESTIMATED).to_numpy()
    return beyond_mask(table, gates) | missing | ~accepted


def pairing_within(table: pd.DataFrame) -> str:
    """How near in time a Table 1's poses were paired with estimates, in words: ``within 50
    ms`` (the tolerance in the table's ``attrs``), or "" where it does not say."""
    tolerance_s = table.attrs.get("tolerance_s")
    return "" if tolerance_s is None else f"within {1e3 * float(tolerance_s):g} ms"


def missing_reason(table: pd.DataFrame) -> str:
    """Why a surveyed pose of a Table 1 without an estimate fails: ``no estimate within 50
    ms`` (``pairing_within``)."""
    return f"no estimate {pairing_within(table)}".rstrip()


def unpaired_mask(table: pd.DataFrame) -> np.ndarray:
    """(N,) bool: the surveyed poses of a Table 1 that no estimate was paired with."""
    return (table["status"] == STATUS_NO_ESTIMATE).to_numpy()


def pose_failures(table: pd.DataFrame, gates: Gates) -> dict[int, list[str]]:
    """Why each pose of a Table 1 fails the per-pose limits or the pairing (pose id →
    reasons, in table order; only failing poses), empty without such gates: no estimate
    paired with it (``missing_reason``; with a per-pose limit or ``min_paired_pct``), a
    status other than an accepted one (the one reason given then), a bounded error
    missing, or one beyond its limit (``|X| 1.04 cm > 1.00 cm``)."""
    checks = gates._checks()
    if not checks and gates.min_paired_pct is None:
        return {}
    columns = {column: np.abs(table[column].to_numpy(dtype=float)) for _, column, *_ in checks}
    missing = missing_reason(table)
    failures: dict[int, list[str]] = {}
    for row, (pose_id, status) in enumerate(zip(table["pose_id"], table["status"], strict=True)):
        if status == STATUS_NO_ESTIMATE:
            failures[int(pose_id)] = [missing]
            continue
        if not checks:
            continue
        if status not in ESTIMATED:
            failures[int(pose_id)] = [f"status {status}"]
            continue
        reasons = []
        for label, column, limit, decimals, unit in checks:
            value = columns[column][row]
            if not np.isfinite(value):
                reasons.append(f"{label} error is missing")
            elif value > limit + GATE_SLACK:
                value_text, limit_text = _exceeding_pair(value, limit, decimals)
                reasons.append(f"|{label}| {value_text}{unit} > {limit_text}{unit}")
        if reasons:
            failures[int(pose_id)] = reasons
    return failures


def _figure_outcomes(
    position_cm: np.ndarray, heading_deg: np.ndarray, gates: Gates, noun: tuple[str, str]
) -> list[GateOutcome]:
    """The RMS, mean and percentile gates over finite errors (magnitudes), in gate order."""
    position = np.abs(position_cm[np.isfinite(position_cm)])
    heading = np.abs(heading_deg[np.isfinite(heading_deg)])

    def stat(values: np.ndarray, how: str) -> float:
        if values.size == 0:
            return math.nan
        if how == "rms":
            return float(np.sqrt(np.mean(values**2)))
        if how == "mean":
            return float(np.mean(values))
        return float(np.percentile(values, gates.percentile))

    pct = f"{gates.percentile:g}th percentile"
    wanted = (
        ("rms", "RMS", gates.rms_cm, gates.rms_deg),
        ("mean", "mean", gates.mean_cm, gates.mean_deg),
        ("percentile", pct, gates.percentile_cm, gates.percentile_deg),
    )
    outcomes = []
    for how, label, limit_cm, limit_deg in wanted:
        if limit_cm is not None:
            name = f"{label} {noun[0]} error"
            outcomes.append(_outcome(name, stat(position, how), limit_cm, "cm"))
        if limit_deg is not None:
            name = f"{label} {noun[1]} error"
            outcomes.append(_outcome(name, stat(heading, how), limit_deg, "°"))
    return outcomes


def coverage_outcome(
    n_paired: int, n_truth: int, limit: float, noun: str, within: str, having: str
) -> GateOutcome:
    """The gate on the share (%) of ``n_truth`` surveyed poses or relations (``noun``, the
    singular) ``having`` an estimate (``n_paired`` do; ``within``: how near, in words)."""
    share = 100.0 * n_paired / n_truth if n_truth else math.nan
    return _outcome(
        f"share of {noun}s {having}",
        share,
        limit,
        "%",
        at_least=True,
        coverage=True,
        detail=f"{n_paired} of {n_truth} {within}".rstrip(),
    )


def survey_outcomes(table: pd.DataFrame, scored: np.ndarray, gates: Gates) -> list[GateOutcome]:
    """Every gate's outcome on a Table 1 (its surveyed poses without an estimate among its
    rows, ``STATUS_NO_ESTIMATE``): the share of surveyed poses paired with an estimate,
    the max of each per-pose bound (over the poses with an estimate, and failed by any
    pose without one) unless ``min_within_pct`` relaxes them, the share of poses passing
    the per-pose limits, then the RMS, mean and percentile gates over the ``scored`` poses
    ((N,) bool: the poses the summary covers)."""
    outcomes = []
    n = len(table)
    if gates.min_paired_pct is not None:
        paired = n - int(np.count_nonzero(unpaired_mask(table)))
        within = pairing_within(table)
        outcomes.append(
            coverage_outcome(
                paired, n, gates.min_paired_pct, "surveyed pose", within, "with an estimate"
            )
        )
    if gates.per_pose and gates.min_within_pct is None:
        for label, column, limit, unit in _grouped_checks(gates):
            values = np.abs(table[list(column)].to_numpy(dtype=float))
            finite_rows = np.all(np.isfinite(values), axis=1)
            measured = float(values[finite_rows].max()) if finite_rows.any() else math.nan
            n_without = n - int(np.count_nonzero(finite_rows))
            detail = f"{n_without} of {counted(n, 'pose')} without an estimate" if n_without else ""
            outcomes.append(
                _outcome(
                    f"max {label}",
                    measured,
                    limit,
                    unit,
                    per_pose=True,
                    detail=detail,
                    also=not n_without,
                )
            )
    if gates.per_pose:
        passing = n - len(pose_failures(table, gates))
        required = 100.0 if gates.min_within_pct is None else gates.min_within_pct
        name = f"share of poses accepted and within {gates.limits_text()}"
        share = 100.0 * passing / n if n else math.nan
        detail = f"{passing} of {counted(n, 'pose')}"
        outcomes.append(
            _outcome(name, share, required, "%", at_least=True, per_pose=True, detail=detail)
        )
    elif gates.min_within_pct is not None:
        raise ValueError("min_within_pct needs a per-pose limit")
    position = table["err_xy_cm"].to_numpy(dtype=float)[scored]
    heading = table["err_theta_deg"].to_numpy(dtype=float)[scored]
    return outcomes + _figure_outcomes(position, heading, gates, ("position", "heading"))


def _grouped_checks(gates: Gates) -> list[tuple[str, tuple[str, ...], float, str]]:
    """Per-pose bounds as the max gates name them: |X| and |Y| together."""
    grouped: list[tuple[str, tuple[str, ...], float, str]] = []
    if gates.axis_cm is not None:
        grouped.append(("|X|, |Y|", ("err_x_cm", "err_y_cm"), gates.axis_cm, "cm"))
    if gates.xy_cm is not None:
        grouped.append(("position error |XY|", ("err_xy_cm",), gates.xy_cm, "cm"))
    if gates.deg is not None:
        grouped.append(("|θ|", ("err_theta_deg",), gates.deg, "°"))
    return grouped


def relation_outcomes(
    trans_cm: np.ndarray, rot_deg: np.ndarray, gates: Gates, n_relations: int, within: str = ""
) -> list[GateOutcome]:
    """The gates over relation errors: the share of the ``n_relations`` reference relations
    with estimates at both ends (``within``: how near, in words) when ``min_paired_pct``
    is set, then the RMS, mean and percentile of the translational (cm) and rotational (°)
    errors, one value per used relation."""
    if gates.per_pose or gates.min_within_pct is not None:
        raise ValueError("relations take no per-pose limit")
    outcomes = []
    if gates.min_paired_pct is not None:
        used, limit = int(np.size(trans_cm)), gates.min_paired_pct
        having = "estimated at both ends"
        outcomes.append(coverage_outcome(used, n_relations, limit, "relation", within, having))
    return outcomes + _figure_outcomes(trans_cm, rot_deg, gates, ("translational", "rotational"))


def failed(outcomes: list[GateOutcome]) -> list[GateOutcome]:
    """The outcomes that did not pass."""
    return [o for o in outcomes if not o.passed]


def outcomes_json(outcomes: list[GateOutcome]) -> list[Mapping[str, object]]:
    """The outcomes as plain JSON values (NaN as None)."""
    return [
        {
            "name": o.name,
            "measured": o.measured if math.isfinite(o.measured) else None,
            "limit": o.limit,
            "unit": o.unit,
            "at_least": o.at_least,
            "per_pose": o.per_pose,
            "coverage": o.coverage,
            "detail": o.detail,
            "passed": o.passed,
        }
        for o in outcomes
    ]


def judged(missing: bool, outcomes: list[GateOutcome]) -> bool:
    """Whether a pose (relation) with reasons to fail fails the run's verdict: a per-pose gate
    failed, or it has no estimate and a gate on the share with one failed. A pose beyond
    its limits that ``min_within_pct`` tolerates, or one without an estimate that
    ``min_paired_pct`` tolerates, does not."""
    failed = [o for o in outcomes if not o.passed]
    return any(o.per_pose for o in failed) or (missing and any(o.coverage for o in failed))
