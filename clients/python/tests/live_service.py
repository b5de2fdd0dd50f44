"""Run the REAL service for the client tests: `uvicorn service.app:app` in a subprocess on
127.0.0.1 with a free port and the shipped default model."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

import httpx
import pytest

REPO = Path(__file__).resolve().parents[3]
MODEL = REPO / "models" / "chessboard-corners-160x120.onnx"
#: Its name in the service (the file stem; `/v1/models/default/...` answers with it too).
DEFAULT_NAME = MODEL.stem
REAL = REPO / "train" / "assets" / "real" / "chessboard-stereo"
API_KEY = "client-tests-key"
MAX_IMAGES = 8  # per request, so that "too many images" is cheap to send
STARTUP_TIMEOUT_S = 90.0


def _other_model() -> str:
    """A shipped model of the default's object besides the default that is another network
    (not a renamed copy)."""
    from service.core.preprocess import load_image, to_network_input
    from service.pipeline.model import PoseModel

    photo = (REAL / "left01.jpg").read_bytes()

    def profile_of(card: dict[str, object]) -> object:
        profile = card.get("profile")
        return profile.get("name") if isinstance(profile, dict) else None

    def answers(model: PoseModel) -> list[float]:
        rgb = load_image(photo, min_size=model.input_size).rgb
        return model.predict(to_network_input(rgb, model.input_size)[None])[0].tolist()

    def card_profile(path: Path) -> object:  # the card beside it: no session to build
        card = json.loads(path.with_suffix(".json").read_text())
        return profile_of(card)

    default = PoseModel.load(MODEL)
    default_answers = answers(default)
    for path in sorted(MODEL.parent.glob("*.onnx")):
        if path == MODEL or card_profile(path) != profile_of(default.card):
            continue
        if max(map(abs, map(float.__sub__, answers(PoseModel.load(path)), default_answers))) > 1e-3:
            return path.stem
    raise RuntimeError("the client tests need a shipped model besides the default")


OTHER_MODEL = _other_model()  # importing onnxruntime on a loaded 2-core machine is slow


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@contextmanager
def run_service(wait_for: str = "/readyz", **env: str) -> Iterator[str]:
    """Start `uvicorn service.app:app` with POSE_* settings `env`; yield its URL once
    `wait_for` answers 200; stop it afterwards. Fails with the server's log if it does not."""
    if not MODEL.is_file():
        pytest.fail(f"the client tests need the shipped model {MODEL.relative_to(REPO)}")
    port = _free_port()
    settings = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith("POSE_") or k == "POSE_OPTIMIZED_DIR"  # the run's shared graphs
    }
    settings |= {"POSE_MODEL_PATH": str(MODEL), "POSE_MAX_IMAGES": str(MAX_IMAGES), **env}
    command = [sys.executable, "-m", "uvicorn", "service.app:app", "--host", "127.0.0.1"]
    with tempfile.TemporaryFile("w+") as log, tempfile.TemporaryDirectory() as state:
        # The cameras it learns go to a store of its own, not the user's.
        settings.setdefault("POSE_CAMERA_DB", str(Path(state) / "cameras.sqlite3"))
        server = subprocess.Popen(
            [*command, "--port", str(port), "--log-level", "warning"],
            cwd=REPO,
            env=settings,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        url = f"http://127.0.0.1:{port}"
        try:
            _wait_for(url + wait_for, server, log)
            yield url
        finally:
            server.terminate()
            try:
                server.wait(timeout=15)
            except subprocess.TimeoutExpired:
                server.kill()
                server.wait()


def _wait_for(url: str, server: subprocess.Popen[bytes], log: IO[str]) -> None:
    deadline = time.monotonic() + STARTUP_TIMEOUT_S
    while time.monotonic() < deadline and server.poll() is None:
        try:
            if httpx.get(url, timeout=2.0).status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    log.seek(0)
    pytest.fail(f"{url} did not answer 200; the service's log:\n{log.read()}")
