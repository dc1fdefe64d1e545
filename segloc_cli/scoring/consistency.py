"""Whether a localizer's own uncertainty can be believed: its covariance against its errors.

A localizer that reports a pose covariance (AMCL and its kin do) claims how large its
errors are. Where the claim holds, the normalized estimation error squared (NEES) of
the position, e_xyᵀ Σ_xy⁻¹ e_xy, follows a χ² law with 2 degrees of freedom, and that of
the heading, e_θ² / σ_θ², one with 1 (Bar-Shalom, Li and Kirubarajan, "Estimation with
Applications to Tracking and Navigation", 2001, section 5.4). So a consistent localizer
puts 1 − exp(−k²/2) of its poses within the kσ ellipse of its position covariance, a
mean position NEES near 2, and the sum of N position NEES, being χ²(2N), within the
quantiles this module computes exactly (no scipy). A mean above that interval says the
errors are larger than the covariance admits (over-confident), below it smaller
(under-confident).

Errors are "surveyed minus estimate" as in Table 1, world frame, metres and radians.
Every function here is pure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from segloc_cli.estimates import COVARIANCE_CELLS, COVARIANCE_COLUMNS
from segloc_cli.geometry import wrap_angle

SIGMAS = (1, 2, 3)
"""The ellipses whose shares of poses are reported: 1σ, 2σ, 3σ of the position."""
EXPECTED_SHARE = tuple(100.0 * (1.0 - math.exp(-0.5 * k * k)) for k in SIGMAS)
"""Share (%) of a consistent localizer's poses within each ellipse of ``SIGMAS``:
39.35, 86.47, 98.89."""
INTERVAL_PROBABILITY = 0.95
"""Two-sided probability of the interval a consistent localizer's mean NEES lies in."""
VERDICTS = ("consistent", "over-confident", "under-confident", "unknown")
"""``Consistency.verdict``: the last when no pose carries a usable covariance."""

# A covariance whose smallest eigenvalue is lost in the rounding of its largest is
# singular in all but name: its inverse would be noise.
_PD_RELATIVE_TOLERANCE = 1e-12

_UNUSABLE = "missing, not positive definite, or too small to invert"

_VERDICT_TEXT = {
    "consistent": "the covariances match the errors",
    "over-confident": "the errors are larger than the covariances say",
    "under-confident": "the errors are smaller than the covariances say",
}


def covariance_matrices(frame: pd.DataFrame) -> np.ndarray:
    """(N, 3, 3) symmetric covariances of (x m, y m, θ rad), world frame, one per row of
    ``frame``, built from its ``COVARIANCE_COLUMNS``; an entry whose column is absent or
    empty is NaN (a frame without any of the columns gives all-NaN matrices)."""
    n = len(frame)
    matrices = np.full((n, 3, 3), np.nan)
    for name, (row, col) in zip(COVARIANCE_COLUMNS, COVARIANCE_CELLS, strict=True):
        if name not in frame.columns:
            continue
        values = frame[name].to_numpy(dtype=float)
        matrices[:, row, col] = values
        matrices[:, col, row] = values
    return matrices


