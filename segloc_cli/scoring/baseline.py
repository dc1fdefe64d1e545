"""Did a run get worse than an earlier one, beyond what noise explains?

The earlier run is the JSON that ``segloc evaluate ... --format json`` wrote (its
``"poses"``); the later one a ``table1`` result. The runs are paired pose by pose
(``pose_id``), so the comparison measures one change of the localizer on the same
surveyed poses, not two samples of poses. Each figure (RMS of X, Y, |XY| and θ; mean
|XY| and mean |θ|; cm and degrees, errors surveyed minus computed) is computed for both
runs, and the 95 % interval of its change (now minus baseline) comes from a paired
bootstrap: the shared poses are resampled with replacement, the same draws for both runs,
so that what the poses have in common cancels and only the change is left to vary.

A figure fails when its whole interval lies above the limit given for its unit: the run
is worse by more than the limit, and noise alone would rarely say so.
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import asdict, dataclass
from typing import NamedTuple

import numpy as np
import pandas as pd

from segloc_cli.errors import InputError
from segloc_cli.estimates import ESTIMATED
from segloc_cli.limits import MAX_ABS_ID, MAX_COORDINATE_M
from segloc_cli.markdown import cell
from segloc_cli.numbers import rounded_frame
from segloc_cli.scoring.gates import (
    GATE_SLACK,
    GateOutcome,
    coverage_outcome,
    outcomes_json,
    with_unit,
)
from segloc_cli.wording import counted

ERROR_KEYS = ("err_x_cm", "err_y_cm", "err_xy_cm", "err_theta_deg")
"""The final errors a baseline's poses carry (cm, cm, cm, degrees)."""

POSE_KEYS = ("pose_id", *ERROR_KEYS, "status")
"""What every pose of a baseline must have."""

ERROR_BOUNDS = {"cm": 400.0 * MAX_COORDINATE_M, "°": 360.0}
"""The largest final error (by unit) a baseline may hold: two positions within ±10^7 m lie
less than 4·10^9 cm apart, and evaluate wraps headings to ±180°. A larger value (or one not
finite) is no run of evaluate, and its square could overflow the comparison's sums."""

HOW_TO_MAKE = "make one with `segloc evaluate ... --format json --out OLD.json`"

WORSE = "worse"
"""The interval lies wholly above the limit: the figure fails."""
WORSE_WITHIN_LIMIT = "worse, within limit"
"""The interval lies above 0, but not wholly above the limit (or no limit was given)."""
NO_CHANGE = "no change shown"
"""The interval holds 0."""
BETTER = "better"
"""The interval lies wholly below 0."""
NOT_COMPARED = "cannot be compared"
"""The figure or its interval is not a finite number: with a limit, the figure fails."""

CONFIDENCE = 0.95
"""Coverage of the bootstrap interval of each change."""
_INTERVAL = f"{CONFIDENCE * 100:g} % interval"


@dataclass(frozen=True)
class _Figure:
    name: str
    unit: str
    column: str
    rms: bool
    """True: root of the mean square; False: mean of the absolute values."""


_FIGURES = (
    _Figure("RMS X", "cm", "err_x_cm", rms=True),
    _Figure("RMS Y", "cm", "err_y_cm", rms=True),
    _Figure("RMS |XY|", "cm", "err_xy_cm", rms=True),
    _Figure("RMS θ", "°", "err_theta_deg", rms=True),
    _Figure("mean |XY|", "cm", "err_xy_cm", rms=False),
    _Figure("mean |θ|", "°", "err_theta_deg", rms=False),
)
_DECIMALS = {"cm": 1, "°": 2}


@dataclass(frozen=True)
class ComparisonRow:
    """One figure of both runs: ``baseline`` and ``now`` in ``unit`` (``"cm"`` or ``"°"``),
    ``change`` = now − baseline, ``low``..``high`` its 95 % bootstrap interval, ``limit``
    the worsening allowed for the unit (None: none given) and the ``verdict`` (``WORSE``,
    ``WORSE_WITHIN_LIMIT``, ``NO_CHANGE``, ``BETTER``)."""

    figure: str
    unit: str
    baseline: float
    now: float
    change: float
    low: float
    high: float
    limit: float | None
    verdict: str

    @property
    def failed(self) -> bool:
        """Worse by more than the limit, or not comparable where a limit is given: a
        comparison that cannot be made never passes."""
        return self.verdict == WORSE or (self.verdict == NOT_COMPARED and self.limit is not None)


