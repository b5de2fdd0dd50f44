"""Fixtures of the service tests: in-process apps (TestClient, model loaded) for most HTTP
cases, a factory for apps with other settings."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import pytest
from fastapi.testclient import TestClient
from service_support import AppFactory

from service.app import create_app
from service.settings import Settings


@contextmanager
def running_app(
    ready: str = "/readyz", raise_server_exceptions: bool = True, **settings: Any
) -> Iterator[TestClient]:
    """A TestClient of `create_app(Settings(**settings))`, its lifespan run (the default
    model loaded), once `ready` answers 200 (every worker's, with `workers` > 1)."""
    app = create_app(Settings(**settings))
    with TestClient(app, raise_server_exceptions=raise_server_exceptions) as client:
        deadline = time.monotonic() + 120  # two test workers on two cores: slow loads
        while client.get(ready).status_code != 200:
            if time.monotonic() > deadline:
                pytest.fail(f"{ready} did not answer 200: {client.get(ready).text}")
            time.sleep(0.02)
        yield client


@pytest.fixture(scope="session")
def app_factory() -> AppFactory:
    """`with app_factory(api_key="k") as client:` an app with those settings."""
    return running_app


@pytest.fixture(scope="session")
def client() -> Iterator[TestClient]:
    """The default app (shipped model, no API key), shared by the whole session."""
    with running_app() as c:
        yield c
