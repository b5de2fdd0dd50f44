"""A stream's track (`WS /v1/stream`, whole mode): frames refined from the last frame's
corners, the network every `stream_track_every` frames to catch drift, and the track kept
where the network agrees with it (`Predictor.confirm`)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from service_support import PHOTO, stream_answers

from service.pipeline import PoseModel, Predictor, Settings
from service.pipeline.predictor import TRACK_AGREE_PX, Track


def test_the_network_checks_the_track_every_10th_frame_and_keeps_it_where_it_agrees(
    client: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    runs: list[int] = []
    run = Predictor.run

    def counted(self: Predictor, job: Any) -> Any:
        runs.append(len(job.uploads))
        return run(self, job)

    monkeypatch.setattr(Predictor, "run", counted)
    answers = stream_answers(client, [PHOTO] * 12)
    assert runs == [1, 1]  # frames 0 and 10
    assert [a["tracked"] for a in answers] == [False] + [True] * 11
    # the same photo: the network's frame answers where the track stands
    corners = np.array([a["corners"] for a in answers])
    assert np.abs(corners[10] - corners[9]).max() < 0.05


def test_a_network_frame_away_from_the_track_answers_as_the_network(
    default_model: PoseModel,
) -> None:
    predictor = Predictor(default_model, Settings())
    job = predictor.admit([(None, PHOTO)], predictor.options("whole"))
    network = predictor.run(job)
    found = network.results[0]
    assert found.corners is not None and found.class_id
    here = Track(np.array(found.corners), network.kappas[0], 0.9)
    kept = predictor.confirm(job, here, network)
    assert kept is not network and kept.results[0].tracked
    assert np.abs(np.array(kept.results[0].corners) - here.corners).max() < TRACK_AGREE_PX
    away = Track(here.corners + 2 * TRACK_AGREE_PX, here.kappa, 0.9)  # a drifted track
    assert predictor.confirm(job, away, network) is network
