"""A server process for the tests that need a real socket: a free port, the environment
without POSE_* settings, start and wait until it answers, stop. Shared by tests/service and
tests/live (pytest puts tests/ on the import path, `pythonpath` in pyproject.toml)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import pytest

ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_until_up(url: str, proc: subprocess.Popen[bytes], log: Path, timeout: float = 180) -> None:
    """Poll `url` until it answers 200; fail with the server log if the process dies (or
    after `timeout` s: a 2-core machine running two test workers, scripts/test.sh, may take
    a minute and more to start a server)."""
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


def stop(proc: subprocess.Popen[bytes], timeout: float = 30) -> int:
    """SIGTERM, wait (kill after `timeout` s); the exit code."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode


#: The one POSE_* variable a server inherits: the run's folder of optimized graphs
#: (tests/conftest.py).
SHARED = "POSE_OPTIMIZED_DIR"


def clean_env(**env: str) -> dict[str, str]:
    """This process's environment without POSE_* variables (but `SHARED`), plus `env`."""
    kept = {k: v for k, v in os.environ.items() if not k.startswith("POSE_") or k == SHARED}
    return {**kept, **env}


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
    with log.open("wb") as sink:
        proc = subprocess.Popen(
            [part.format(port=port) for part in command],
            cwd=cwd,
            env=clean_env(**(env or {})),
            stdout=sink,
            stderr=subprocess.STDOUT,
        )
    base = f"http://127.0.0.1:{port}"
    try:
        wait_until_up(base + ready, proc, log)
        yield base, proc
    finally:
        stop(proc)