def chi2_cdf(x: float, dof: int) -> float:
    """P(X ≤ x) for X ~ χ²(``dof``), ``dof`` a positive integer, exactly (to rounding).

    For even ``dof`` = 2k, X / 2 is Gamma(k, 1), so P(X ≤ x) = 1 − Σ_{m<k} e^(−x/2)
    (x/2)^m / m! (the Poisson sum); for odd ``dof`` the same recurrence in half-integer
    steps starts from χ²(1), whose CDF is erf(√(x/2)).
    """
    if dof < 1 or int(dof) != dof:
        raise ValueError(f"dof must be a positive integer, got {dof}")
    if not x > 0.0:
        return 0.0
    half = 0.5 * float(x)
    start, base = (0.0, 1.0) if dof % 2 == 0 else (0.5, math.erf(math.sqrt(half)))
    # Orders m of the terms e^(−x/2) (x/2)^m / Γ(m + 1) the recurrence subtracts. Those more
    # than 40 standard deviations below the Poisson mean x/2 are below e^(−800): dropping
    # them changes nothing, and keeps a sum over a million poses short.
    first = max(0, int(half - 40.0 * math.sqrt(half) - 40.0))
    orders = start + np.arange(first, dof // 2)
    if orders.size == 0:
        return base
    log_gamma = math.lgamma(orders[0] + 1.0) + np.concatenate(
        ([0.0], np.cumsum(np.log(orders[1:])))
    )
    terms = np.exp(orders * math.log(half) - half - log_gamma)
    return float(min(max(base - terms.sum(), 0.0), 1.0))


def chi2_quantile(probability: float, dof: int) -> float:
    """The x with P(X ≤ x) = ``probability`` for X ~ χ²(``dof``), by bisection on the
    exact ``chi2_cdf`` to a relative precision of 1e-12."""
    if not 0.0 < probability < 1.0:
        raise ValueError(f"probability must lie in (0, 1), got {probability}")
    low, high = 0.0, dof + 10.0 * math.sqrt(2.0 * dof) + 10.0
    while chi2_cdf(high, dof) < probability:
        low, high = high, 2.0 * high
    while high - low > 1e-12 * high:
        middle = 0.5 * (low + high)
        if chi2_cdf(middle, dof) < probability:
            low = middle
        else:
            high = middle
    return 0.5 * (low + high)


def mean_nees_interval(
    n_poses: int, dof_per_pose: int, probability: float = INTERVAL_PROBABILITY
) -> tuple[float, float]:
    """The two-sided ``probability`` interval of the mean NEES over ``n_poses`` poses of a
    consistent localizer, each NEES χ²(``dof_per_pose``): the sum is χ²(n · dof)."""
    if n_poses < 1:
        return (math.nan, math.nan)
    dof = n_poses * dof_per_pose
    tail = 0.5 * (1.0 - probability)
    return (chi2_quantile(tail, dof) / n_poses, chi2_quantile(1.0 - tail, dof) / n_poses)


def _float_or_none(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


@dataclass(frozen=True)
class Consistency:
    """How a localizer's covariances bear out against its errors.

    ``n_poses``: poses with a finite error; ``n_without``: those among them with no usable
    covariance (an entry missing, the 3×3 not positive definite, or so small against the
    error that its NEES is not a finite number), left out of the rest.
    ``share_within``: % of the used poses inside the 1σ, 2σ and 3σ ellipse of their
    position covariance (``SIGMAS``); ``expected_share`` the same for a consistent
    localizer. ``nees_position`` and ``nees_heading``: mean NEES of the position (2×2
    block; expected 2) and of the heading (expected 1); ``nees_interval`` and
    ``nees_heading_interval`` the 95 % intervals their means lie in for a consistent
    localizer with this many poses. ``verdict`` (``VERDICTS``) judges the position NEES:
    above its interval over-confident, below under-confident. NaN where no pose is used.
    """

    n_poses: int
    n_without: int
    share_within: tuple[float, float, float]
    nees_position: float
    nees_heading: float
    nees_interval: tuple[float, float]
    nees_heading_interval: tuple[float, float]
    verdict: str
    expected_share: tuple[float, ...] = EXPECTED_SHARE

    @property
    def n_used(self) -> int:
        """Poses with both a finite error and a usable covariance."""
        return self.n_poses - self.n_without

    def lines(self) -> list[str]:
        """The result in words, one sentence a line, for a Markdown summary."""
        if self.n_used == 0:
            return [
                f"Covariance: none of the {self.n_poses} poses carries a usable one ({_UNUSABLE}), "
                "so its consistency is not judged."
            ]
        without = f"; {self.n_without} without ({_UNUSABLE})" if self.n_without else ""
        sigmas = " / ".join(f"{k}σ" for k in SIGMAS)
        shares = " / ".join(f"{s:.1f}" for s in self.share_within)
        expected = " / ".join(f"{s:.1f}" for s in self.expected_share)
        low, high = self.nees_interval
        low_h, high_h = self.nees_heading_interval
        return [
            f"Covariance: {self.n_used} of {self.n_poses} poses carry a usable one{without}.",
            f"Within the {sigmas} ellipse of the position covariance: {shares} % of poses "
            f"(a consistent localizer: {expected} %).",
            f"Mean NEES of the position {self.nees_position:.2f} (expected 2; 95 % of "
            f"consistent localizers within {low:.2f} to {high:.2f} over {self.n_used} poses), "
            f"of the heading {self.nees_heading:.2f} (expected 1; within {low_h:.2f} to "
            f"{high_h:.2f}).",
            f"Covariance verdict: {self.verdict}: {_VERDICT_TEXT[self.verdict]}.",
        ]

    def as_json(self) -> dict:
        """The result as plain ints, floats, strings and lists; NaN as None."""
        return {
            "n_poses": int(self.n_poses),
            "n_without": int(self.n_without),
            "n_used": int(self.n_used),
            "sigmas": list(SIGMAS),
            "share_within_pct": [_float_or_none(s) for s in self.share_within],
            "expected_share_pct": [_float_or_none(s) for s in self.expected_share],
            "nees_position": _float_or_none(self.nees_position),
            "nees_heading": _float_or_none(self.nees_heading),
            "nees_interval": [_float_or_none(v) for v in self.nees_interval],
            "nees_heading_interval": [_float_or_none(v) for v in self.nees_heading_interval],
            "verdict": self.verdict,
        }


def usable_covariances(covariances: np.ndarray) -> np.ndarray:
    """(N,) bool: the covariances (N, 3, 3) that are finite and positive definite."""
    covariances = np.asarray(covariances, dtype=float)
    finite = np.all(np.isfinite(covariances), axis=(1, 2))
    usable = np.zeros(finite.shape, dtype=bool)
    if finite.any():
        eigenvalues = np.linalg.eigvalsh(covariances[finite])
        largest = eigenvalues[:, -1]
        usable[finite] = (largest > 0.0) & (eigenvalues[:, 0] > _PD_RELATIVE_TOLERANCE * largest)
    return usable


def _verdict(mean_nees: float, interval: tuple[float, float]) -> str:
    if mean_nees > interval[1]:
        return "over-confident"
    if mean_nees < interval[0]:
        return "under-confident"
    return "consistent"


def _mean(values: np.ndarray) -> float:
    """The mean of finite ``values``; where their sum overflows, the sum of their shares
    (each value over their count), which stays within the largest."""
    with np.errstate(over="ignore"):
        mean = float(np.mean(values))
    return mean if math.isfinite(mean) else float(np.sum(values / values.size))


def consistency(errors: np.ndarray, covariances: np.ndarray) -> Consistency | None:
    """Judge ``covariances`` (N, 3, 3; x m, y m, θ rad, world frame) against ``errors``
    (N, 3: x m, y m, θ rad, surveyed minus estimate, θ wrapped again here).

    Poses whose error is not finite are left out (they have no estimate to judge).
    Returns None when no pose carries any covariance entry at all, as for a localizer
    that reports none; otherwise a ``Consistency``.
    """
    errors = np.asarray(errors, dtype=float)
    covariances = np.asarray(covariances, dtype=float)
    if errors.ndim != 2 or errors.shape[1] != 3:
        raise ValueError(f"errors must be (N, 3), got shape {errors.shape}")
    if covariances.shape != (errors.shape[0], 3, 3):
        raise ValueError(
            f"covariances must be ({errors.shape[0]}, 3, 3), got shape {covariances.shape}"
        )
    if not np.isfinite(covariances).any():
        return None
    posed = np.all(np.isfinite(errors), axis=1)
    errors, covariances = errors[posed], covariances[posed]
    used = usable_covariances(covariances)
    ex, ey, etheta = errors[:, 0], errors[:, 1], wrap_angle(errors[:, 2])
    a, b, d = covariances[:, 0, 0], covariances[:, 0, 1], covariances[:, 1, 1]
    with np.errstate(all="ignore"):
        # The 2×2 inverse in closed form: positive definiteness of the 3×3 keeps det > 0,
        # but a covariance of subnormal entries (1e-310 m²) has a det that rounds to 0, and
        # one tiny against its error a NEES past float64's range. Such a pose has no NEES to
        # judge: it is counted among those without a usable covariance.
        nees_xy = (d * ex * ex - 2.0 * b * ex * ey + a * ey * ey) / (a * d - b * b)
        nees_theta = etheta * etheta / covariances[:, 2, 2]
    used &= np.isfinite(nees_xy) & np.isfinite(nees_theta)
    nees_xy, nees_theta = nees_xy[used], nees_theta[used]
    n_used = int(np.count_nonzero(used))

    if n_used:
        share = tuple(100.0 * float(np.mean(nees_xy <= k * k)) for k in SIGMAS)
        mean_xy, mean_theta = _mean(nees_xy), _mean(nees_theta)
    else:
        share = (math.nan,) * len(SIGMAS)
        mean_xy = mean_theta = math.nan
    interval = mean_nees_interval(n_used, 2)
    return Consistency(
        n_poses=int(errors.shape[0]),
        n_without=int(errors.shape[0]) - n_used,
        share_within=(share[0], share[1], share[2]),
        nees_position=mean_xy,
        nees_heading=mean_theta,
        nees_interval=interval,
        nees_heading_interval=mean_nees_interval(n_used, 1),
        verdict=_verdict(mean_xy, interval) if n_used else "unknown",
    )
