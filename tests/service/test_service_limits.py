"""What a request may cost: the pixel budget of a request (HTTP, /v2, a stream frame) read
from the image headers, JSON nested too deep, out-of-range numbers, and the drain state."""

from __future__ import annotations

import base64
import json
import struct

import pytest
from fastapi.testclient import TestClient
from image_bytes import black_png
from service_support import JPEG, PHOTO, AppFactory

from service.bounded_json import MAX_DEPTH, JSONTooDeepError, loads, nesting_depth
from service.core.preprocess import decoded_pixels, image_header, load_image
from service.pipeline.zoom import detail_decode_size
from service.settings import Settings

BUDGET = Settings().max_request_pixels


@pytest.fixture(scope="module")
def bomb() -> bytes:
    """A black 7000 x 7000 PNG: 143 kB, 49 MP (within the per-image limit of 50 MP)."""
    data = black_png(7000, 7000)
    header = image_header(data)
    assert header.width * header.height <= Settings().max_pixels
    return data


def _multipart(images: list[bytes]) -> list[tuple[str, tuple[str, bytes, str]]]:
    return [("image", (f"{i}.png", data, "image/png")) for i, data in enumerate(images)]


def test_sixteen_bombs_are_refused_from_their_headers(client: TestClient, bomb: bytes) -> None:
    r = client.post("/v1/predict", files=_multipart([bomb] * 16))
    assert r.status_code == 413, r.text
    error = r.json()["error"]
    assert error["code"] == "pixel_budget_exceeded"
    assert (
        f"16 image(s), the largest 7000x7000, decode to {16 * 49_000_000} pixels"
        in (error["message"])
    )
    assert f"budget of {BUDGET} pixels per request" in error["message"]
    assert client.post("/v1/predict", content=PHOTO, headers=JPEG).status_code == 200


@pytest.mark.parametrize("binary", [False, True], ids=["json", "binary"])
def test_sixteen_bombs_through_v2_bytes_are_refused(
    client: TestClient, bomb: bytes, binary: bool
) -> None:
    spec = {"name": "image_bytes", "datatype": "BYTES", "shape": [16]}
    if binary:
        raw = b"".join(struct.pack("<I", len(bomb)) + bomb for _ in range(16))
        head = json.dumps({"inputs": [{**spec, "parameters": {"binary_data_size": len(raw)}}]})
        r = client.post(
            "/v2/models/default/infer",
            content=head.encode() + raw,
            headers={"inference-header-content-length": str(len(head))},
        )
    else:
        data = [base64.b64encode(bomb).decode()] * 16
        r = client.post("/v2/models/default/infer", json={"inputs": [{**spec, "data": data}]})
    assert r.status_code == 413, r.text
    assert set(r.json()) == {"error"} and "pixels per request" in r.json()["error"]


def test_a_jpeg_counts_at_the_size_it_is_decoded_at(app_factory: AppFactory) -> None:
    """A 640x480 JPEG decodes at 1/2 (320x240, the zoom pass's detail) in whole mode: it fits
    a budget of 100,000 pixels, which a 640x480 PNG (decoded whole) does not."""
    header = image_header(PHOTO)
    assert (header.width, header.height) == (640, 480)
    decode = detail_decode_size((160, 120))
    assert decoded_pixels(header, decode) == 320 * 240
    assert load_image(PHOTO, min_size=decode).rgb.shape == (240, 320, 3)
    png = black_png(640, 480)
    with app_factory(max_request_pixels=100_000) as c:
        assert c.post("/v1/predict", content=PHOTO, headers=JPEG).status_code == 200
        r = c.post("/v1/predict", content=png, headers={"content-type": "image/png"})
        assert r.status_code == 413 and r.json()["error"]["code"] == "pixel_budget_exceeded"
        with c.websocket_connect("/v1/stream") as ws:
            assert ws.receive_json()["event"] == "ready"
            ws.send_bytes(png)
            refused = ws.receive_json()
            ws.send_bytes(PHOTO)
            answered = ws.receive_json()
    assert refused["seq"] == 0 and refused["error"]["code"] == "pixel_budget_exceeded"
    assert refused["error"]["message"].startswith("frame 0: 1 image(s), the largest 640x480")
    assert answered["seq"] == 1 and "class_id" in answered


