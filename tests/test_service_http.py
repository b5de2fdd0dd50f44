"""End to end: a real uvicorn on 127.0.0.1 serving the shipped model, happy paths, a hostile
corpus (each answered with its status and JSON error, the server staying up), API keys,
readiness, metrics, and a request in flight surviving SIGTERM."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import cv2
import httpx
import numpy as np
import pytest
from image_bytes import png_claiming, with_exif_orientation

from service.app import create_app
from service.predictor import Predictor
from service.regions import region_of_class
from service.settings import DEFAULT_MODEL, Settings

ROOT = Path(__file__).resolve().parent.parent
REAL = ROOT / "train" / "assets" / "real" / "chessboard-stereo"
CARD = json.loads(DEFAULT_MODEL.with_suffix(".json").read_text())


# --- a live server in a subprocess ---------------------------------------------------------


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_until_up(url: str, proc: subprocess.Popen[bytes], log: Path, timeout: float = 60) -> None:
    """Poll `url` until it answers 200; fail with the server log if the process dies."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            pytest.fail(f"server exited with {proc.returncode}:\n{log.read_text()}")
        try:
            if httpx.get(url, timeout=2).status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(0.1)
    pytest.fail(f"server not up at {url} after {timeout} s:\n{log.read_text()}")


def stop(proc: subprocess.Popen[bytes]) -> int:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode


@contextmanager
def live_server(
    command: list[str],
    log: Path,
    env: dict[str, str] | None = None,
    ready: str = "/readyz",
    cwd: Path = ROOT,
) -> Iterator[tuple[str, subprocess.Popen[bytes]]]:
    """Run `command` (with `{port}` filled in), yield (base URL, process), stop it."""
    port = free_port()
    clean = {k: v for k, v in os.environ.items() if not k.startswith("POSE_")}
    with log.open("wb") as sink:
        proc = subprocess.Popen(
            [part.format(port=port) for part in command],
            cwd=cwd,
            env={**clean, **(env or {})},
            stdout=sink,
            stderr=subprocess.STDOUT,
        )
    base = f"http://127.0.0.1:{port}"
    try:
        wait_until_up(base + ready, proc, log)
        yield base, proc
    finally:
        stop(proc)


UVICORN = [sys.executable, "-m", "uvicorn", "service.app:app", "--port", "{port}"]
SERVE = [str(Path(sys.executable).with_name("planar-pose")), "serve", "--port", "{port}"]


@pytest.fixture(scope="session")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    log = tmp_path_factory.mktemp("server") / "uvicorn.log"
    with live_server([*UVICORN, "--host", "127.0.0.1"], log) as (base, _):
        yield base
    assert "Traceback" not in log.read_text()


@pytest.fixture()
def client(server: str) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=server, timeout=60) as c:
        yield c


# --- inputs ----------------------------------------------------------------------------------


