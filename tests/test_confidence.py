"""The verdict: the evidence of a fit, the confidence model and the status it gives."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from segloc_cli.config import ConfidenceParams
from segloc_cli.estimates import STATUS_AMBIGUOUS, STATUS_LOST, STATUS_OK
from segloc_cli.geometry import Pose2
from segloc_cli.method.confidence import (
    FEATURES,
    LOCAL_MAPS,
    MODEL_PATH,
    TIE_SCALE,
    UNINFORMED,
    ConfidenceModel,
    Evidence,
    judge,
    points_status,
    shipped_models,
)
from segloc_cli.method.extract import extract_segments
from segloc_cli.method.localize import Localizer
from segloc_cli.sim import NOISE_FREE, random_free_poses, random_world, simulate_scan
from segloc_cli.world import World


def _evidence(**changes) -> Evidence:
    values = dict(
        inlier_ratio=0.9, runner_up_ratio=0.2, score=0.8, runner_up_score=0.15, hold_points=40.0,
        crossing_ratio=0.05, points=200,
    )  # fmt: skip
    return Evidence(**{**values, **changes})


MARGIN_MODEL = ConfidenceModel(
    features=("inlier_margin",), mean=(0.1,), scale=(0.05,), weights=(2.0,), bias=0.0
)
"""P = 1 / (1 + exp(−2·(margin − 0.1) / 0.05)): one half at a margin of 0.1."""


def test_features_are_the_listed_inputs_worked_out_by_hand():
    features = _evidence().features()
    assert set(FEATURES) <= set(features)
    assert features["inlier_ratio"] == 0.9
    # 0.9 − 0.2 of 200 points: the rival leaves 140 of the answer's points off the map.
    assert features["log_margin_points"] == pytest.approx(math.log(141.0))
    assert _evidence(runner_up_ratio=0.95).features()["log_margin_points"] == 0.0
    assert features["inlier_margin"] == pytest.approx(0.7)
    assert features["score_margin"] == pytest.approx(0.65)
    assert features["log_hold_points"] == pytest.approx(math.log(41.0))
    assert features["tie"] == pytest.approx(-math.log(0.65 + TIE_SCALE))
    assert features["crossing_ratio"] == 0.05
    # A tie scores the most; a rival fitting better by score cannot make it larger.
    tied = _evidence(runner_up_score=0.8).features()["tie"]
    assert tied == pytest.approx(-math.log(TIE_SCALE))
    assert _evidence(runner_up_score=0.9).features()["tie"] == tied


def test_probability_is_the_logistic_of_the_standardized_features():
    for margin, expected in [
        (0.1, 0.5),
        (0.15, 1 / (1 + math.exp(-2.0))),
        (0.0, 1 / (1 + math.e**4)),
    ]:
        evidence = _evidence(inlier_ratio=0.6 + margin, runner_up_ratio=0.6)
        assert MARGIN_MODEL.probability(evidence) == pytest.approx(expected, rel=1e-12)


def test_probability_stays_in_the_open_unit_interval_at_any_evidence():
    huge = ConfidenceModel(("inlier_margin",), (0.0,), (1e-9,), (1.0,), 0.0)
    assert 0.0 <= huge.probability(_evidence(runner_up_ratio=0.0)) <= 1.0
    assert 0.0 <= huge.probability(_evidence(runner_up_ratio=1.0)) <= 1.0


def test_the_uninformed_model_gives_even_odds_and_rows_match_single_answers():
    assert UNINFORMED.probability(_evidence()) == 0.5
    rows = [_evidence(runner_up_ratio=r) for r in (0.0, 0.5, 0.85)]
    x = np.array([[e.features()["inlier_margin"]] for e in rows])
    np.testing.assert_allclose(
        MARGIN_MODEL.probabilities(x), [MARGIN_MODEL.probability(e) for e in rows], rtol=1e-15
    )


def test_model_round_trips_through_its_json_object():
    again = ConfidenceModel.from_dict(json.loads(json.dumps(MARGIN_MODEL.as_dict())))
    assert again == MARGIN_MODEL


@pytest.mark.parametrize(
    ("changes", "status"),
    [
        ({}, STATUS_OK),  # margin 0.7: P ≈ 1
        ({"runner_up_ratio": 0.85}, STATUS_AMBIGUOUS),  # margin 0.05: P ≈ 0.12
        ({"hold_points": 1.0}, STATUS_AMBIGUOUS),  # a corridor, however sure the model is
        ({"inlier_ratio": 0.45, "runner_up_ratio": 0.0}, STATUS_LOST),
    ],
)
def test_judge_follows_the_confidence_and_the_points(changes, status):
    evidence = _evidence(**changes)
    got, confidence = judge(evidence, ConfidenceParams(min_confidence=0.9), MARGIN_MODEL)
    assert got == status
    assert confidence == MARGIN_MODEL.probability(evidence)


def test_the_threshold_decides_between_ok_and_ambiguous():
    evidence = _evidence(inlier_ratio=0.82, runner_up_ratio=0.7)  # margin 0.12: P ≈ 0.69
    assert judge(evidence, ConfidenceParams(min_confidence=0.6), MARGIN_MODEL)[0] == STATUS_OK
    got = judge(evidence, ConfidenceParams(min_confidence=0.7), MARGIN_MODEL)[0]
    assert got == STATUS_AMBIGUOUS


def test_points_status_asks_no_rival():
    params = ConfidenceParams()
    assert points_status(0.9, 40.0, params) == STATUS_OK
    assert points_status(0.9, 0.5, params) == STATUS_AMBIGUOUS
    assert points_status(0.3, 40.0, params) == STATUS_LOST
    assert points_status(float("nan"), 40.0, params) == STATUS_LOST


@pytest.mark.parametrize("mode", LOCAL_MAPS)
def test_the_shipped_models_read_known_features_and_trust_a_clear_margin(mode):
    model = shipped_models()[mode]
    data = json.loads(MODEL_PATH.read_text(encoding="utf-8"))
    assert ConfidenceModel.from_dict(data["models"][mode]) == model
    assert set(model.features) <= set(FEATURES)
    assert len(model.mean) == len(model.scale) == len(model.weights) == len(model.features)
    assert all(s > 0 for s in model.scale)
    assert data["provenance"]["trials"][mode], "the model says what it was fitted on"
    # A rival explaining the scan as well as the answer must cost confidence, and a wider
    # lead over it must not.
    clear, tied = _evidence(), _evidence(runner_up_ratio=0.9, runner_up_score=0.8)
    assert model.probability(clear) > 0.9 > model.probability(tied)
    leads = [_evidence(runner_up_ratio=r, runner_up_score=r) for r in (0.85, 0.7, 0.5, 0.2)]
    assert np.all(np.diff([model.probability(e) for e in leads]) >= 0)


def test_a_localized_scan_carries_its_evidence_and_confidence():
    rng = np.random.default_rng(42)
    world = random_world(rng)
    truth = Pose2(*random_free_poses(world, 1, rng)[0])
    scan = simulate_scan(world, truth, NOISE_FREE, rng, 0.0)
    guess = Pose2(truth.x + 0.6, truth.y - 0.4, truth.theta + 0.2)
    est = Localizer.on_map(world.segments).localize(extract_segments(scan), guess, scan.points())
    assert est.evidence is not None
    assert est.evidence.inlier_ratio == est.inlier_ratio
    assert est.evidence.hold_points == Localizer.on_map(world.segments).hold_points(
        scan.points(), est.pose
    )
    single = shipped_models()["single"]
    assert est.confidence == single.probability(est.evidence)
    assert est.status == judge(est.evidence, ConfidenceParams(), single)[0]


def test_a_symmetric_room_is_not_trusted():
    """Seen from a pose or its half-turn about the centre, a bare room looks the same."""
    corners = np.array([[0.0, 0.0], [8.0, 0.0], [8.0, 5.0], [0.0, 5.0]])
    room = World(np.hstack([corners, np.roll(corners, -1, axis=0)]))
    scan = simulate_scan(
        room, Pose2.from_deg(2.5, 1.5, 30.0), NOISE_FREE, np.random.default_rng(1), 0.0
    )
    localizer = Localizer.on_map(room.segments, global_search=True)
    est = localizer.localize_global(extract_segments(scan), scan.points())
    assert est.evidence.score == pytest.approx(est.evidence.runner_up_score)
    assert est.confidence < ConfidenceParams().min_confidence
    assert est.status == STATUS_AMBIGUOUS