def _nested(depth: int) -> bytes:
    return b'{"inputs": ' + b"[" * depth + b"]" * depth + b"}"


@pytest.mark.parametrize("depth", [MAX_DEPTH + 1, 5000, 100_000])
def test_v2_json_nested_too_deep_is_400(client: TestClient, depth: int) -> None:
    r = client.post("/v2/models/default/infer", content=_nested(depth))
    assert r.status_code == 400, r.text
    assert set(r.json()) == {"error"}
    assert f"nested {depth + 1} deep, more than {MAX_DEPTH}" in r.json()["error"]


def test_v2_hostile_shapes_of_valid_json_are_400(client: TestClient) -> None:
    spec = {"name": "x", "datatype": "FP32", "shape": [1], "data": [1.0]}
    for doc in (
        {"inputs": [{**spec, "parameters": [1]}]},
        {"inputs": [spec], "outputs": [1, 2]},
        {"inputs": [{**spec, "data": [10**400]}]},
        {"inputs": [{**spec, "data": "[" * 100 + "]" * 100}]},  # brackets in a string
    ):
        r = client.post("/v2/models/default/infer", json=doc)
        assert r.status_code == 400, (doc, r.text)
        assert set(r.json()) == {"error"}
    r = client.post(
        "/v2/models/default/infer",
        content=b'{"inputs": []}',
        headers={"inference-header-content-length": "999"},
    )
    assert r.status_code == 400 and "more than the body" in r.json()["error"]


def test_the_depth_is_counted_outside_strings_only() -> None:
    assert nesting_depth(b"1") == 0
    assert nesting_depth(b'{"a": [1, {"b": "[[[["}]}') == 3
    assert nesting_depth(b'["\\"[[", [[1]]]') == 3  # an escaped quote does not end the string
    assert nesting_depth(b'["\\\\", [[1]]]') == 3  # an escaped backslash before the quote does
    assert loads(b"[" * MAX_DEPTH + b"]" * MAX_DEPTH) is not None
    with pytest.raises(JSONTooDeepError):
        loads("[" * (MAX_DEPTH + 1) + "]" * (MAX_DEPTH + 1))
    with pytest.raises(ValueError):
        loads(b"\xff")


def test_a_deep_first_stream_message_is_no_key(app_factory: AppFactory) -> None:
    with app_factory(api_key="k") as c, c.websocket_connect("/v1/stream") as ws:
        ws.send_text('{"api_key": ' + "[" * 100_000 + "]" * 100_000 + "}")
        answer = ws.receive_json()
    assert answer["error"]["code"] == "unauthorized"


@pytest.mark.parametrize("fx", ["1", "100000"])
def test_fx_at_the_ends_of_its_range_is_used(client: TestClient, fx: str) -> None:
    r = client.post("/v1/predict", params={"fx": fx}, content=PHOTO, headers=JPEG)
    assert r.status_code == 200, r.text
    result = r.json()["results"][0]
    assert result["fx"] == float(fx) and result["fx_source"] == "query"


@pytest.mark.parametrize("fx", ["0", "1e-320", "100000.5", "1e300", "nan", "-inf"])
def test_fx_out_of_range_closes_the_stream_with_4422(client: TestClient, fx: str) -> None:
    with client.websocket_connect(f"/v1/stream?fx={fx}") as ws:
        answer = ws.receive_json()
    assert answer["error"]["code"] == "invalid_parameters"
    assert answer["error"]["message"].startswith("fx: must be 1 to 100000 pixels, got ")


def test_draining_says_not_ready_and_closes_connections(app_factory: AppFactory) -> None:
    with app_factory() as c:
        state = c.app.state.pose  # type: ignore[attr-defined]
        assert c.get("/readyz").status_code == 200
        assert "connection" not in c.get("/healthz").headers
        state.drain.started = 0.0  # what SIGTERM does with POSE_DRAIN_S (service/api/drain.py)
        r = c.get("/readyz")
        assert r.status_code == 503 and "shutting down (SIGTERM)" in r.json()["error"]["message"]
        assert c.get("/v2/health/ready").status_code == 503
        answer = c.post("/v1/predict", content=PHOTO, headers=JPEG)
        assert answer.status_code == 200 and answer.headers["connection"] == "close"
