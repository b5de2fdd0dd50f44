"""What the live tests share: a real uvicorn serving the shipped model on a free port, the
video made from rendered frames, raw WebSocket helpers and the stream's Prometheus series."""

from __future__ import annotations

import json
import re
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import httpx
import numpy as np
from server_process import live_server

ROOT = Path(__file__).resolve().parents[2]
REAL = ROOT / "train" / "assets" / "real" / "chessboard-stereo"
PHOTO = REAL / "left01.jpg"
API_KEY = "live-tests-key"
FRAME_SIZE = (640, 480)

#: Camera centres (cm, object frame) of the rendered frames and their class (SPEC 3: quadrant
#: from the x/y signs, +4 when z >= 60 cm); None = no object (class 0).
VIEWS: list[tuple[int, tuple[float, float, float] | None]] = [
    (0, None),
    (1, (12, 9, 35)),
    (2, (-12, 9, 35)),
    (3, (-12, -9, 35)),
    (4, (12, -9, 35)),
    (5, (22, 16, 80)),
    (6, (-22, 16, 80)),
    (7, (-22, -16, 80)),
    (8, (22, -16, 80)),
]
FRAMES_PER_VIEW = 3


@dataclass(frozen=True)
class Server:
    url: str
    pid: int

    @property
    def ws(self) -> str:
        return "ws" + self.url.removeprefix("http") + "/v1/stream"


@contextmanager
def run_server(log: Path, ready: str = "/readyz", **env: str) -> Iterator[Server]:
    """`uvicorn service.app:app` with POSE_* settings `env`, once `ready` answers 200."""
    command = [sys.executable, "-m", "uvicorn", "service.app:app", "--host", "127.0.0.1"]
    command += ["--port", "{port}", "--log-level", "warning"]
    with live_server(command, log, env, ready) as (url, proc):
        yield Server(url, proc.pid)


def render_frames() -> tuple[list[np.ndarray], list[int]]:
    """BGR frames (640x480) of VIEWS, FRAMES_PER_VIEW each, by the project's renderer."""
    from service.core.profile import load_profile
    from train.synth.render import render_view

    profile = load_profile("chessboard")
    grey = np.full((FRAME_SIZE[1], FRAME_SIZE[0], 3), 127, np.uint8)
    frames, classes = [], []
    for k, centre in VIEWS:
        rgb = grey if centre is None else render_view(profile, FRAME_SIZE, np.array(centre, float))
        frames += [cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)] * FRAMES_PER_VIEW
        classes += [k] * FRAMES_PER_VIEW
    return frames, classes


def write_video(path: Path, frames: list[np.ndarray], fps: float = 10.0) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, FRAME_SIZE)
    assert writer.isOpened(), f"OpenCV cannot write {path}"
    for frame in frames:
        writer.write(frame)
    writer.release()


def read_video(path: Path) -> list[np.ndarray]:
    capture = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        frames.append(frame)
    capture.release()
    return frames


def jpeg(bgr: np.ndarray, quality: int = 90) -> bytes:
    ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    return buf.tobytes()


def predict_each(
    url: str, frames: list[bytes], mode: str, query: str = "", **headers: str
) -> list[dict[str, Any]]:
    """The /v1/predict answer of each frame, one request per frame (`query`: more parameters,
    e.g. `fx=512`)."""
    results = []
    with httpx.Client(base_url=url, timeout=30, headers=headers) as http:
        for data in frames:
            answer = http.post(
                f"/v1/predict?mode={mode}&{query}",
                content=data,
                headers={"content-type": "image/jpeg"},
            )
            assert answer.status_code == 200, answer.text
            results.append(answer.json()["results"][0])
    return results


def metric(url: str, name: str, **labels: str) -> float:
    """One sample of the service's /metrics (0 when absent)."""
    text = httpx.get(url + "/metrics", timeout=10).text
    want = ",".join(f'{k}="{v}"' for k, v in sorted(labels.items()))
    for line in text.splitlines():
        match = re.fullmatch(rf"{re.escape(name)}(?:\{{(.*)\}})? (\S+)", line)
        if match and ",".join(sorted((match.group(1) or "").split(","))) == want:
            return float(match.group(2))
    return 0.0


def messages(text_messages: list[str | bytes]) -> list[dict[str, Any]]:
    return [json.loads(m) for m in text_messages]
