"""What needs a real socket and process: the `uvicorn service.app:app` entry point, a chunked
body larger than the limit while it streams in, and a request in flight surviving SIGTERM."""

from __future__ import annotations

import json
import signal
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from server_process import live_server
from service_support import JPEG, PHOTO, SERVE, UVICORN, check_answer


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    log = tmp_path_factory.mktemp("server") / "uvicorn.log"
    with live_server([*UVICORN, "--host", "127.0.0.1"], log) as (base, _):
        yield base
    assert "Traceback" not in log.read_text()


def chunks(total: int) -> Iterator[bytes]:
    for _ in range(total // 1_048_576):
        yield bytes(1_048_576)


def test_uvicorn_entry_answers(server: str) -> None:
    r = httpx.post(server + "/v1/predict?mode=sliding", content=PHOTO, headers=JPEG, timeout=60)
    assert r.status_code == 200, r.text
    check_answer(r.json(), "sliding", [(640, 480)])


def test_oversize_chunked_body_is_cut_off_while_streaming(server: str) -> None:
    r = httpx.post(
        server + "/v1/predict",
        content=chunks(30 * 1_048_576),
        headers={"content-type": "image/png"},
        timeout=60,
    )
    assert r.status_code == 413 and r.json()["error"]["code"] == "payload_too_large"
    after = httpx.post(server + "/v1/predict", content=PHOTO, headers=JPEG, timeout=60)
    assert after.status_code == 200


@pytest.mark.parametrize("workers", ["1", "2"])
def test_request_in_flight_at_sigterm_still_gets_its_answer(tmp_path: Path, workers: str) -> None:
    """SIGTERM while a request's body is still arriving: uvicorn drains it, then exits (with
    worker processes: the supervisor passes SIGTERM on, each worker drains)."""
    log = tmp_path / "serve.log"
    with live_server([*SERVE, "--workers", workers], log) as (base, proc):
        port = int(base.rsplit(":", 1)[1])
        head = (
            f"POST /v1/predict?mode=sliding HTTP/1.1\r\nHost: x\r\nContent-Type: image/jpeg\r\n"
            f"Content-Length: {len(PHOTO)}\r\nConnection: close\r\n\r\n"
        ).encode()
        with socket.create_connection(("127.0.0.1", port), timeout=30) as sock:
            sock.sendall(head + PHOTO[:1000])
            time.sleep(0.5)
            proc.send_signal(signal.SIGTERM)
            time.sleep(0.5)
            assert proc.poll() is None  # still draining
            sock.sendall(PHOTO[1000:])
            answer = b""
            while chunk := sock.recv(65536):
                answer += chunk
        # uvicorn re-raises the signal once drained: exit by SIGTERM, not a crash code
        assert proc.wait(timeout=30) in (0, -signal.SIGTERM)
    assert "Finished server process" in log.read_text()
    status, _, body = answer.partition(b"\r\n\r\n")
    assert status.startswith(b"HTTP/1.1 200"), answer[:300]
    check_answer(json.loads(body), "sliding", [(640, 480)])
