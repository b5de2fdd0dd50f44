"""No failed request when the service stops or its model is redeployed, under load, with 2
worker processes (and 1): SIGTERM drains (POSE_DRAIN_S), and a model file replaced by `rm` + `cp`,
by an atomic rename or by a Kubernetes-style symlink swap keeps answering throughout."""

from __future__ import annotations

import os
import shutil
import signal
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest
from server_process import live_server
from service_support import CARD, JPEG, PHOTO, SERVE, card_of, network_of, served_answer
from test_service_models import DEFAULT, REPLACEMENT, SMALL

NEW_NAME = card_of(REPLACEMENT)["name"]


class Load:
    """Threads posting the photo to /v1/predict until stopped: half on one keep-alive
    connection, half on a new connection per request; every answer or failure counted."""

    def __init__(self, base: str, threads: int = 6) -> None:
        self.base, self.stop = base, threading.Event()
        self.answers: Counter[str] = Counter()
        self.failures: list[str] = []
        self.threads = [threading.Thread(target=self._run, args=(i % 2,)) for i in range(threads)]

    def _run(self, fresh: int) -> None:
        client = httpx.Client(base_url=self.base, timeout=60)
        while not self.stop.is_set():
            try:
                r = client.post("/v1/predict", content=PHOTO, headers=JPEG)
                if r.status_code == 200:
                    self.answers[network_of(r.json(), (SMALL, REPLACEMENT))] += 1
                else:
                    self.failures.append(f"{r.status_code} {r.text[:200]}")
            except httpx.HTTPError as exc:
                self.failures.append(repr(exc))
            if fresh:
                client.close()
                client = httpx.Client(base_url=self.base, timeout=60)
        client.close()

    def __enter__(self) -> Load:
        for t in self.threads:
            t.start()
        return self

    def __exit__(self, *_: object) -> None:
        self.stop.set()
        for t in self.threads:
            t.join()

    @property
    def count(self) -> int:
        return sum(self.answers.values())


def _wait_for(what: Callable[[], bool], seconds: float) -> None:
    deadline = time.monotonic() + seconds
    while not what():
        assert time.monotonic() < deadline, f"not within {seconds} s"
        time.sleep(0.05)


def _not_ready(base: str) -> bool:
    ready = httpx.get(base + "/readyz", timeout=10)
    assert ready.status_code == 503 or ready.json()["status"] == "ready"
    return ready.status_code == 503 and "shutting down (SIGTERM)" in ready.text


@pytest.mark.parametrize("workers", [2, 1])
def test_sigterm_under_load_fails_no_request(tmp_path: Path, workers: int) -> None:
    """SIGTERM to `planar-pose-serve --workers 2` (and 1) under load: /readyz 503 at once,
    every request sent during the drain answered 200, then the listener refuses and it
    exits."""
    log = tmp_path / "serve.log"
    env = {"POSE_DRAIN_S": "4", "POSE_ACCESS_LOG": "false"}
    with live_server([*SERVE, "--workers", str(workers)], log, env) as (base, proc):
        with Load(base) as load:
            _wait_for(lambda: load.count >= 20, 60)
            proc.send_signal(signal.SIGTERM)
            signalled, at_signal = time.monotonic(), load.count
            _wait_for(lambda: _not_ready(base), 1.0)
            time.sleep(max(0.0, signalled + 2.0 - time.monotonic()))  # within the drain
        assert load.failures == [], load.failures[:5]
        assert load.count > at_signal  # answered during the drain
        assert proc.wait(timeout=60) in (0, -signal.SIGTERM)
        with pytest.raises(httpx.ConnectError):  # refused, not accepted and reset
            httpx.get(base + "/healthz", timeout=5)
    text = log.read_text()
    assert text.count("SIGTERM: draining for 4 s") == workers  # each worker
    assert text.count("Finished server process") == workers and "Traceback" not in text


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("deploy")
    for suffix in (".onnx", ".json"):
        shutil.copyfile(SMALL.with_suffix(suffix), path / f"{DEFAULT}{suffix}")
    return path