def encode(ext: str, image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(ext, image)
    assert ok
    return buf.tobytes()


PHOTO = (REAL / "left01.jpg").read_bytes()
BGR = cv2.imread(str(REAL / "right05.jpg"), cv2.IMREAD_COLOR)
GREY = cv2.imread(str(REAL / "left03.jpg"), cv2.IMREAD_GRAYSCALE)

# name -> (bytes, content type, (width, height) after EXIF orientation)
IMAGES: dict[str, tuple[bytes, str, tuple[int, int]]] = {
    "jpeg": (PHOTO, "image/jpeg", (640, 480)),
    "png": (encode(".png", BGR), "image/png", (640, 480)),
    "webp": (encode(".webp", BGR), "image/webp", (640, 480)),
    "bmp": (encode(".bmp", BGR), "image/bmp", (640, 480)),
    "gif": (encode(".gif", BGR), "image/gif", (640, 480)),
    "grey-png": (encode(".png", GREY), "image/png", (640, 480)),
    "rgba-png": (encode(".png", cv2.cvtColor(BGR, cv2.COLOR_BGR2BGRA)), "image/png", (640, 480)),
    "16bit-png": (encode(".png", GREY.astype(np.uint16) * 257), "image/png", (640, 480)),
    "exif-rotated": (with_exif_orientation(PHOTO, 6), "image/jpeg", (480, 640)),
    "tiny-1x1": (encode(".png", np.full((1, 1, 3), 200, np.uint8)), "image/png", (1, 1)),
    "small-crop": (encode(".jpg", BGR[100:200, 300:420]), "image/jpeg", (120, 100)),
}


def check_answer(body: dict[str, Any], mode: str, sizes: list[tuple[int, int]]) -> None:
    """The answer follows the contract: region from the class, probabilities, box in bounds."""
    assert body["model"] == CARD["name"] and body["mode"] == mode
    assert len(body["results"]) == len(sizes)
    for result, (w, h) in zip(body["results"], sizes, strict=True):
        probs = result["probabilities"]
        assert len(probs) == 9 and abs(sum(probs) - 1) < 1e-6 and min(probs) >= 0
        assert result["class_id"] == int(np.argmax(probs))
        assert result["confidence"] == pytest.approx(max(probs))
        assert result["region"] == dict(region_of_class(result["class_id"]))
        assert result["elapsed_ms"] > 0
        box = result["box"]
        if mode == "whole" or result["class_id"] == 0:
            assert box is None
        else:
            assert box["x"] >= 0 and box["y"] >= 0 and box["w"] >= 1 and box["h"] >= 1
            assert box["x"] + box["w"] <= w and box["y"] + box["h"] <= h


# --- happy paths -----------------------------------------------------------------------------


@pytest.mark.parametrize("mode", ["whole", "sliding", "proposals"])
@pytest.mark.parametrize("name", list(IMAGES))
def test_raw_body_every_kind_of_image(client: httpx.Client, name: str, mode: str) -> None:
    data, media, size = IMAGES[name]
    r = client.post(
        "/v1/predict", params={"mode": mode}, content=data, headers={"content-type": media}
    )
    assert r.status_code == 200, r.text
    check_answer(r.json(), mode, [size])
    assert r.json()["results"][0]["filename"] is None


def inference_count(client: httpx.Client, mode: str) -> float:
    text = client.get("/metrics").text
    prefix = f'pose_inference_seconds_count{{mode="{mode}"}} '
    lines = text.splitlines()
    return next((float(ln[len(prefix) :]) for ln in lines if ln.startswith(prefix)), 0.0)


@pytest.mark.parametrize("mode", ["whole", "sliding", "proposals"])
def test_many_images_one_batched_call(client: httpx.Client, mode: str) -> None:
    names = ["jpeg", "png", "exif-rotated", "tiny-1x1", "grey-png"]
    files = [("image", (f"{n}.img", IMAGES[n][0], IMAGES[n][1])) for n in names]
    calls = inference_count(client, mode)
    r = client.post("/v1/predict", params={"mode": mode}, files=files)
    assert r.status_code == 200, r.text
    body = r.json()
    check_answer(body, mode, [IMAGES[n][2] for n in names])
    assert [res["filename"] for res in body["results"]] == [f"{n}.img" for n in names]
    assert inference_count(client, mode) == calls + 1  # one onnxruntime run for all images
    for n, res in zip(names, body["results"], strict=True):
        alone = client.post(
            "/v1/predict", params={"mode": mode}, files=[("image", (n, *IMAGES[n][:2]))]
        )
        assert alone.json()["results"][0]["class_id"] == res["class_id"]
        assert np.allclose(
            alone.json()["results"][0]["probabilities"], res["probabilities"], atol=1e-5
        )


def test_model_card_health_ready_docs(client: httpx.Client) -> None:
    card = client.get("/v1/model").json()
    assert card["name"] == CARD["name"] and card["input"] == CARD["input"]
    assert len(card["classes"]) == 9
    assert client.get("/healthz").json()["status"] == "ok"
    assert client.get("/readyz").json() == {"status": "ready", "model": CARD["name"]}
    assert client.get("/docs").status_code == 200
    spec = client.get("/openapi.json").json()["paths"]["/v1/predict"]["post"]
    assert {"multipart/form-data", "image/*"} <= set(spec["requestBody"]["content"])


def test_metrics_count_requests_by_route_and_status(client: httpx.Client) -> None:
    client.post("/v1/predict", content=b"", headers={"content-type": "image/png"})
    r = client.get("/metrics")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/plain")
    text = r.text
    assert 'pose_http_requests_total{method="POST",route="/v1/predict",status="400"}' in text
    assert 'pose_http_request_duration_seconds_bucket{le="0.005",route="/v1/predict"}' in text
    assert 'pose_images_processed_total{mode="whole"}' in text


# --- hostile corpus --------------------------------------------------------------------------


def chunks(total: int) -> Iterator[bytes]:
    for _ in range(total // 1_048_576):
        yield bytes(1_048_576)


TOO_MANY = [("image", (f"{i}.jpg", PHOTO, "image/jpeg")) for i in range(17)]

HOSTILE: dict[str, tuple[dict[str, Any], int, str]] = {
    "zero-bytes": (
        {"content": b"", "headers": {"content-type": "image/jpeg"}},
        400,
        "undecodable_image",
    ),
    "truncated-jpeg": (
        {"content": PHOTO[: len(PHOTO) // 2], "headers": {"content-type": "image/jpeg"}},
        400,
        "undecodable_image",
    ),
    "text-as-image": (
        {"content": b"hello, I am text" * 20, "headers": {"content-type": "image/png"}},
        400,
        "undecodable_image",
    ),
    "png-header-only": (
        {"content": png_claiming(40, 30, padding=64), "headers": {"content-type": "image/png"}},
        400,
        "undecodable_image",
    ),
    "wrong-content-type": (
        {"content": PHOTO, "headers": {"content-type": "text/plain"}},
        415,
        "unsupported_media_type",
    ),
    "no-content-type": ({"content": PHOTO}, 415, "unsupported_media_type"),
    "svg": (
        {"content": b"<svg/>", "headers": {"content-type": "image/svg+xml"}},
        415,
        "unsupported_media_type",
    ),
    "tiff-part": (
        {"files": [("image", ("a.tif", PHOTO, "image/tiff"))]},
        415,
        "unsupported_media_type",
    ),
    "png-50000x50000": (
        {
            "content": png_claiming(50_000, 50_000, padding=64),
            "headers": {"content-type": "image/png"},
        },
        413,
        "image_too_large",
    ),
    "oversize-body": (
        {"content": bytes(21 * 1_048_576), "headers": {"content-type": "image/png"}},
        413,
        "payload_too_large",
    ),
    "oversize-chunked": (
        {"content": chunks(30 * 1_048_576), "headers": {"content-type": "image/png"}},
        413,
        "payload_too_large",
    ),
    "too-many-images": ({"files": TOO_MANY}, 413, "too_many_images"),
    "bad-mode": (
        {"params": {"mode": "fast"}, "content": PHOTO, "headers": {"content-type": "image/jpeg"}},
        422,
        "invalid_parameters",
    ),
    "no-image-field": (
        {"files": [("photo", ("a.jpg", PHOTO, "image/jpeg"))]},
        422,
        "invalid_parameters",
    ),
    "text-field": (
        {"data": {"image": "x"}, "files": [("x", ("a", b"1", "image/png"))]},
        422,
        "invalid_parameters",
    ),
    "broken-multipart": (
        {
            "content": b"--x\r\nContent-Disposition: form-data\r\n\r\nzz",
            "headers": {"content-type": "multipart/form-data; boundary=x"},
        },
        400,
        "bad_request",
    ),
}


@pytest.fixture(scope="module")
def baseline(server: str) -> dict[str, Any]:
    r = httpx.post(server + "/v1/predict", content=PHOTO, headers={"content-type": "image/jpeg"})
    return r.json()["results"][0]


@pytest.mark.parametrize("name", list(HOSTILE))
def test_hostile_input_gets_its_error_and_the_server_stays_up(
    client: httpx.Client, baseline: dict[str, Any], name: str
) -> None:
    kwargs, status, code = HOSTILE[name]
    r = client.post("/v1/predict", **kwargs)
    assert r.status_code == status, r.text
    assert r.json()["error"]["code"] == code
    assert set(r.json()["error"]) == {"code", "message"} and "Traceback" not in r.text
    after = client.post("/v1/predict", content=PHOTO, headers={"content-type": "image/jpeg"})
    assert after.status_code == 200
    assert after.json()["results"][0]["probabilities"] == baseline["probabilities"]


def test_not_found_and_wrong_method_are_json(client: httpx.Client) -> None:
    assert client.get("/nope").json()["error"]["code"] == "not_found"
    assert client.get("/v1/predict").json()["error"]["code"] == "method_not_allowed"


# --- API key, CORS, readiness, crashes, shutdown ---------------------------------------------


@pytest.fixture(scope="module")
def keyed_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    env = {"POSE_API_KEY": "s3cret", "POSE_CORS_ORIGINS": "https://app.example"}
    log = tmp_path_factory.mktemp("keyed") / "uvicorn.log"
    with live_server(UVICORN, log, env) as (base, _):
        yield base


@pytest.mark.parametrize(
    ("headers", "status"),
    [
        ({}, 401),
        ({"authorization": "Bearer wrong"}, 401),
        ({"authorization": "Basic s3cret"}, 401),
        ({"x-api-key": "s3cre"}, 401),
        ({"authorization": "Bearer s3cret"}, 200),
        ({"x-api-key": "s3cret"}, 200),
    ],
)
def test_api_key(keyed_server: str, headers: dict[str, str], status: int) -> None:
    r = httpx.post(
        keyed_server + "/v1/predict",
        content=PHOTO,
        headers={"content-type": "image/jpeg", **headers},
    )
    assert r.status_code == status
    assert httpx.get(keyed_server + "/v1/model", headers=headers).status_code == status
    if status == 401:
        assert r.json()["error"]["code"] == "unauthorized"
        assert r.headers["www-authenticate"] == "Bearer"
    for open_path in ("/healthz", "/readyz", "/metrics"):
        assert httpx.get(keyed_server + open_path).status_code == 200


def test_cors_preflight(keyed_server: str) -> None:
    r = httpx.options(
        keyed_server + "/v1/predict",
        headers={"origin": "https://app.example", "access-control-request-method": "POST"},
    )
    assert r.headers["access-control-allow-origin"] == "https://app.example"


def test_not_ready_without_model(tmp_path: Path) -> None:
    env = {"POSE_MODEL_PATH": str(tmp_path / "missing.onnx")}
    with live_server(UVICORN, tmp_path / "log", env, ready="/healthz") as (base, _):
        r = httpx.get(base + "/readyz")
        assert r.status_code == 503 and r.json()["error"]["code"] == "not_ready"
        assert "missing.onnx" in r.json()["error"]["message"]
        r = httpx.post(base + "/v1/predict", content=PHOTO, headers={"content-type": "image/jpeg"})
        assert r.status_code == 503 and r.json()["error"]["code"] == "not_ready"
        assert httpx.get(base + "/v1/model").status_code == 503
        assert httpx.get(base + "/healthz").status_code == 200


def test_unexpected_exception_is_logged_and_answered_500(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    def explode(self: Predictor, images: Any, mode: str) -> None:
        raise RuntimeError("secret internals")

    monkeypatch.setattr(Predictor, "predict", explode)
    app = create_app(Settings())

    async def call() -> httpx.Response:
        transport = httpx.ASGITransport(app, raise_app_exceptions=False)
        async with (
            app.router.lifespan_context(app),
            httpx.AsyncClient(transport=transport, base_url="http://t") as c,
        ):
            for _ in range(300):
                if (await c.get("/readyz")).status_code == 200:
                    break
                await asyncio.sleep(0.05)
            return await c.post(
                "/v1/predict", content=PHOTO, headers={"content-type": "image/jpeg"}
            )

    r = asyncio.run(call())
    assert r.status_code == 500
    assert r.json() == {
        "error": {"code": "internal_error", "message": "internal server error (logged)"}
    }
    assert "secret internals" in caplog.text and "Traceback" not in r.text


def test_request_in_flight_at_sigterm_still_gets_its_answer(tmp_path: Path) -> None:
    """SIGTERM while a request's body is still arriving: uvicorn drains it, then exits."""
    log = tmp_path / "serve.log"
    with live_server(SERVE, log) as (base, proc):
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
