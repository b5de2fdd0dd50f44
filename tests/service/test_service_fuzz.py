"""A fuzz corpus against a live server: hundreds of generated hostile requests over HTTP
(/v1/predict: broken and lying images, bombs, malformed multipart, bad query strings), /v2
(mutated infer requests, deep JSON, lying binary headers) and the stream (bad frames, text,
bad query strings). Not one answer may be a 5xx (or a stream's internal_error / 1011), and
the service must answer a photo correctly afterwards, with no traceback in its log."""

from __future__ import annotations

import base64
import json
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import httpx
import numpy as np
import pytest
from image_bytes import black_png, png_claiming
from server_process import live_server
from service_support import JPEG, PHOTO, SERVE
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

SEED = 43
#: The least number of hostile requests the corpus holds (the issue's bar).
LEAST = 300


@dataclass
class Case:
    """One hostile HTTP request: method, path with query, headers and body."""

    path: str
    body: bytes = b""
    headers: dict[str, str] = field(default_factory=dict)
    files: list[tuple[str, tuple[str | None, bytes, str]]] | None = None


def _images(rng: np.random.Generator) -> list[bytes]:
    """Valid images of every format to mutate: the board photo and small random ones."""
    noise = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    encoded = [cv2.imencode(ext, noise)[1].tobytes() for ext in (".png", ".webp", ".bmp")]
    return [PHOTO, *encoded, cv2.imencode(".jpg", noise)[1].tobytes()]


