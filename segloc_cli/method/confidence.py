"""How far to trust an estimate: a confidence, and the status ``ok``, ``ambiguous`` or ``lost``.

The confidence is the probability that the answer is the right place (within 30 cm and 3°
of the truth), predicted from what the fit leaves behind (``Evidence``): how firmly the
points fix the position along their weakest direction, and how far the best distinct
alternative falls behind, in points. A logistic model (``ConfidenceModel``) per kind of
local map (a scan, or a window of scans) maps them to the probability; its weights are fitted by
``benchmarks/calibrate.py`` on simulated and real trials and shipped in
``confidence_model.json`` beside this module, with the trials they were fitted on. It speaks
of answers whose searched area holds the truth: a guess within the search's reach
(``--search-half-width-m``), or none (``--global``).

The status follows from it (``judge``): ``lost`` when too little of the scan lies on the map,
``ambiguous`` when the confidence is below ``min_confidence`` or nothing pins the position
along one direction (a corridor), else ``ok``.
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from segloc_cli.config import ConfidenceParams
from segloc_cli.estimates import STATUS_AMBIGUOUS, STATUS_LOST, STATUS_OK

RIGHT_PLACE_M = 0.30
RIGHT_PLACE_DEG = 3.0
"""An answer within this distance (m) and heading (°) of the truth is the right place, which
the confidence is the probability of; beyond either it is another place, not an imprecise fit."""

MODEL_PATH = Path(__file__).with_name("confidence_model.json")
FEATURES = ("log_hold_points", "log_margin_points")
"""The inputs of the model, keys of ``Evidence.features``: how firmly the points fix the
position, and how far the best distinct rival falls behind, counted in points: how many of
the points on the map at the answer the rival leaves off it (none at an exact twin).

Left out, though ``Evidence.features`` offers them: how near the fit scores of the answer and
the rival tie (``tie``), which says nearly what the margin in points says; fitted with it on
the real logs alone, the model gave it the wrong sign and let the simulated twins through.
The share of the scan on the map (``inlier_ratio``), which made the fitted logs' clutter the
measure of every other log's (on each shared log left out of the fit in turn it flagged up
to a third of the right answers of the most cluttered one), and only sets ``lost`` below
``min_inlier_ratio``. The share of beams through walls, the inliers' RMS distance and the
counts of points and of segments, which stood for the scanner and the map rather than for
the fit."""
LOCAL_MAPS = ("single", "window")
"""The local maps a confidence is fitted for: one scan, and a window of scans (``window.py``),
whose margins over a rival are larger for the same doubt."""
TIE_SCALE = 0.003
"""Score margin (the score runs 0–1) below which ``tie`` is near its largest, −log TIE_SCALE:
the answer and its rival fit alike there to within the scatter of the score itself."""


@dataclass(frozen=True)
class Evidence:
    """What the verdict weighs, measured at the answer after refinement.

    ``inlier_ratio`` and ``runner_up_ratio``: shares (0–1) of the scan's points within the
    final gate of a map segment at the answer and at its best distinct alternative (0 when
    none was found); ``score`` and ``runner_up_score``: the fit scores there (``Refinement.
    score``, 0–1, which also rewards how close the points lie); ``hold_points``: how many
    points' worth fix the position along its weakest direction (``refine.support``);
    ``crossing_ratio``: the share of the beams that would have passed through a wall of the
    map to reach their reading (``freespace.crossing_ratio``); ``points``: how many points
    the shares are of (a window's, ``window.py``, or the scan's); ``scan_inlier_ratio``: of
    a window, the share of the scan's own points on the map at the answer (None: the scan
    alone, whose share is ``inlier_ratio``). A window's neighbours add points only where the
    scan saw none, more of them clutter than of walls the scan already covers, so it is the
    scan's own share that says whether the answer is ``lost``.
    """

    inlier_ratio: float
    runner_up_ratio: float
    score: float
    runner_up_score: float
    hold_points: float
    crossing_ratio: float
    points: int = 0
    scan_inlier_ratio: float | None = None

    @property
    def own_inlier_ratio(self) -> float:
        """The share of the scan's own points on the map at the answer (0–1)."""
        return self.inlier_ratio if self.scan_inlier_ratio is None else self.scan_inlier_ratio

    def features(self) -> dict[str, float]:
        """The model's inputs (``FEATURES``) and the other measures the calibration reports
        beside them, by name: plain numbers, none NaN.

        ``tie`` = −log(score margin + ``TIE_SCALE``) rises steeply as the margin falls to 0: a
        linear weight on the margin alone cannot tell a clear lead of a few hundredths from
        the exact tie a symmetric place gives.
        """
        score_margin = self.score - self.runner_up_score
        return {
            "inlier_ratio": self.inlier_ratio,
            "own_inlier_ratio": self.own_inlier_ratio,
            "log_hold_points": math.log1p(max(self.hold_points, 0.0)),
            "inlier_margin": self.inlier_ratio - self.runner_up_ratio,
            "score_margin": score_margin,
            "tie": -math.log(max(score_margin, 0.0) + TIE_SCALE),
            "crossing_ratio": self.crossing_ratio,
            "log_margin_points": math.log1p(
                max(self.inlier_ratio - self.runner_up_ratio, 0.0) * self.points
            ),
        }


