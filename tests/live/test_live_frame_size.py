"""How large a stream frame may be, under `planar-pose-serve` (its WebSocket limit is
POSE_MAX_UPLOAD_BYTES + 4 KiB): up to POSE_MAX_UPLOAD_BYTES a frame is read and answered (the
pixel limits apply to what it decodes to), above it the frame gets `payload_too_large` and the
stream goes on, above the WebSocket limit the connection closes (1009, message too big)."""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from live_support import PHOTO
from server_process import live_server
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from service.settings import Settings

SERVE = [str(Path(sys.executable).with_name("planar-pose-serve")), "--port", "{port}"]
LIMIT = Settings().max_upload_bytes


@pytest.fixture(scope="module")
def stream_url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    log = tmp_path_factory.mktemp("frames") / "serve.log"
    with live_server([*SERVE, "--workers", "1"], log, {"POSE_ACCESS_LOG": "false"}) as (url, _):
        yield "ws" + url.removeprefix("http") + "/v1/stream"


def test_frames_up_to_the_upload_limit_are_answered(stream_url: str) -> None:
    photo = PHOTO.read_bytes()
    big = photo + bytes(17 * 1024 * 1024)  # 17 MiB: a JPEG with junk after its end
    over = bytes(LIMIT + 1)
    with connect(stream_url, compression=None, max_size=None) as ws:
        assert json.loads(ws.recv(timeout=30))["event"] == "ready"
        answers = []
        for frame in (big, over, photo):
            ws.send(frame)
            answers.append(json.loads(ws.recv(timeout=60)))
    assert answers[0]["seq"] == 0 and "class_id" in answers[0], answers[0]
    assert answers[1]["error"]["code"] == "payload_too_large"
    assert answers[1]["error"]["message"] == f"frame 1 is larger than {LIMIT} bytes"
    assert answers[2]["seq"] == 2 and answers[2]["class_id"] == answers[0]["class_id"]


def test_a_frame_above_the_websocket_limit_ends_the_connection(stream_url: str) -> None:
    """uvicorn closes (1009) while the frame still arrives: the client sees the close or,
    still sending, a reset; the service goes on."""
    with connect(stream_url, compression=None, max_size=None) as ws:
        assert json.loads(ws.recv(timeout=30))["event"] == "ready"
        with pytest.raises((ConnectionClosed, OSError)) as ended:
            ws.send(bytes(LIMIT + 8192))
            ws.recv(timeout=60)
    if isinstance(ended.value, ConnectionClosed) and ended.value.rcvd is not None:
        assert ended.value.rcvd.code == 1009
    with connect(stream_url, compression=None) as ws:
        assert json.loads(ws.recv(timeout=30))["event"] == "ready"
        ws.send(PHOTO.read_bytes())
        assert "class_id" in json.loads(ws.recv(timeout=60))