def _mutate(rng: np.random.Generator, data: bytes) -> bytes:
    """One random mutation: truncation, flipped bytes (anywhere or in the header), inserted
    junk, a splice of two halves, a repeated block."""
    raw = bytearray(data)
    how = int(rng.integers(0, 6))
    if how == 0:
        return bytes(raw[: int(rng.integers(0, len(raw)))])
    if how in (1, 2):
        span = len(raw) if how == 1 else min(len(raw), 64)
        for at in rng.integers(0, span, int(rng.integers(1, 24))):
            raw[at] = int(rng.integers(0, 256))
        return bytes(raw)
    at = int(rng.integers(0, len(raw)))
    if how == 3:
        return bytes(raw[:at] + rng.bytes(int(rng.integers(1, 4096))) + raw[at:])
    if how == 4:
        return bytes(raw[:at] + raw[at // 2 :])
    return bytes(raw[:at] + raw[at : at + 512] * int(rng.integers(2, 50)) + raw[at:])


def _jpeg_claiming(w: int, h: int) -> bytes:
    data = bytearray(PHOTO)
    sof = next(i for i in range(2, len(data) - 1) if data[i] == 0xFF and data[i + 1] == 0xC0)
    data[sof + 5 : sof + 9] = struct.pack(">HH", h, w)
    return bytes(data)


def http_cases(rng: np.random.Generator) -> list[Case]:
    """Hostile /v1/predict requests."""
    images = _images(rng)
    media = ["image/png", "image/jpeg", "image/webp", "image/gif", "image/bmp"]
    cases = [
        Case(
            "/v1/predict",
            _mutate(rng, images[int(rng.integers(0, len(images)))]),
            {"content-type": str(rng.choice(media))},
        )
        for _ in range(90)
    ]
    lies = [
        png_claiming(w, h, 32)
        for w, h in (
            (0, 1),
            (1, 0),
            (65535, 65535),
            (2**31 - 1, 2),
            (2**32 - 1, 2**32 - 1),
            (1, 10**9),
        )
    ]
    lies += [_jpeg_claiming(w, h) for w, h in ((0, 0), (65535, 65535), (1, 65535), (7500, 7500))]
    lies += [
        b"GIF89a" + struct.pack("<HH", 65535, 65535),
        b"RIFF\x00\x00\x00\x00WEBPVP8X" + bytes(20),
    ]
    lies += [
        b"BM" + bytes(16) + struct.pack("<ii", 2**31 - 1, -(2**31)),
        b"\xff\xd8\xff",
        b"\x89PNG\r\n\x1a\n",
    ]
    cases += [Case("/v1/predict", data, {"content-type": "image/png"}) for data in lies]
    bomb = black_png(7000, 7000)
    cases += [
        Case("/v1/predict", files=[("image", ("b.png", bomb, "image/png"))] * n) for n in (2, 16)
    ]
    cases += [
        Case("/v1/predict", b"", {"content-type": "image/png"}),
        Case("/v1/predict", PHOTO, {"content-type": "text/plain"}),
        Case("/v1/predict", PHOTO, {}),
        Case("/v1/predict", b"{}", {"content-type": "application/json"}),
        Case("/v1/predict", PHOTO, {"content-type": "multipart/form-data"}),
        Case("/v1/predict", PHOTO, {"content-type": "multipart/form-data; boundary=x"}),
        Case(
            "/v1/predict",
            b"--x\r\n\r\n" * 1000,
            {"content-type": "multipart/form-data; boundary=x"},
        ),
        Case(
            "/v1/predict",
            b"--x\r\nContent-Disposition: form-data; name=image\r\n\r\n" + PHOTO,
            {"content-type": "multipart/form-data; boundary=x"},
        ),
        Case("/v1/predict", files=[("image", ("a.jpg", PHOTO, "image/jpeg"))] * 17),
        Case("/v1/predict", files=[("picture", ("a.jpg", PHOTO, "image/jpeg"))]),
        Case("/v1/predict", files=[("image", ("a.jpg", PHOTO, "text/html"))]),
        Case("/v1/predict", files=[("image", (None, b"", "image/jpeg"))]),
    ]
    queries = [
        "fx=",
        "fx=-1",
        "fx=nan",
        "fx=1e309",
        "fx=0x10",
        "fx=" + "9" * 5000,
        "fx=1&fx=2",
        "mode=",
        "mode=WHOLE",
        "mode=whole%00",
        "mode=" + "x" * 3000,
        "fx=500&mode=sliding",
        "fx=%ff%fe",
        "smooth=2",
        "mode=proposals&fx=1e5",
    ]
    cases += [Case(f"/v1/predict?{q}", PHOTO, JPEG) for q in queries]
    cases += [
        Case(f"/v1/models/{name}/predict", PHOTO, JPEG)
        for name in ("..", "%2e%2e", "a" * 300, "default%00")
    ]
    return cases


def _valid_v2(rng: np.random.Generator) -> dict[str, Any]:
    if rng.random() < 0.5:
        return {
            "inputs": [
                {
                    "name": "image_bytes",
                    "datatype": "BYTES",
                    "shape": [1],
                    "data": [base64.b64encode(PHOTO).decode()],
                }
            ]
        }
    return {
        "id": "x",
        "inputs": [
            {
                "name": "image",
                "datatype": "FP32",
                "shape": [1, 3, 120, 160],
                "data": [0.5] * (3 * 120 * 160),
            }
        ],
        "outputs": [{"name": "class_id"}],
    }


def _junk(rng: np.random.Generator) -> Any:
    values: list[Any] = [
        None,
        [],
        {},
        "x",
        -1,
        0,
        2**63,
        1e308,
        -1e308,
        True,
        "A" * 10000,
        [[[]]],
        {"a": {"b": {}}},
        [None] * 50,
        "\udcff" * 2,
        float("nan"),
    ]
    return values[int(rng.integers(0, len(values)))]


def v2_cases(rng: np.random.Generator) -> list[Case]:
    """Hostile /v2 infer requests: mutated documents, raw junk, lying binary headers."""
    cases = []
    for _ in range(80):
        doc = _valid_v2(rng)
        spec = doc["inputs"][0]
        where = [doc, spec][int(rng.integers(0, 2))]
        key = str(rng.choice(list(where) + ["parameters", "outputs", "shape"]))
        if rng.random() < 0.2:
            where.pop(key, None)
        else:
            where[key] = _junk(rng)
        cases.append(
            Case(
                "/v2/models/default/infer",
                json.dumps(doc).encode(),
                {"content-type": "application/json"},
            )
        )
    for depth in (33, 1000, 5000, 200_000):
        cases.append(
            Case("/v2/models/default/infer", b'{"inputs": ' + b"[" * depth + b"]" * depth + b"}")
        )
        cases.append(
            Case(
                "/v2/models/default/infer",
                b'{"a": ' + b'{"a": ' * depth + b"1" + b"}" * depth + b"}",
            )
        )
    cases += [
        Case("/v2/models/default/infer", body)
        for body in (
            b"",
            b"null",
            b"[]",
            b"\xff\xfe",
            b"{",
            b'{"inputs": [' * 3,
            b"NaN",
            b'"' + b"\\" * 9999 + b'"',
            json.dumps(
                {
                    "inputs": [
                        {"name": "x", "datatype": "FP32", "shape": [2**62, 2**62], "data": [1]}
                    ]
                }
            ).encode(),
            json.dumps(
                {"inputs": [{"name": "x", "datatype": "FP32", "shape": [-1], "data": [1]}]}
            ).encode(),
            json.dumps(
                {"inputs": [{"name": "x", "datatype": "FP32", "shape": [0], "data": []}]}
            ).encode(),
            b'{"inputs": [{"name": "x", "datatype": "FP32", "shape": [1], "data": [NaN]}]}',
            b'{"inputs": [{"name": "x", "datatype": "FP32", "shape": [1], "data": [1'
            + b"0" * 5000
            + b"]}]}",
            json.dumps(
                {"inputs": [{"name": "x", "datatype": "BYTES", "shape": [1], "data": ["!!!"]}]}
            ).encode(),
            json.dumps(
                {
                    "inputs": [
                        {
                            "name": "x",
                            "datatype": "BYTES",
                            "shape": [1],
                            "data": [base64.b64encode(rng.bytes(99)).decode()],
                        }
                    ]
                }
            ).encode(),
        )
    ]
    for _ in range(16):
        raw = rng.bytes(int(rng.integers(0, 64)))
        head = json.dumps(
            {
                "inputs": [
                    {
                        "name": "x",
                        "datatype": str(rng.choice(["BYTES", "FP32"])),
                        "shape": [1],
                        "parameters": {"binary_data_size": int(rng.integers(0, 80))},
                    }
                ]
            }
        ).encode()
        length = str(int(rng.integers(0, len(head) + 80))) if rng.random() < 0.7 else "abc"
        cases.append(
            Case(
                "/v2/models/default/infer", head + raw, {"inference-header-content-length": length}
            )
        )
    cases += [
        Case(
            "/v2/models/default/infer",
            struct.pack("<I", 2**32 - 1) * 4,
            {"inference-header-content-length": "0"},
        )
    ]
    return cases


def stream_frames(rng: np.random.Generator) -> list[bytes | str]:
    """Hostile messages on one stream: mutated and lying images, junk, text."""
    images = _images(rng)
    frames: list[bytes | str] = [
        _mutate(rng, images[int(rng.integers(0, len(images)))]) for _ in range(30)
    ]
    frames += [rng.bytes(int(rng.integers(0, 2048))) for _ in range(8)]
    frames += [png_claiming(65535, 65535), _jpeg_claiming(7500, 7500), b"", black_png(7000, 7000)]
    frames += ["hello", "{}", '{"api_key": 1}', "[" * 5000, "\x00" * 100]
    return frames


#: Hostile query strings of the stream (each its own socket).
STREAM_QUERIES = [
    "mode=",
    "mode=bogus",
    "smooth=nan",
    "smooth=-0.1",
    "smooth=1",
    "fx=0",
    "fx=inf",
    "fx=1e400",
    "fx=abc",
    "model=..",
    "model=" + "m" * 500,
    "fx=500&mode=sliding",
]


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, Path]]:
    log = tmp_path_factory.mktemp("fuzz") / "serve.log"
    with live_server([*SERVE, "--workers", "1"], log, {"POSE_ACCESS_LOG": "false"}) as (base, _):
        yield base, log


