"""The stream's parts without a server: the drop-oldest queue, smoothing, the query
parameters, and (in-process, Starlette's TestClient) a frame whose inference crashes."""

from __future__ import annotations

import json
import time
from dataclasses import replace
from typing import Any

import anyio
import pytest
from fastapi.testclient import TestClient
from live_support import PHOTO

from service.app import create_app
from service.core.paths import DEFAULT_MODEL
from service.pipeline.results import ImageResult, Region
from service.settings import Settings
from service.stream.protocol import (
    CloseCode,
    Frame,
    FrameQueue,
    Smoother,
    StreamRefused,
    parse_options,
)


def test_the_queue_drops_the_oldest_and_counts() -> None:
    queue = FrameQueue(depth=2)
    dropped = [queue.put(Frame(i, b"x")) for i in range(5)]
    assert dropped == [0, 0, 1, 1, 1] and len(queue) == 2
    assert queue.take_dropped() == 3 and queue.take_dropped() == 0

    async def drain() -> list[object]:
        first, second = await queue.get(), await queue.get()
        queue.close()
        assert first is not None and second is not None
        return [first.seq, second.seq, await queue.get()]

    assert anyio.run(drain) == [3, 4, None]
    assert queue.put(Frame(9, b"x")) == 0 and len(queue) == 0  # closed: nothing kept
    with pytest.raises(ValueError):
        FrameQueue(depth=0)


def test_a_waiting_consumer_wakes_on_put() -> None:
    queue = FrameQueue()

    async def main() -> int:
        async with anyio.create_task_group() as tasks:
            got: list[int] = []

            async def consume() -> None:
                frame = await queue.get()
                assert frame is not None
                got.append(frame.seq)

            tasks.start_soon(consume)
            await anyio.sleep(0.01)
            queue.put(Frame(7, b"x"))
        return got[0]

    assert anyio.run(main) == 7


def _result(probs: list[float]) -> ImageResult:
    k = max(range(9), key=probs.__getitem__)
    return ImageResult(
        filename=None,
        class_id=k,
        region=Region(present=k > 0, depth=None, x=None, y=None, label="x"),
        probabilities=probs,
        confidence=probs[k],
        box=None,
        elapsed_ms=1.0,
    )


def test_smoothing_lags_and_off_is_identity() -> None:
    a, b = [0.0] * 9, [0.0] * 9
    a[1], b[5] = 1.0, 1.0
    off = Smoother(0.0)
    assert off.apply(_result(b)).probabilities == b
    smooth = Smoother(0.75)
    first = smooth.apply(_result(a))
    assert first.class_id == 1
    second = smooth.apply(_result(b))  # 0.75 * a + 0.25 * b: still class 1
    assert second.class_id == 1 and second.probabilities[5] == pytest.approx(0.25)
    assert second.region.label == "near, x+, y+" and second.confidence == pytest.approx(0.75)
    third = smooth.apply(_result(b))
    assert third.probabilities[5] == pytest.approx(0.4375)
    with pytest.raises(ValueError):
        Smoother(1.0)


def test_smoothing_to_class_0_drops_the_corners() -> None:
    board, empty = [0.0] * 9, [0.0] * 9
    board[2], empty[0] = 1.0, 1.0
    corners = [[1.0, 2.0], [3.0, 2.0], [3.0, 4.0], [1.0, 4.0]]
    smooth = Smoother(0.75)
    assert smooth.apply(replace(_result(board), corners=corners)).corners == corners
    # the frames' own answers say class 0 (with corners, to see them dropped)
    lagging = [smooth.apply(replace(_result(empty), corners=corners)) for _ in "abc"]
    assert [r.class_id for r in lagging] == [2, 2, 0]  # board at 0.75, 0.56, 0.42
    assert lagging[1].corners == corners and lagging[2].corners is None


@pytest.mark.parametrize(
    ("query", "message"),
    [
        ({"mode": "nope"}, "mode: must be one of whole, sliding, proposals, got 'nope'"),
        ({"smooth": "-0.1"}, "smooth: must be in [0, 1) (0 = off), got '-0.1'"),
        ({"smooth": "nan"}, "smooth: must be in [0, 1) (0 = off), got 'nan'"),
        ({"smooth": "０.5"}, "smooth: must be a number in [0, 1), got '０.5'"),
        ({"smooth": "x"}, "smooth: must be a number in [0, 1), got 'x'"),
        ({"fx": "wide"}, "fx: must be a number of pixels, got 'wide'"),
        ({"fx": "９００"}, "fx: must be a number of pixels, got '９００'"),  # ASCII digits only
        ({"fx": "1_000"}, "fx: must be a number of pixels, got '1_000'"),
        ({"regions": "８x３"}, "in ASCII digits"),
    ],
)
def test_bad_parameters_name_themselves(query: dict[str, str], message: str) -> None:
    with pytest.raises(StreamRefused) as refused:
        parse_options(query)
    assert message in refused.value.message
    assert refused.value.close == CloseCode.INVALID_PARAMETERS


def test_parameters() -> None:
    options = parse_options({"mode": "sliding", "smooth": "0.5", "model": "m", "fx": "512"})
    assert (options.mode, options.smooth, options.model) == ("sliding", 0.5, "m")
    assert options.fx == 512.0 and parse_options({}).fx is None
    assert parse_options({}).mode == "whole" and parse_options({"model": ""}).model is None


def test_a_crash_on_one_frame_is_an_error_message_and_the_stream_goes_on(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    app = create_app(Settings(model_path=DEFAULT_MODEL, stream_track_every=0))  # every frame
    with TestClient(app) as client:  # through the network, the crash's way
        deadline = time.monotonic() + 60
        while client.get("/readyz").status_code != 200 and time.monotonic() < deadline:
            time.sleep(0.05)
        predictor = app.state.pose.predictor
        real = predictor.run
        calls = {"n": 0}

        def flaky(*args: Any, **kwargs: Any) -> object:
            calls["n"] += 1
            if calls["n"] == 2:
                raise RuntimeError("boom")
            return real(*args, **kwargs)

        monkeypatch.setattr(predictor, "run", flaky)
        with client.websocket_connect("/v1/stream") as ws:
            assert json.loads(ws.receive_text())["event"] == "ready"
            answers = []
            for _ in range(3):
                ws.send_bytes(PHOTO.read_bytes())
                answers.append(json.loads(ws.receive_text()))
    assert [a["seq"] for a in answers] == [0, 1, 2]
    assert answers[1]["error"] == {
        "code": "internal_error",
        "message": "frame 1: internal server error (logged)",
    }
    assert answers[2]["class_id"] == answers[0]["class_id"]