@dataclass(frozen=True)
class Comparison:
    """A run against its baseline: a ``ComparisonRow`` per figure, over the ``n_shared``
    poses both runs have and score; ``n_only_baseline`` and ``n_only_now`` poses were in one
    run only, ``n_left_out`` in both but left out (an error missing, or with ``only_ok`` a
    status not accepted, in at least one run). ``failed``: some figure is worse beyond
    its limit."""

    rows: list[ComparisonRow]
    n_shared: int
    n_only_baseline: int
    n_only_now: int
    n_left_out: int
    only_ok: bool
    failed: bool
    n_baseline: int = 0
    fewer: GateOutcome | None = None

    @property
    def outcomes(self) -> list[GateOutcome]:
        """The share of the baseline's poses compared, when bounded (``fewer``), then a gate
        per figure that has a limit: the low end of its interval against it."""
        figures = [
            GateOutcome(
                f"{row.figure} worse than the baseline's by",
                row.low,
                row.limit,
                row.unit,
                not row.failed,
                detail=f"the low end of the {_INTERVAL}",
            )
            for row in self.rows
            if row.limit is not None
        ]
        return ([] if self.fewer is None else [self.fewer]) + figures

    @property
    def failures(self) -> list[str]:
        """The figures worse beyond their limit, a phrase each, after the shortfall of poses
        compared when it failed."""
        fewer = [] if self.fewer is None or self.fewer.passed else [self.fewer.text]
        return fewer + [
            f"{row.figure} {NOT_COMPARED} (not a finite number)"
            if row.verdict == NOT_COMPARED
            else f"{row.figure} worse by {with_unit(_num(row.change, row.unit), row.unit)} "
            f"({_INTERVAL} {with_unit(_interval(row), row.unit)}) beyond "
            f"{with_unit(f'{row.limit:g}', row.unit)}"
            for row in self.rows
            if row.failed and row.limit is not None
        ]

    def _counts_line(self) -> str:
        why = "an error missing or a status not accepted" if self.only_ok else "an error missing"
        line = (
            f"{self.n_shared} poses of both runs compared; {self.n_only_baseline} only in the "
            f"baseline, {self.n_only_now} only in this run; {self.n_left_out} of both left out "
            f"({why} in at least one run)."
        )
        if self.fewer is not None:
            verdict = "pass" if self.fewer.passed else "FAIL"
            compared = self.fewer.result
            line += f" Poses compared, of those the baseline scored: {compared}: {verdict}."
        return line

    def _verdict_line(self) -> str:
        limits = {row.unit: row.limit for row in self.rows if row.limit is not None}
        if not limits:
            return "No limit given: no figure can fail."
        worse_by = " or ".join(
            f"{with_unit(f'{limit:g}', unit)} ({unit} figures)" for unit, limit in limits.items()
        )
        failing = [row.figure for row in self.rows if row.failed]
        verdict = f"{', '.join(failing)} worse beyond it: FAIL" if failing else "none is: pass"
        return f"A figure fails when its whole interval lies above {worse_by}; {verdict}."

    def lines(self) -> list[str]:
        """The comparison in plain lines: one per figure, then the counts and the verdict."""
        figures = [
            f"{row.figure}: {with_unit(_num(row.baseline, row.unit), row.unit)} → "
            f"{with_unit(_num(row.now, row.unit), row.unit)}, change "
            f"{with_unit(_num(row.change, row.unit, sign=True), row.unit)} ({_INTERVAL} "
            f"{with_unit(_interval(row), row.unit)}): {row.verdict}"
            for row in self.rows
        ]
        return [*figures, self._counts_line(), self._verdict_line()]

    def format_md(self) -> str:
        """A Markdown table (figure, baseline, now, change, 95 % interval, verdict; cm to 0.1,
        degrees to 0.01), then the counts of poses and the verdict, one line each."""
        header = ["figure", "baseline", "now", "change", _INTERVAL, "verdict"]
        rows = [
            [
                # A bare "|" would end the cell.
                cell(f"{row.figure} ({row.unit})"),
                _num(row.baseline, row.unit),
                _num(row.now, row.unit),
                _num(row.change, row.unit, sign=True),
                _interval(row),
                row.verdict,
            ]
            for row in self.rows
        ]
        table = [header, ["---", *("---:" for _ in range(4)), "---"], *rows]
        body = "\n".join("| " + " | ".join(cells) + " |" for cells in table)
        return f"{body}\n\n{self._counts_line()}\n{self._verdict_line()}\n"

    def as_json(self) -> dict:
        """The comparison as JSON values: ``figures`` (the rows' fields and ``failed``), the
        counts, ``only_ok`` and ``failed``; NaN as None."""
        figures = [
            {
                key: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for key, v in asdict(row).items()
            }
            | {"failed": row.failed}
            for row in self.rows
        ]
        return {
            "figures": figures,
            "n_baseline": self.n_baseline,
            "n_shared": self.n_shared,
            "n_only_baseline": self.n_only_baseline,
            "n_only_now": self.n_only_now,
            "n_left_out": self.n_left_out,
            "only_ok": self.only_ok,
            "fewer": None if self.fewer is None else outcomes_json([self.fewer])[0],
            "failed": self.failed,
        }


