"""What the service tests share: paths, the photos, the commands that serve, and a contract
check of /v1/predict answers (a real server process: `server_process.live_server`)."""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from contextlib import AbstractContextManager
from functools import cache
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from service.core.paths import DEFAULT_MODEL, DEFAULT_MODEL_DIR
from service.core.regions import region_of_class
from service.pipeline.model import PoseModel
from service.pipeline.predictor import Predictor
from service.settings import Settings

ROOT = Path(__file__).resolve().parents[2]
REAL = ROOT / "train" / "assets" / "real" / "chessboard-stereo"
PHOTO = (REAL / "left01.jpg").read_bytes()
CARD = json.loads(DEFAULT_MODEL.with_suffix(".json").read_text())


def card_of(model: Path) -> dict[str, Any]:
    """The card beside a shipped model."""
    card: dict[str, Any] = json.loads(model.with_suffix(".json").read_text())
    return card


def _weights(model: Path) -> bytes:
    """The model's weights: its graph's initializers' bytes, in order (the `onnx` package reads
    them without building a session: a second a model on a loaded machine, at every worker's
    collection)."""
    import onnx

    return b"".join(i.raw_data for i in onnx.load(str(model)).graph.initializer)


#: Shipped models other than the default that are other networks (not a copy of the default
#: under another name): the tests need two different networks, whichever the project ships.
_DEFAULT_WEIGHTS = _weights(DEFAULT_MODEL)
OTHER_MODELS = [
    p
    for p in sorted(DEFAULT_MODEL_DIR.glob("*.onnx"))
    if p != DEFAULT_MODEL and _weights(p) != _DEFAULT_WEIGHTS
]
assert len(OTHER_MODELS) >= 2, "the service tests need two shipped models besides the default"


@cache
def served_answer(model: Path) -> np.ndarray:
    """The service's whole-mode probabilities for PHOTO with `model` (the full pipeline)."""
    predictor = Predictor(PoseModel.load(model), Settings())
    return np.array(predictor.predict([(None, PHOTO)], "whole").results[0].probabilities)


def network_of(answer: dict[str, Any], models: tuple[Path, ...]) -> str:
    """The card name of the one of `models` that gave `answer` to PHOTO: the nearest
    probabilities (every answer names the served name, the same before and after a file is
    replaced)."""
    got = np.array(answer["results"][0]["probabilities"])
    nearest = min(models, key=lambda m: float(np.abs(served_answer(m) - got).max()))
    return str(card_of(nearest)["name"])


#: `app_factory` (conftest): `with app_factory(**settings) as client:` an in-process app.
AppFactory = Callable[..., AbstractContextManager[TestClient]]
JPEG = {"content-type": "image/jpeg"}

UVICORN = [sys.executable, "-m", "uvicorn", "service.app:app", "--port", "{port}"]
#: `planar-pose-serve` of this checkout (the console script would import the installed one)
SERVE = [sys.executable, "-m", "service.cli", "--port", "{port}"]


def stream_answers(client: TestClient, frames: list[bytes]) -> list[dict[str, Any]]:
    """Each frame sent on a new `WS /v1/stream` (after its "ready" event) and its answer, in
    lockstep."""
    with client.websocket_connect("/v1/stream") as ws:
        assert ws.receive_json()["event"] == "ready"
        answers = []
        for frame in frames:
            ws.send_bytes(frame)
            answers.append(ws.receive_json())
    return answers


def encode(ext: str, image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(ext, image)
    assert ok
    return buf.tobytes()


def check_answer(
    body: dict[str, Any], mode: str, sizes: list[tuple[int, int]], model: str = CARD["name"]
) -> None:
    """The answer follows the contract: region from the class, probabilities, box in bounds."""
    assert body["model"] == model and body["mode"] == mode
    assert len(body["results"]) == len(sizes)
    for result, (w, h) in zip(body["results"], sizes, strict=True):
        probs = result["probabilities"]
        assert len(probs) == 9 and abs(sum(probs) - 1) < 1e-6 and min(probs) >= 0
        assert result["class_id"] == int(np.argmax(probs))
        assert result["confidence"] == pytest.approx(max(probs))
        assert result["region"] == dict(region_of_class(result["class_id"]))
        assert result["elapsed_ms"] > 0
        corners = result.get("corners")
        if mode != "whole" or result["class_id"] == 0:
            assert corners is None
        elif corners is not None:
            assert len(corners) == 4 and all(len(c) == 2 for c in corners)
        box = result["box"]
        if mode == "whole" or result["class_id"] == 0:
            assert box is None
        else:
            assert box["x"] >= 0 and box["y"] >= 0 and box["w"] >= 1 and box["h"] >= 1
            assert box["x"] + box["w"] <= w and box["y"] + box["h"] <= h


def board_photo() -> tuple[bytes, np.ndarray]:
    """A 640x480 PNG of the profile's board warped onto known corners over grey, and the
    corners [4, 2] in the order (-X,-Y), (+X,-Y), (+X,+Y), (-X,+Y) (the texture's bottom left
    square is the (-X,-Y) one)."""
    texture = cv2.imread(str(ROOT / "train/assets/profiles/chessboard/texture.png"))
    th, tw = texture.shape[:2]
    corners = np.float32([[190, 335], [470, 350], [455, 130], [205, 115]])
    src = np.float32([[0, th], [tw, th], [tw, 0], [0, 0]])
    H = cv2.getPerspectiveTransform(src, corners)
    image = cv2.warpPerspective(texture, H, (640, 480), borderValue=(128, 128, 128))
    return encode(".png", image), corners