@dataclass(frozen=True)
class ConfidenceModel:
    """A logistic model: P(right) = 1 / (1 + exp(−(bias + Σ wᵢ (xᵢ − meanᵢ) / scaleᵢ))).

    ``features`` names the inputs (keys of ``Evidence.features``) in the order of
    ``mean``, ``scale`` and ``weights``.
    """

    features: tuple[str, ...]
    mean: tuple[float, ...]
    scale: tuple[float, ...]
    weights: tuple[float, ...]
    bias: float

    def probability(self, evidence: Evidence) -> float:
        """P(the answer is the right place) given ``evidence``, in [0, 1]."""
        values = evidence.features()
        return float(self.probabilities(np.array([[values[name] for name in self.features]]))[0])

    def probabilities(self, x: np.ndarray) -> np.ndarray:
        """P(right) (N,) for the rows of ``x`` (N, F), the ``features`` in order."""
        z = self.bias + (np.asarray(x, dtype=float) - self.mean) / self.scale @ self.weights
        return 1.0 / (1.0 + np.exp(-np.clip(z, -700.0, 700.0)))

    def as_dict(self) -> dict:
        """The model as the JSON object ``confidence_model.json`` holds under "model"."""
        return {
            "features": list(self.features),
            "mean": list(self.mean),
            "scale": list(self.scale),
            "weights": list(self.weights),
            "bias": self.bias,
        }

    @classmethod
    def from_dict(cls, data: dict) -> ConfidenceModel:
        """The model from its JSON object (see ``as_dict``)."""
        return cls(
            features=tuple(data["features"]),
            mean=tuple(float(v) for v in data["mean"]),
            scale=tuple(float(v) for v in data["scale"]),
            weights=tuple(float(v) for v in data["weights"]),
            bias=float(data["bias"]),
        )


UNINFORMED = ConfidenceModel(features=(), mean=(), scale=(), weights=(), bias=0.0)
"""A model that knows nothing: 0.5 for every answer. The calibration localizes with it, so
that what it fits never depends on an earlier fit."""


@functools.cache
def shipped_models() -> dict[str, ConfidenceModel]:
    """The models fitted by ``benchmarks/calibrate.py``, one per kind of local map in
    ``LOCAL_MAPS``, read once from ``MODEL_PATH``."""
    data = json.loads(MODEL_PATH.read_text(encoding="utf-8"))["models"]
    return {mode: ConfidenceModel.from_dict(data[mode]) for mode in LOCAL_MAPS}


def judge(
    evidence: Evidence, params: ConfidenceParams, model: ConfidenceModel
) -> tuple[str, float]:
    """Status and confidence of an answer from its ``evidence``, by ``model``."""
    confidence = model.probability(evidence)
    status = points_status(evidence.own_inlier_ratio, evidence.hold_points, params)
    if status == STATUS_OK and confidence < params.min_confidence:
        status = STATUS_AMBIGUOUS
    return status, confidence


def points_status(inlier_ratio: float, hold_points: float, params: ConfidenceParams) -> str:
    """The status the points alone give, rivals unasked: ``lost`` below the inlier share,
    ``ambiguous`` where they cannot fix the position along one direction, else ``ok``."""
    if not inlier_ratio >= params.min_inlier_ratio:
        return STATUS_LOST
    if hold_points < params.min_hold_points:
        return STATUS_AMBIGUOUS
    return STATUS_OK