def _num(value: float, unit: str, sign: bool = False) -> str:
    text = f"{value:{'+' if sign else ''}.{_DECIMALS[unit]}f}"
    # A sign the precision shown cannot support reads as a change that is not there.
    return text.replace("+", "").replace("-", "") if float(text) == 0.0 else text


def _interval(row: ComparisonRow) -> str:
    return f"[{_num(row.low, row.unit, sign=True)}, {_num(row.high, row.unit, sign=True)}]"


def parse_baseline(text: str, path: object = "baseline") -> dict:
    """``text`` as a baseline: a JSON object whose ``"poses"`` list holds, for every pose,
    ``pose_id`` (a unique integer within int64), ``err_x_cm``, ``err_y_cm``, ``err_xy_cm``
    (cm), ``err_theta_deg`` (degrees; each null or a finite number within ``ERROR_BOUNDS``)
    and ``status``. Returns the object. Raises a one-line ``InputError`` naming ``path`` and
    what is wrong, a file nested too deeply among them."""
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(
            f"not JSON ({exc.msg}, line {exc.lineno}); a baseline is the JSON of evaluate: "
            + HOW_TO_MAKE,
            path=path,
        ) from None
    except RecursionError:
        raise InputError(
            "its JSON is nested too deeply to be the JSON of evaluate; " + HOW_TO_MAKE, path=path
        ) from None
    except ValueError:  # an integer of more digits than Python converts
        raise InputError(
            "holds a number too long to read, so it is not the JSON of evaluate; " + HOW_TO_MAKE,
            path=path,
        ) from None
    _baseline_run(data, path)
    return data


class _Run(NamedTuple):
    """One run's poses: ``pose_id`` (n,) unique, ``errors`` (n, 4) in ERROR_KEYS order (cm,
    cm, cm, degrees; NaN where missing) and ``accepted`` (n,) bool, status in ESTIMATED."""

    pose_id: np.ndarray
    errors: np.ndarray
    accepted: np.ndarray


def _baseline_run(data: object, path: object) -> _Run:
    """The poses of a baseline's JSON object, checked; one-line ``InputError`` otherwise."""
    poses = data.get("poses") if isinstance(data, dict) else None
    if not isinstance(poses, list):
        raise InputError(
            'has no "poses" list, so it is not a table of evaluate; ' + HOW_TO_MAKE, path=path
        )
    for i, pose in enumerate(poses):
        missing = [key for key in POSE_KEYS if not isinstance(pose, dict) or key not in pose]
        if missing:
            raise InputError(f"poses[{i}] lacks {', '.join(missing)}; {HOW_TO_MAKE}", path=path)
        _check_pose(pose, i, path)
    errors = [[math.nan if p[key] is None else p[key] for key in ERROR_KEYS] for p in poses]
    run = _Run(
        np.array([p["pose_id"] for p in poses], dtype=np.int64),
        np.array(errors, dtype=float).reshape(-1, len(ERROR_KEYS)),
        np.array([p["status"] in ESTIMATED for p in poses], dtype=bool),
    )
    _refuse_repeated_ids(run.pose_id, path, "the baseline")
    return run


def _check_pose(pose: dict, i: int, path: object) -> None:
    """Refuse the ``i``-th pose of a baseline unless its id is an integer within int64 and
    each error null or a finite number within ``ERROR_BOUNDS``."""
    pose_id = pose["pose_id"]
    if not isinstance(pose_id, int) or isinstance(pose_id, bool):
        raise InputError(f"poses[{i}]: pose_id {pose_id!r} is not an integer", path=path)
    if abs(pose_id) > MAX_ABS_ID:
        raise InputError(
            f"poses[{i}]: pose_id {_shown(pose_id)} is not an integer within ±{MAX_ABS_ID}",
            path=path,
        )
    for key, unit in zip(ERROR_KEYS, ("cm", "cm", "cm", "°"), strict=True):
        value = pose[key]
        if value is None:
            continue
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise InputError(f"poses[{i}]: {key} {value!r} is not a number or null", path=path)
        bound = ERROR_BOUNDS[unit]
        if not abs(value) <= bound:
            raise InputError(
                f"poses[{i}]: {key} {_shown(value)} is no error evaluate gives (a finite "
                f"number within ±{with_unit(f'{bound:g}', unit)}); {HOW_TO_MAKE}",
                path=path,
            )