@pytest.fixture(scope="module")
def watched(folder: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """`planar-pose-serve --workers 2` on `folder`, watching it every 0.1 s."""
    log = tmp_path_factory.mktemp("watched") / "serve.log"
    env = {"POSE_MODEL_WATCH_S": "0.1", "POSE_ACCESS_LOG": "false"}
    with live_server([*SERVE, "--workers", "2", "--model-dir", str(folder)], log, env) as (
        base,
        _,
    ):
        yield base
    assert "Traceback" not in log.read_text()


def _every_worker_answers(base: str, name: str) -> bool:
    for _ in range(8):  # new connections: the kernel spreads them over both workers
        r = httpx.post(base + "/v1/predict", content=PHOTO, headers=JPEG, timeout=60)
        if r.status_code != 200 or network_of(r.json(), (SMALL, REPLACEMENT)) != name:
            return False
    return True


def _copy_in_place(source: Path, target: Path) -> None:
    """`cp`: the target written in chunks where it is, seen half written meanwhile."""
    with source.open("rb") as src, target.open("wb") as out:
        while chunk := src.read(256 * 1024):
            out.write(chunk)
            out.flush()
            time.sleep(0.02)


def _rm_then_cp(folder: Path, source: Path) -> None:
    for suffix in (".onnx", ".json"):
        (folder / f"{DEFAULT}{suffix}").unlink()
    time.sleep(1.0)  # the watcher sees the file gone, twice over
    _copy_in_place(source.with_suffix(".json"), folder / f"{DEFAULT}.json")
    _copy_in_place(source.with_suffix(".onnx"), folder / f"{DEFAULT}.onnx")


def _atomic_rename(folder: Path, source: Path) -> None:
    for suffix in (".json", ".onnx"):
        tmp = folder / f".{DEFAULT}{suffix}.tmp"
        shutil.copyfile(source.with_suffix(suffix), tmp)
        os.replace(tmp, folder / f"{DEFAULT}{suffix}")


def _symlink_swap(folder: Path, source: Path) -> None:
    """A Kubernetes volume's update: the files are links through `..data`, a link to a
    versioned folder; the new folder is written, then `..data` is swapped by a rename."""
    version = folder / f"..{time.monotonic_ns()}"
    version.mkdir()
    for suffix in (".json", ".onnx"):
        shutil.copyfile(source.with_suffix(suffix), version / f"{DEFAULT}{suffix}")
    data = folder / "..data"
    if not data.is_symlink():  # first use: turn the plain files into links
        tmp = folder / "..data_tmp"
        tmp.symlink_to(version.name)
        os.replace(tmp, data)
        for suffix in (".json", ".onnx"):
            link = folder / f".{DEFAULT}{suffix}.link"
            link.symlink_to(f"..data/{DEFAULT}{suffix}")
            os.replace(link, folder / f"{DEFAULT}{suffix}")
        return
    tmp = folder / "..data_tmp"
    tmp.symlink_to(version.name)
    os.replace(tmp, data)


@pytest.mark.parametrize(
    "deploy",
    [_rm_then_cp, _atomic_rename, _symlink_swap],
    ids=["rm-then-cp", "atomic-rename", "symlink-swap"],
)
def test_a_redeploy_under_load_fails_no_request(
    watched: str, folder: Path, deploy: Callable[[Path, Path], None]
) -> None:
    """The default model replaced under load (2 workers, folder watched): 0 failed requests,
    the old model answering until the new one is loaded, then the new one everywhere."""
    for model in (SMALL, REPLACEMENT):  # what tells the two networks' answers apart
        served_answer(model)
    current = httpx.post(watched + "/v1/predict", content=PHOTO, headers=JPEG, timeout=60)
    old_name = network_of(current.json(), (SMALL, REPLACEMENT))
    back = old_name != CARD["name"]
    source, new_name = (SMALL, CARD["name"]) if back else (REPLACEMENT, NEW_NAME)
    with Load(watched, threads=4) as load:
        _wait_for(lambda: load.count >= 10, 60)
        deploy(folder, source)
        _wait_for(lambda: load.answers[new_name] >= 10, 60)
    assert load.failures == [], load.failures[:5]
    assert load.answers[old_name] > 0
    _wait_for(lambda: _every_worker_answers(watched, new_name), 30)