def test_the_fuzz_corpus_gets_no_5xx_and_the_service_stays_healthy(
    server: tuple[str, Path],
) -> None:
    base, log = server
    rng = np.random.default_rng(SEED)
    cases = http_cases(rng) + v2_cases(rng)
    frames = stream_frames(rng)
    assert len(cases) + len(frames) + len(STREAM_QUERIES) >= LEAST
    statuses: dict[int, int] = {}
    with httpx.Client(base_url=base, timeout=120) as client:
        for case in cases:
            r = client.post(
                case.path,
                content=None if case.files else case.body,
                headers=case.headers,
                files=case.files,
            )
            assert r.status_code < 500, (case.path, case.headers, case.body[:80], r.text[:300])
            statuses[r.status_code] = statuses.get(r.status_code, 0) + 1
    assert {400, 404, 413, 415, 422} <= set(statuses), statuses  # every kind of refusal
    ws_url = "ws" + base.removeprefix("http") + "/v1/stream"
    answers = []
    with connect(ws_url, compression=None, max_size=None) as ws:
        assert json.loads(ws.recv(timeout=30))["event"] == "ready"
        for frame in frames:
            ws.send(frame)
            answers.append(json.loads(ws.recv(timeout=60)))
    assert not [a for a in answers if a.get("error", {}).get("code") == "internal_error"], answers
    for query in STREAM_QUERIES:
        with connect(f"{ws_url}?{query}", compression=None) as ws:
            first = json.loads(ws.recv(timeout=30))
            if first.get("event") == "ready":
                continue
            assert first["error"]["code"] != "internal_error", (query, first)
            with pytest.raises(ConnectionClosed) as closed:
                ws.recv(timeout=30)
            assert closed.value.rcvd is not None and closed.value.rcvd.code != 1011, query
    # and the service is healthy
    assert httpx.get(base + "/healthz", timeout=30).status_code == 200
    assert httpx.get(base + "/readyz", timeout=30).status_code == 200
    r = httpx.post(base + "/v1/predict", content=PHOTO, headers=JPEG, timeout=60)
    assert r.status_code == 200 and r.json()["results"][0]["class_id"] != 0
    text = log.read_text()
    assert "Traceback" not in text and "unhandled error" not in text, text[-3000:]