def _shown(value: float) -> str:
    """A number of a baseline as its message shows it: an integer of many digits by its
    first ones and its length."""
    text = repr(value)
    return text if len(text) <= 24 else f"{text[:12]}… ({len(text)} digits)"


def _table_run(table: pd.DataFrame) -> _Run:
    """The poses of this run's table, its errors rounded as evaluate's JSON writes them
    (``numbers.py``), so that a run compared with the baseline it wrote changes by
    exactly nothing."""
    run = _Run(
        table["pose_id"].to_numpy(dtype=np.int64),
        rounded_frame(table[list(ERROR_KEYS)]).to_numpy(dtype=float),
        table["status"].isin(ESTIMATED).to_numpy(),
    )
    _refuse_repeated_ids(run.pose_id, None, "this run's table")
    return run


def _refuse_repeated_ids(pose_id: np.ndarray, path: object, which: str) -> None:
    ids, counts = np.unique(pose_id, return_counts=True)
    if np.any(counts > 1):
        raise InputError(
            f"{which} has pose {ids[counts > 1][0]} more than once; poses are paired by pose_id",
            path=path,
        )


def _check_limit(limit: float | None, name: str) -> None:
    if limit is not None and not limit >= 0.0:
        raise ValueError(f"{name} must be a non-negative number, got {limit}")


def _verdict(figures: tuple, low: float, high: float, limit: float | None) -> str:
    """The verdict on a change whose interval is ``low``..``high``, ``figures`` the
    baseline's, the run's and the change, all of which must be finite to be compared."""
    if not np.isfinite([*figures, low, high]).all():
        return NOT_COMPARED
    # The same poses read from another format (a heading from a quaternion) differ in the
    # last bits; a change that small is no change.
    if limit is not None and low > limit + GATE_SLACK:
        return WORSE
    if low > GATE_SLACK:
        return WORSE_WITHIN_LIMIT
    if high < -GATE_SLACK:
        return BETTER
    return NO_CHANGE


