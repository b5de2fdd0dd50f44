"""Worker processes: `planar-pose-serve --workers 2` on one port, ready only when every
worker has its models, Prometheus counts added up across workers, a model replaced and
reloaded while a load test runs (0 failed requests), and SIGTERM draining a request."""

from __future__ import annotations

import threading
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import httpx
import psutil
import pytest
from server_process import live_server
from service_support import JPEG, PHOTO, SERVE, AppFactory, card_of, network_of, served_answer
from test_service_models import DEFAULT, LARGE, REPLACEMENT, SMALL, put

NEW_NAME = card_of(REPLACEMENT)["name"]


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("models")
    put(path, DEFAULT, SMALL)
    put(path, "board-large", LARGE)
    return path


@pytest.fixture(scope="module")
def server(
    folder: Path, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[tuple[str, psutil.Process]]:
    """(base URL, supervisor process) of `planar-pose-serve --workers 2`."""
    log = tmp_path_factory.mktemp("workers") / "serve.log"
    command = [*SERVE, "--workers", "2", "--model-dir", str(folder)]
    with live_server(command, log, {"POSE_ACCESS_LOG": "false"}) as (base, proc):
        assert len(worker_processes(psutil.Process(proc.pid))) == 2
        yield base, psutil.Process(proc.pid)
    assert "Traceback" not in log.read_text(), log.read_text()


@pytest.fixture(scope="module")
def workers(server: tuple[str, psutil.Process]) -> str:
    return server[0]


def worker_processes(supervisor: psutil.Process) -> list[psutil.Process]:
    """The live worker processes of a supervisor (not a killed one not yet reaped)."""
    out = []
    for child in supervisor.children():
        try:
            if "spawn_main" in " ".join(child.cmdline()):
                out.append(child)
        except psutil.Error:  # gone, or a zombie
            continue
    return out


def request_count(base: str, route: str) -> float:
    text = httpx.get(base + "/metrics").text
    prefix = f'pose_http_requests_total{{method="POST",route="{route}",status="200"}} '
    return next((float(ln[len(prefix) :]) for ln in text.splitlines() if ln.startswith(prefix)), 0)


def test_metrics_add_up_across_workers(workers: str) -> None:
    before = request_count(workers, "/v1/predict")
    with httpx.Client(base_url=workers, timeout=60) as c:
        for _ in range(12):  # new connections: the kernel spreads them over both workers
            assert c.post("/v1/predict", content=PHOTO, headers=JPEG).status_code == 200
            c.close()
            c = httpx.Client(base_url=workers, timeout=60)
    assert request_count(workers, "/v1/predict") == before + 12
    text = httpx.get(workers + "/metrics").text
    assert 'pose_inference_seconds_bucket{le="+Inf",mode="whole"}' in text


def _load(base: str, stop: threading.Event, answers: Counter[str], errors: list[str]) -> None:
    with httpx.Client(base_url=base, timeout=60) as c:
        while not stop.is_set():
            try:
                r = c.post("/v1/predict", content=PHOTO, headers=JPEG)
            except httpx.HTTPError as exc:
                errors.append(repr(exc))
                continue
            if r.status_code == 200:
                answers[network_of(r.json(), (SMALL, REPLACEMENT))] += 1
            else:
                errors.append(f"{r.status_code} {r.text[:200]}")


def test_model_replaced_during_a_load_test_fails_no_request(workers: str, folder: Path) -> None:
    for model in (SMALL, REPLACEMENT):  # what tells the two networks' answers apart
        served_answer(model)
    stop, answers, errors = threading.Event(), Counter[str](), list[str]()
    threads = [
        threading.Thread(target=_load, args=(workers, stop, answers, errors)) for _ in range(4)
    ]
    for t in threads:
        t.start()
    try:
        time.sleep(1.0)
        put(folder, DEFAULT, REPLACEMENT)
        report = httpx.post(workers + "/v1/models/reload", timeout=60).json()
        assert report["loaded"] == [DEFAULT], report
        time.sleep(1.5)  # the other worker follows within its sync interval
        answers_at_swap = sum(answers.values())
        time.sleep(1.0)
    finally:
        stop.set()
        for t in threads:
            t.join()
    assert errors == [], errors[:5]
    assert answers[DEFAULT] > 0 and answers[NEW_NAME] > 0, answers
    assert sum(answers.values()) > answers_at_swap
    # every worker now answers with the new model (the other one within its sync interval
    # plus a model load, seconds on a loaded machine)
    deadline, seen = time.monotonic() + 30, set()
    while seen != {NEW_NAME} and time.monotonic() < deadline:
        seen = set()
        for _ in range(10):
            with httpx.Client(base_url=workers, timeout=60) as c:
                answer = c.post("/v1/predict", content=PHOTO, headers=JPEG).json()
            seen.add(network_of(answer, (SMALL, REPLACEMENT)))
    assert seen == {NEW_NAME}
    put(folder, DEFAULT, SMALL)  # leave the folder as the module found it


def test_ready_only_when_every_worker_has_its_models(
    app_factory: AppFactory, tmp_path: Path
) -> None:
    runtime = tmp_path / "runtime"
    with app_factory(ready="/healthz", workers=2, runtime_dir=runtime) as c:
        deadline = time.monotonic() + 60  # a loaded machine takes seconds to load a model
        while not ((runtime / "ready").is_dir() and any((runtime / "ready").iterdir())):
            assert time.monotonic() < deadline, "no worker became ready within 60 s"
            time.sleep(0.01)
        r = c.get("/readyz")
        assert r.status_code == 503 and "1 of 2 workers" in r.json()["error"]["message"]
        dead = psutil.Popen(["true"])
        dead.wait()
        (runtime / "ready" / str(dead.pid)).touch()  # a worker that died is not counted
        assert c.get("/readyz").status_code == 503
        assert c.get("/v2/health/ready").status_code == 503
        (runtime / "ready" / str(psutil.Process().ppid())).touch()  # a live second worker
        assert c.get("/readyz").json()["status"] == "ready"
        assert c.get("/v2/health/ready").json() == {"ready": True}


def test_a_killed_worker_is_replaced_without_a_503(server: tuple[str, psutil.Process]) -> None:
    """SIGKILL of one of 2 workers under load: uvicorn starts another, which accepts from
    the shared socket only once its default model is loaded (the app's lifespan), so no
    request is answered 503; only requests in flight on the dead worker fail."""
    base, supervisor = server
    stop, answers, errors = threading.Event(), Counter[str](), list[str]()
    clients = [threading.Thread(target=_load, args=(base, stop, answers, errors)) for _ in range(4)]
    for t in clients:
        t.start()
    try:
        time.sleep(0.5)
        victim = worker_processes(supervisor)[0]
        victim.kill()
        deadline = time.monotonic() + 60
        while not (
            victim.pid not in {w.pid for w in worker_processes(supervisor)}
            and len(worker_processes(supervisor)) == 2
            and httpx.get(base + "/readyz", timeout=10).status_code == 200
        ):
            assert time.monotonic() < deadline, "no replacement worker ready within 60 s"
            time.sleep(0.05)
        served_before = sum(answers.values())
        time.sleep(1.0)  # the replacement takes its share
    finally:
        stop.set()
        for t in clients:
            t.join()
    assert not [e for e in errors if e.startswith("503")], errors
    assert len(errors) <= 4, errors  # at most one request in flight per client
    assert sum(answers.values()) > served_before
