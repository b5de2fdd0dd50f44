"""Fixtures: the real service, once without and once with an API key, for the whole session."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from live_service import API_KEY, REAL, run_service


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
def photos() -> list[Path]:
    """Three real photographs (640x480 grey JPEGs of a chessboard)."""
    return [REAL / name for name in ("left01.jpg", "right05.jpg", "left12.jpg")]