def compare(
    baseline: dict,
    table: pd.DataFrame,
    *,
    only_ok: bool = False,
    fail_if_worse_cm: float | None = None,
    fail_if_worse_deg: float | None = None,
    fail_if_fewer_pct: float | None = None,
    n_resamples: int = 2000,
    seed: int = 0,
) -> Comparison:
    """This run's ``table`` (a ``table1`` result) against ``baseline`` (``parse_baseline``).

    Poses are paired by ``pose_id``; those whose final errors are missing (NaN) in either
    run are left out, and with ``only_ok`` those whose status is not accepted
    (``estimates.ESTIMATED``) in either run. Each figure's change is now − baseline, its 95 %
    interval the 2.5 and 97.5 percentiles of ``n_resamples`` paired bootstrap resamples
    drawn with ``np.random.default_rng(seed)``. A cm figure fails when its interval's low
    end exceeds ``fail_if_worse_cm``, a degree figure when it exceeds ``fail_if_worse_deg``.
    With ``fail_if_fewer_pct``, the comparison also fails when the poses compared fall short
    of those the baseline scored (its poses with errors, accepted ones with ``only_ok``) by
    more than that share (%): a run that stopped answering must not pass on the poses it
    still has.

    Raises ``InputError`` when fewer than two poses are left to compare (unless the runs
    share the survey and ``fail_if_fewer_pct`` is set: the comparison then fails on the
    shortfall, with no figure) or a pose id repeats in ``table``; ``ValueError`` for a
    negative limit or fewer than one resample.
    """
    _check_limit(fail_if_worse_cm, "fail_if_worse_cm")
    _check_limit(fail_if_worse_deg, "fail_if_worse_deg")
    _check_limit(fail_if_fewer_pct, "fail_if_fewer_pct")
    if n_resamples < 1:
        raise ValueError(f"n_resamples must be at least 1, got {n_resamples}")
    before = _baseline_run(baseline, "baseline")
    now = _table_run(table)
    shared, in_before, in_now = np.intersect1d(
        before.pose_id, now.pose_id, assume_unique=True, return_indices=True
    )
    keep = np.isfinite(before.errors[in_before]).all(axis=1)
    keep &= np.isfinite(now.errors[in_now]).all(axis=1)
    if only_ok:
        keep &= before.accepted[in_before] & now.accepted[in_now]
    n = int(np.count_nonzero(keep))
    scored_before = np.isfinite(before.errors).all(axis=1)
    if only_ok:
        scored_before &= before.accepted
    n_baseline = int(np.count_nonzero(scored_before))
    fewer = None
    if fail_if_fewer_pct is not None:
        fewer = coverage_outcome(
            n, n_baseline, 100.0 - fail_if_fewer_pct, "the baseline's scored pose", "", "compared"
        )
    comparison = functools.partial(
        Comparison,
        n_shared=n,
        n_only_baseline=before.pose_id.size - shared.size,
        n_only_now=now.pose_id.size - shared.size,
        n_left_out=shared.size - n,
        only_ok=only_ok,
        n_baseline=n_baseline,
        fewer=fewer,
    )
    if n < 2 and fewer is not None and shared.size >= 2:
        return comparison(rows=[], failed=True)
    if n < 2:
        raise InputError(
            f"the baseline and this run share {counted(n, 'pose')} with errors to "
            f"compare ({shared.size} in both, {shared.size - n} left out); at least 2 are "
            "needed: are they of the same survey?"
        )
    # Errors so large that their squares overflow give figures that are not finite: those
    # are not compared (``NOT_COMPARED``), without numpy's warnings on the way.
    with np.errstate(over="ignore", invalid="ignore"):
        before_values = _summands(before.errors[in_before[keep]])
        now_values = _summands(now.errors[in_now[keep]])
        lows, highs = _paired_interval(before_values, now_values, n_resamples, seed)
        baseline_figures = _finish(before_values.mean(axis=0))
        now_figures = _finish(now_values.mean(axis=0))
        changes = now_figures - baseline_figures
    limits = {"cm": fail_if_worse_cm, "°": fail_if_worse_deg}
    rows = [
        ComparisonRow(
            figure=figure.name,
            unit=figure.unit,
            baseline=float(baseline_figures[j]),
            now=float(now_figures[j]),
            change=float(changes[j]),
            low=float(lows[j]),
            high=float(highs[j]),
            limit=limits[figure.unit],
            verdict=_verdict(
                (baseline_figures[j], now_figures[j], changes[j]),
                float(lows[j]),
                float(highs[j]),
                limits[figure.unit],
            ),
        )
        for j, figure in enumerate(_FIGURES)
    ]
    failed = any(row.failed for row in rows) or (fewer is not None and not fewer.passed)
    return comparison(rows=rows, failed=failed)


def _paired_interval(
    before: np.ndarray, now: np.ndarray, n_resamples: int, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """(figures,) each: the ends of the CONFIDENCE interval of each figure's change, from
    ``_summands`` (n, figures) of both runs over the same poses, by a paired bootstrap."""
    n = before.shape[0]
    draws = np.random.default_rng(seed).integers(0, n, size=(n_resamples, n))
    # A resample's mean is its draw counts times the values: one product for all figures.
    counts = _counts(draws, n).astype(float)
    # Same draws, same arithmetic for both runs: identical runs differ by exactly zero.
    changes = _finish(counts @ now / n) - _finish(counts @ before / n)
    tail = 100.0 * (1.0 - CONFIDENCE) / 2.0
    lows, highs = np.percentile(changes, [tail, 100.0 - tail], axis=0)
    return lows, highs


def _summands(errors: np.ndarray) -> np.ndarray:
    """(n, figures): what each figure averages per pose of ``errors`` (n, 4 in ERROR_KEYS
    order): the squared error for an RMS figure, the absolute error for a mean."""
    columns = errors[:, [ERROR_KEYS.index(figure.column) for figure in _FIGURES]]
    rms = np.array([figure.rms for figure in _FIGURES])
    return np.where(rms, np.square(columns), np.abs(columns))


def _finish(means: np.ndarray) -> np.ndarray:
    """(..., figures) means of ``_summands`` to the figures: the root for RMS figures."""
    rms = np.array([figure.rms for figure in _FIGURES])
    return np.where(rms, np.sqrt(np.abs(means)), means)


def _counts(draws: np.ndarray, n: int) -> np.ndarray:
    """(resamples, n) how often each pose is drawn in each resample of ``draws``."""
    rows = np.arange(draws.shape[0])[:, None] * n
    return np.bincount((rows + draws).ravel(), minlength=draws.size).reshape(draws.shape)
