"""The real container: the Dockerfile built by podman (deploy/build_image.py), run read-only
without other flags, healthy, answering a photo, serving its page's files, storing a camera,
as the non-root user, without torch or training code, stopped by SIGTERM.

Needs root with podman, runc and mmdebstrap (`.ci/run` installs them on Debian); skipped with
the reason otherwise. The build's `pip install` and the base image come from the package
registries (PyPI, Debian), as in `.ci/run`.
"""

from __future__ import annotations

import importlib.util
import os
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from types import ModuleType

import httpx
import pytest
from server_process import free_port
from service_support import JPEG, PHOTO, ROOT, check_answer

from service.core.paths import DEFAULT_MODEL_NAME

# The build (pip install of the service's wheels) takes minutes on a loaded 2-core machine.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(1500)]
TAG = "localhost/planar-pose:test"


def _builder() -> ModuleType:
    spec = importlib.util.spec_from_file_location("build_image", ROOT / "deploy/build_image.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["build_image"] = module
    spec.loader.exec_module(module)
    return module


build_image = _builder()


@pytest.fixture(scope="module")
def image() -> str:
    if missing := build_image.missing_tools():
        pytest.skip(f"not installed: {', '.join(missing)} (apt-get install podman runc mmdebstrap)")
    if os.geteuid() != 0:
        pytest.skip("the podman recipe needs root")
    try:
        measured = build_image.build(TAG)
    except build_image.BuildError as exc:
        pytest.fail(str(exc))
    assert measured.image_mb > 0
    return TAG


@contextmanager
def running(image: str, *flags: str, ready: str = "/readyz") -> Iterator[tuple[str, str]]:
    """`podman run -d FLAGS image` on a free port: (container id, base URL) once `ready`
    answers 200; removed afterwards."""
    port = free_port()
    cid = build_image.podman("run", "-d", "-p", f"127.0.0.1:{port}:8000", *flags, image)
    cid_text = cid.stdout.strip()
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 120
        while True:
            try:
                if httpx.get(base + ready, timeout=2).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if time.monotonic() > deadline:
                logs = build_image.podman("logs", cid_text, check=False)
                pytest.fail(f"container not ready after 120 s:\n{logs.stdout}{logs.stderr}")
            time.sleep(0.25)
        yield cid_text, base
    finally:
        build_image.podman("rm", "--force", cid_text, check=False)


#: `--read-only` as Docker has it (no tmpfs on /tmp: podman's --read-only-tmpfs=false).
READ_ONLY = ("--read-only", "--read-only-tmpfs=false")


@pytest.fixture(scope="module")
def container(image: str) -> Iterator[tuple[str, str]]:
    """The image run as a read-only container without any other flag, as deployments run it."""
    with running(image, *READ_ONLY) as started:
        yield started


def test_the_container_answers_a_photo(container: tuple[str, str]) -> None:
    _, base = container
    r = httpx.post(base + "/v1/predict?mode=sliding", content=PHOTO, headers=JPEG, timeout=60)
    assert r.status_code == 200, r.text
    check_answer(r.json(), "sliding", [(640, 480)])
    names = {m["name"] for m in httpx.get(base + "/v1/models").json()["models"]}
    assert DEFAULT_MODEL_NAME in names and len(names) > 1  # the model folder
    assert httpx.get(base + "/v2/health/ready").json() == {"ready": True}


def test_the_page_s_files_and_the_camera_store_are_there(container: tuple[str, str]) -> None:
    """The page's vendored three.js is in the image (package data of subfolders), and the
    camera store at /data/cameras.sqlite3 is writable by the service's user."""
    _, base = container
    three = httpx.get(base + "/static/vendor/three/build/three.module.min.js", timeout=10)
    assert three.status_code == 200 and len(three.content) > 100_000
    made = httpx.post(base + "/v1/cameras", json={"fx": 900.0, "width": 640, "height": 480})
    assert made.status_code == 201, made.text
    listed = httpx.get(base + "/v1/cameras").json()["cameras"]
    assert [c["id"] for c in listed] == [made.json()["id"]]


def test_healthcheck_user_and_no_training_code(container: tuple[str, str]) -> None:
    cid, _ = container
    assert build_image.podman("healthcheck", "run", cid, check=False).returncode == 0
    assert build_image.podman("exec", cid, "id", "-u").stdout.strip() == "10001"
    for module in ("torch", "train"):
        done = build_image.podman("exec", cid, "python", "-c", f"import {module}", check=False)
        assert done.returncode != 0 and f"No module named '{module}'" in done.stderr


def test_a_read_only_container_keeps_its_temporary_files_off_the_root(
    container: tuple[str, str],
) -> None:
    """Read-only without extra flags: no tmpfs on /tmp or /var/tmp, so the service's temporary
    files go to /dev/shm (the camera store is on the image's /data volume: tested above)."""
    cid, _ = container
    mounts = build_image.podman("exec", cid, "cat", "/proc/mounts").stdout
    assert not [m for m in mounts.splitlines() if m.split()[1] in ("/tmp", "/var/tmp")]
    root = [m.split() for m in mounts.splitlines() if m.split()[1] == "/"]
    assert root and "ro" in root[0][3].split(","), root


def test_a_camera_store_on_a_tmpfs_says_what_to_mount_or_works(image: str) -> None:
    """podman's `--tmpfs /data` is root's, mode 755, whatever mode= says: the store answers
    503 naming what to mount, and the tmpfs it names (`:U`, owned by the service's user)
    works."""
    with running(image, *READ_ONLY, "--tmpfs", "/data:mode=1777", ready="/healthz") as (_, base):
        r = httpx.post(base + "/v1/cameras", json={"fx": 900.0})
        assert r.status_code == 503, r.text
        message = r.json()["error"]["message"]
        assert "/data belongs to uid 0 with mode 755" in message, message
        assert "--tmpfs /data:U" in message and "-v pose-data:/data" in message
    with running(image, *READ_ONLY, "--tmpfs", "/data:U", ready="/healthz") as (_, base):
        made = httpx.post(base + "/v1/cameras", json={"fx": 900.0})
        assert made.status_code == 201, made.text
        assert [c["id"] for c in httpx.get(base + "/v1/cameras").json()["cameras"]] == [
            made.json()["id"]
        ]


def test_sigterm_stops_the_container_cleanly(container: tuple[str, str]) -> None:
    cid, _ = container
    build_image.podman("stop", "-t", "15", cid)
    state = build_image.podman("inspect", "--format", "{{.State.ExitCode}}", cid).stdout.strip()
    logs = build_image.podman("logs", cid).stderr + build_image.podman("logs", cid).stdout
    assert "Finished server process" in logs, logs[-2000:]
    assert state in ("0", "143"), state  # exited on SIGTERM, not killed (137)
