"""Retries, backoff and connection failures, watched on a scripted local server."""

from __future__ import annotations

import asyncio
import socket
from pathlib import Path
from typing import Any

import pytest
from planar_pose_client import (
    AsyncPoseClient,
    BadImageError,
    PoseClient,
    PoseConnectionError,
    PoseError,
    RetryPolicy,
    ServiceUnavailable,
)
from scripted_server import Script, error_body, prediction_body, serve

PHOTO = Path(__file__).resolve().parents[3] / "train/assets/real/chessboard-stereo/left01.jpg"
NOT_READY = (503, error_body("not_ready", "model is loading"))
FAST: dict[str, Any] = {"backoff": 0.01, "backoff_max": 0.05}  # keep the test quick


def test_503_twice_then_success_is_retried():
    script = Script([NOT_READY, NOT_READY, (200, prediction_body(["left01.jpg"]))])
    with serve(script) as url, PoseClient(url, retries=2, **FAST) as client:
        prediction = client.predict(PHOTO)
    assert len(script.requests) == 3
    assert all(r[:2] == ("POST", "/v1/predict?mode=whole") for r in script.requests)
    assert prediction.filename == "left01.jpg" and prediction.class_id == 6
    assert prediction.label == "far, x-, y+" and prediction.present


def test_async_503_twice_then_success_is_retried():
    script = Script([NOT_READY, NOT_READY, (200, prediction_body(["a.png", "left01.jpg"]))])

    async def call(url: str):
        async with AsyncPoseClient(url, retries=3, **FAST) as client:
            return await client.predict_many([PHOTO.read_bytes(), PHOTO])

    with serve(script) as url:
        predictions = asyncio.run(call(url))
    assert len(script.requests) == 3
    assert [p.filename for p in predictions] == ["a.png", "left01.jpg"]


def test_503_beyond_the_retries_raises_service_unavailable():
    script = Script([NOT_READY])
    with (
        serve(script) as url,
        PoseClient(url, retries=1, **FAST) as client,
        pytest.raises(ServiceUnavailable) as info,
    ):
        client.model_info()
    assert len(script.requests) == 2
    assert info.value.status == 503 and info.value.code == "not_ready"
    assert str(info.value) == "HTTP 503 not_ready: model is loading"


def test_400_is_not_retried():
    script = Script([(400, error_body("bad_image", "cannot decode")), NOT_READY])
    with (
        serve(script) as url,
        PoseClient(url, retries=5, **FAST) as client,
        pytest.raises(BadImageError, match="cannot decode"),
    ):
        client.predict(b"not an image")
    assert len(script.requests) == 1


def test_other_statuses_and_broken_answers_are_plain_pose_errors():
    html = "<html><body>Bad gateway</body></html>\n<p>nginx</p>"
    ok = prediction_body(["left01.jpg"])
    script = Script(
        [
            (500, error_body("internal_error", "internal server error (logged)")),
            (502, html),
            (502, html),
            (200, {"model": "fake", "mode": "whole", "results": []}),
            (200, {**ok, "results": [{**ok["results"][0], "class_id": 12}]}),
            (200, "not json"),
        ]
    )
    with serve(script) as url, PoseClient(url, retries=1, **FAST) as client:
        with pytest.raises(PoseError) as crash:
            client.predict(PHOTO)
        assert type(crash.value) is PoseError and crash.value.code == "internal_error"
        assert len(script.requests) == 1  # 500 is not retried
        with pytest.raises(PoseError) as gateway:
            client.predict(PHOTO)
        assert gateway.value.status == 502 and gateway.value.code == "http_502"
        assert gateway.value.message == "<html><body>Bad gateway</body></html>"
        assert len(script.requests) == 3  # 502 is retried once
        for problem in (r"sent 1 image\(s\) but got 0", "results.0.class_id", "json_invalid|JSON"):
            with pytest.raises(PoseError, match=problem) as broken:
                client.predict(PHOTO)
            assert broken.value.code == "invalid_response" and broken.value.status == 200


def test_the_api_key_is_sent_as_a_bearer_token():
    script = Script([(200, prediction_body(["left01.jpg"]))])
    with serve(script) as url, PoseClient(url, api_key="s3cret") as client:
        client.predict(PHOTO)
    assert script.requests[0][2]["Authorization"] == "Bearer s3cret"


def _refused_url() -> str:
    """A URL on which nothing listens: bind a port, then free it."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    return f"http://127.0.0.1:{port}"


@pytest.mark.parametrize("retries", [0, 2])
def test_connection_refused_after_the_configured_retries(retries):
    with PoseClient(_refused_url(), retries=retries, **FAST) as client:
        with pytest.raises(PoseConnectionError) as info:
            client.predict(PHOTO)
        assert not client.health() and not client.ready()
    assert info.value.attempts == retries + 1 and info.value.status is None
    assert "cannot reach http://127.0.0.1:" in str(info.value)


def test_async_connection_refused_after_the_configured_retries():
    async def call():
        async with AsyncPoseClient(_refused_url(), retries=1, **FAST) as client:
            assert not await client.health()
            await client.model_info()

    with pytest.raises(PoseConnectionError) as info:
        asyncio.run(call())
    assert info.value.attempts == 2


def test_backoff_doubles_with_jitter_and_is_capped():
    policy = RetryPolicy(retries=9, backoff=0.1, backoff_max=1.0)
    for retry, base in enumerate([0.1, 0.2, 0.4, 0.8, 1.0, 1.0]):
        waits = [policy.delay(retry) for _ in range(50)]
        assert all(0.5 * base <= w <= base for w in waits)
        assert len(set(waits)) > 1  # jittered
    assert policy.delay(0, retry_after=0.7) >= 0.7
    assert policy.delay(0, retry_after=30.0) == 1.0
    with pytest.raises(ValueError):
        RetryPolicy(retries=-1)
