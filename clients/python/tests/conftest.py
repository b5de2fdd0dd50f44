"""Fixtures: the real service, once without and once with an API key, for the whole session."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from live_service import API_KEY, MODEL, REAL, run_service


@pytest.fixture(scope="session")
def service_url() -> Iterator[str]:
    """The service without an API key."""
    with run_service() as url:
        yield url


@pytest.fixture(scope="session")
def secured_url() -> Iterator[str]:
    """The service requiring API key `API_KEY`."""
    with run_service(POSE_API_KEY=API_KEY) as url:
        yield url


@pytest.fixture(scope="session")
def unready_url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """The service up but never ready: its model file is not an ONNX model."""
    broken = tmp_path_factory.mktemp("model") / "broken.onnx"
    broken.write_bytes(b"not an onnx model")
    with run_service(wait_for="/healthz", POSE_MODEL_PATH=str(broken)) as url:
        yield url


@pytest.fixture(scope="session")
def photos() -> list[Path]:
    """Three real photographs (640x480 grey JPEGs of a chessboard)."""
    return [REAL / name for name in ("left01.jpg", "right05.jpg", "left12.jpg")]


@pytest.fixture(scope="session")
def folder_url() -> Iterator[str]:
    """The service serving the shipped model folder (several models)."""
    with run_service(POSE_MODEL_DIR=str(MODEL.parent)) as url:
        yield url
