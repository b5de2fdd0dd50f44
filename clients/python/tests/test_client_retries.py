"""Retries, backoff and connection failures, watched through `httpx.MockTransport`."""

from __future__ import annotations

import asyncio
import socket
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
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

PHOTO = Path(__file__).resolve().parents[3] / "train/assets/real/chessboard-stereo/left01.jpg"
FAST: dict[str, Any] = {"backoff": 0.01, "backoff_max": 0.05}  # keep the test quick
URL = "http://pose.test"


def prediction_body(filenames: list[str]) -> dict[str, Any]:
    """A valid POST /v1/predict answer for `filenames`, all of class 6 (far, x-, y+)."""
    probabilities = [0.02] * 9
    probabilities[6] = 0.84
    result = {
        "class_id": 6,
        "region": {"present": True, "depth": "far", "x": "-", "y": "+", "label": "far, x-, y+"},
        "probabilities": probabilities,
        "confidence": 0.84,
        "box": None,
        "elapsed_ms": 1.5,
    }
    return {
        "model": "fake",
        "mode": "whole",
        "results": [{"filename": name, **result} for name in filenames],
    }


def error_body(code: str, message: str) -> dict[str, Any]:
    return {"error": {"code": code, "message": message}}


NOT_READY = (503, error_body("not_ready", "model is loading"))


@dataclass
class Script:
    """Answers in order, the last one repeating: (status, JSON-able body, or str sent as
    text/html); `requests` records what the client sent."""

    answers: list[tuple[int, Any]]
    requests: list[httpx.Request] = field(default_factory=list)

    def __call__(self, request: httpx.Request) -> httpx.Response:
        request.read()
        self.requests.append(request)
        status, body = self.answers[min(len(self.requests), len(self.answers)) - 1]
        if isinstance(body, str):  # e.g. a proxy's HTML error page
            return httpx.Response(status, text=body, headers={"content-type": "text/html"})
        return httpx.Response(status, json=body)

    def sync(self) -> httpx.MockTransport:
        return httpx.MockTransport(self)

    def paths(self) -> list[tuple[str, str]]:
        return [(r.method, f"{r.url.path}?{r.url.query.decode()}") for r in self.requests]


def client(script: Script, **kw: Any) -> PoseClient:
    return PoseClient(URL, transport=script.sync(), **kw)


def test_503_twice_then_success_is_retried():
    script = Script([NOT_READY, NOT_READY, (200, prediction_body(["left01.jpg"]))])
    with client(script, retries=2, **FAST) as c:
        prediction = c.predict(PHOTO)
    assert len(script.requests) == 3
    assert script.paths() == [("POST", "/v1/predict?mode=whole")] * 3
    assert prediction.filename == "left01.jpg" and prediction.class_id == 6
    assert prediction.label == "far, x-, y+" and prediction.present


def test_async_503_twice_then_success_is_retried():
    script = Script([NOT_READY, NOT_READY, (200, prediction_body(["a.png", "left01.jpg"]))])

    async def call() -> list[Any]:
        transport = httpx.MockTransport(script)
        async with AsyncPoseClient(URL, retries=3, transport=transport, **FAST) as c:
            return await c.predict_many([PHOTO.read_bytes(), PHOTO])

    predictions = asyncio.run(call())
    assert len(script.requests) == 3
    assert [p.filename for p in predictions] == ["a.png", "left01.jpg"]


def test_503_beyond_the_retries_raises_service_unavailable():
    script = Script([NOT_READY])
    with client(script, retries=1, **FAST) as c, pytest.raises(ServiceUnavailable) as info:
        c.model_info()
    assert len(script.requests) == 2
    assert info.value.status == 503 and info.value.code == "not_ready"
    assert str(info.value) == "HTTP 503 not_ready: model is loading"


def test_400_is_not_retried():
    script = Script([(400, error_body("bad_image", "cannot decode")), NOT_READY])
    with (
        client(script, retries=5, **FAST) as c,
        pytest.raises(BadImageError, match="cannot decode"),
    ):
        c.predict(b"not an image")
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
    with client(script, retries=1, **FAST) as c:
        with pytest.raises(PoseError) as crash:
            c.predict(PHOTO)
        assert type(crash.value) is PoseError and crash.value.code == "internal_error"
        assert len(script.requests) == 1  # 500 is not retried
        with pytest.raises(PoseError) as gateway:
            c.predict(PHOTO)
        assert gateway.value.status == 502 and gateway.value.code == "http_502"
        assert gateway.value.message == "<html><body>Bad gateway</body></html>"
        assert len(script.requests) == 3  # 502 is retried once
        for problem in (r"sent 1 image\(s\) but got 0", "results.0.class_id", "json_invalid|JSON"):
            with pytest.raises(PoseError, match=problem) as broken:
                c.predict(PHOTO)
            assert broken.value.code == "invalid_response" and broken.value.status == 200


def test_the_api_key_is_sent_as_a_bearer_token():
    script = Script([(200, prediction_body(["left01.jpg"]))])
    with client(script, api_key="s3cret") as c:
        c.predict(PHOTO)
    assert script.requests[0].headers["Authorization"] == "Bearer s3cret"


def test_transport_errors_are_retried_then_reported():
    """A dropped connection (no answer) counts as an attempt; the last error is reported."""
    attempts: list[httpx.Request] = []

    def flaky(request: httpx.Request) -> httpx.Response:
        attempts.append(request)
        if len(attempts) < 3:
            raise httpx.RemoteProtocolError("server disconnected", request=request)
        return httpx.Response(200, json=prediction_body(["left01.jpg"]))

    with PoseClient(URL, retries=2, transport=httpx.MockTransport(flaky), **FAST) as c:
        assert c.predict(PHOTO).class_id == 6
    assert len(attempts) == 3

    def timeout(request: httpx.Request) -> httpx.Response:
        raise httpx.ReadTimeout("read timed out", request=request)

    with (
        PoseClient(URL, retries=1, transport=httpx.MockTransport(timeout), **FAST) as c,
        pytest.raises(PoseConnectionError, match=r"timed out \(ReadTimeout\) \(2 attempts\)"),
    ):
        c.model_info()


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
