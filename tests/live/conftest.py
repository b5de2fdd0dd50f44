"""Fixtures of the live tests: real servers (uvicorn in a subprocess, shipped model), one
without and one with an API key, and the test video, for the whole session."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from live_support import API_KEY, Server, render_frames, run_server, write_video


@pytest.fixture(scope="session")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """The service without an API key."""
    with run_server(tmp_path_factory.mktemp("server") / "server.log") as live:
        yield live


@pytest.fixture(scope="session")
def secured(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """The service requiring API key `API_KEY`."""
    log = tmp_path_factory.mktemp("secured") / "server.log"
    with run_server(log, POSE_API_KEY=API_KEY) as live:
        yield live


@pytest.fixture(scope="session")
def video(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[int]]:
    """An MP4 (640x480, 27 frames) of rendered views of known classes, and those classes."""
    frames, classes = render_frames()
    path = tmp_path_factory.mktemp("video") / "views.mp4"
    write_video(path, frames)
    return path, classes
