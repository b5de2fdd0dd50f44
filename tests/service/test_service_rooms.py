"""The service in rooms (docs/architecture.md): the pipeline answers plain dataclasses that
the HTTP layer turns into its JSON, and a request's headers are read once."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import pytest
from fastapi.testclient import TestClient
from service_support import PHOTO, stream_answers

from service.api.schemas import image_result_out
from service.core import preprocess
from service.core.paths import REPO_ROOT
from service.pipeline import Predictor, job


def test_the_service_top_level_holds_at_most_12_modules() -> None:
    top = sorted(p.name for p in (REPO_ROOT / "service").glob("*.py"))
    assert len(top) <= 12, top


def _fields(answer: Any) -> Any:
    """The field names of a JSON answer, nested (the values left out: timings, refinement)."""
    if isinstance(answer, dict):
        return [(k, _fields(v)) for k, v in answer.items()]
    return None


def test_the_pipeline_answers_dataclasses_that_the_api_answers_field_for_field(
    client: TestClient,
) -> None:
    predictor: Predictor = client.app.state.pose.predictor  # type: ignore[attr-defined]
    result = predictor.predict([(None, PHOTO)], "whole").results[0]
    assert dataclasses.is_dataclass(result) and result.pose is not None
    answered = client.post("/v1/predict", content=PHOTO, headers={"content-type": "image/jpeg"})
    got, expected = answered.json()["results"][0], image_result_out(result).model_dump(mode="json")
    assert _fields(got) == _fields(expected)
    assert got["class_id"] == expected["class_id"] and got["image_size"] == expected["image_size"]


def _counting(calls: list[int], read: Callable[[bytes], Any]) -> Callable[[bytes], Any]:
    def counted(data: bytes) -> Any:
        calls.append(len(data))
        return read(data)

    return counted


@pytest.mark.parametrize("mode", ["whole", "sliding"])
def test_each_uploads_header_is_read_once(
    client: TestClient, monkeypatch: pytest.MonkeyPatch, mode: str
) -> None:
    calls: list[int] = []
    counted = _counting(calls, preprocess.image_header)
    monkeypatch.setattr(job, "image_header", counted)
    monkeypatch.setattr(preprocess, "image_header", counted)
    files = [("image", ("a.jpg", PHOTO, "image/jpeg")), ("image", ("b.jpg", PHOTO, "image/jpeg"))]
    answer = client.post("/v1/predict", params={"mode": mode}, files=files)
    assert answer.status_code == 200, answer.text
    assert calls == [len(PHOTO)] * 2


def test_each_stream_frames_header_is_read_once_tracked_or_not(
    client: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls: list[int] = []
    counted = _counting(calls, preprocess.image_header)
    monkeypatch.setattr(job, "image_header", counted)
    monkeypatch.setattr(preprocess, "image_header", counted)
    answers = stream_answers(client, [PHOTO] * 3)
    assert all("class_id" in a for a in answers), answers
    assert calls == [len(PHOTO)] * 3
