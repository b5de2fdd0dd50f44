"""Where the network calls the object absent but may be wrong, the texture aligned at the
photo's resolution has a second say (service/pipeline/predictor.py `RESCUE_FROM_P`,
`ZERO_SHOT_RESCUE_FROM_P`, `PRESENT_SCORE`)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest
from service_support import board_photo, encode

from service.pipeline import PoseModel, Predictor, Settings
from service.pipeline.predictor import PRESENT_SCORE, RESCUE_FROM_P, ZERO_SHOT_RESCUE_FROM_P


@pytest.fixture(scope="module")
def predictor(default_model: PoseModel) -> Predictor:
    return Predictor(default_model, Settings())


def missed(predictor: Predictor, monkeypatch: pytest.MonkeyPatch, present: float) -> None:
    """The network answers every image absent, with P(present) `present`."""
    run = predictor._run

    def absent(*args: object, **kwargs: object) -> object:
        answer = run(*args, **kwargs)
        probs = np.tile([1.0 - present] + [present / 8] * 8, (len(answer.probabilities), 1))
        return replace(answer, probabilities=probs)

    monkeypatch.setattr(predictor, "_run", absent)


def test_an_object_the_network_missed_is_found_where_its_texture_aligns(
    predictor: Predictor, monkeypatch: pytest.MonkeyPatch
) -> None:
    data, corners = board_photo()
    want = predictor.predict([(None, data)], "whole").results[0]
    missed(predictor, monkeypatch, 2 * RESCUE_FROM_P)
    got = predictor.predict([(None, data)], "whole").results[0]
    assert got.class_id == want.class_id != 0 and got.corners_source == "refined"
    assert got.refinement is not None and got.refinement.score >= PRESENT_SCORE
    assert 1.0 - got.probabilities[0] == pytest.approx(got.refinement.score, abs=1e-3)
    assert np.abs(np.array(got.corners) - corners).max() < 2.0
    assert got.pose is not None


@pytest.mark.parametrize("present", [0.5 * RESCUE_FROM_P, 0.45])
def test_no_second_opinion_below_its_p_nor_where_no_texture_aligns(
    predictor: Predictor, monkeypatch: pytest.MonkeyPatch, present: float
) -> None:
    data, _ = board_photo()
    grey = encode(".png", np.random.default_rng(0).integers(0, 255, (480, 640, 3), np.uint8))
    missed(predictor, monkeypatch, present)
    board, noise = (
        r.results[0] for r in (predictor.predict([(None, d)], "whole") for d in (data, grey))
    )
    assert noise.class_id == 0 and noise.corners is None  # nothing aligns in noise
    if present < RESCUE_FROM_P:  # not asked: the network's "absent" stands
        assert board.class_id == 0 and board.corners is None


def test_a_zero_shot_model_is_asked_again_from_a_lower_p(
    default_model: PoseModel, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A zero-shot model's presence is set to call nearly every absent render absent: its
    "absent" at a P(present) between the two thresholds is looked at again, a trained one's
    stands."""
    assert ZERO_SHOT_RESCUE_FROM_P < RESCUE_FROM_P
    between = (ZERO_SHOT_RESCUE_FROM_P + RESCUE_FROM_P) / 2
    data, _ = board_photo()
    zero_shot = replace(default_model, card={**default_model.card, "zero_shot": {}})
    assert zero_shot.training == "zero-shot" and default_model.training == "trained"
    answers = {}
    for name, model in (("zero-shot", zero_shot), ("trained", default_model)):
        predictor = Predictor(model, Settings())
        missed(predictor, monkeypatch, between)
        answers[name] = predictor.predict([(None, data)], "whole").results[0]
    assert answers["zero-shot"].class_id != 0 and answers["zero-shot"].corners_source == "refined"
    assert answers["trained"].class_id == 0 and answers["trained"].corners is None


def test_the_features_are_searched_near_the_corners_of_a_trained_network_that_found_it(
    default_model: PoseModel, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A trained network that found the object marks where it is: its features are searched
    there. Where it missed it, or the network is zero-shot, the whole photo is searched."""
    import service.pipeline.predictor as module

    searched: list[str] = []
    refine = module.refine_corners

    def spy(*args: object, **kwargs: Any) -> object:
        searched.append(kwargs["features"])
        return refine(*args, **kwargs)

    monkeypatch.setattr(module, "refine_corners", spy)
    data, _ = board_photo()
    zero_shot = replace(default_model, card={**default_model.card, "zero_shot": {}})
    for model in (default_model, zero_shot):
        Predictor(model, Settings()).predict([(None, data)], "whole")
    trained = Predictor(default_model, Settings())
    missed(trained, monkeypatch, 2 * RESCUE_FROM_P)
    trained.predict([(None, data)], "whole")
    assert searched == ["near", "photo", "photo"]
