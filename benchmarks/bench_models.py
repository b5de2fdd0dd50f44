"""Many models per server, and workers that take traffic only once ready (issue 52), in one
run: `python -m service.cli --workers 2` (this checkout's code) on a small and a large model
folder, then a worker SIGKILLed under load.

1. Start, compared: the shipped folder (models/, 6 models) against a folder of `--models`
   corner models (copies of models/*corners*.onnx and their cards under other names, the
   default model among them, in a temp folder): seconds until /readyz answers 200, resident
   MB of each worker.
2. Use (the large folder): `--used` different models, each asked once and its answer timed
   (a cold model: its graph loads in the worker that takes the request), then 5 times more
   on new connections (so both workers load it): the first answers' median and slowest, each
   worker's resident MB after, and from /metrics the loads, cache hits, misses, evictions,
   models loaded and their estimated bytes (POSE_MODEL_MEMORY_MB, `--memory-mb`). The first
   models right after ready, while the background writes their optimized graphs (a graph
   not optimized yet is loaded unoptimized and optimized in a thread meanwhile), then
   `--used` others, later (the copies share the 4 shipped graphs' optimized ones).
3. SIGKILL (the shipped folder): `--clients` keep-alive clients post the board photo to
   /v1/predict for `--seconds`; 5 s in, one worker is SIGKILLed and uvicorn's supervisor
   starts another: answers by status, 503 answers, failed requests (connection errors:
   those in flight on the dead worker), and when /readyz says every worker is back.

Targets (the issue's): ready <= 15 s with 200 models, <= 1 GB per worker after 20 models,
a cold model's first answer <= 1 s, 0 answers 503 and <= 8 failed requests around the kill.

    .venv/bin/python benchmarks/bench_models.py [--models 200] [--used 20] [--seconds 20]
        [--clients 8] [--memory-mb MB] [--write-docs]
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import httpx
import psutil
from docs_section import write_section  # benchmarks/, the script's own folder

from service.pipeline.model import PoseModel

ROOT = Path(__file__).resolve().parent.parent
MODELS = ROOT / "models"
PHOTO = (ROOT / "train" / "assets" / "real" / "chessboard-stereo" / "left01.jpg").read_bytes()
JPEG = {"Content-Type": "image/jpeg"}
DEFAULT = "chessboard-corners-160x120"
DOCS = ROOT / "docs" / "benchmarks.md"
LOG_LEVEL = os.environ.get("BENCH_LOG_LEVEL", "warning")  # of the servers (info: each load)
TARGET_READY_S, TARGET_RSS_MB, TARGET_COLD_S, TARGET_FAILED = 15.0, 1000.0, 1.0, 8


#: The lines printed, for `--write-docs`.
LINES: list[str] = []


def say(*parts: object, sep: str = " ") -> None:
    """Print a line as it comes, and keep it."""
    text = sep.join(str(p) for p in parts)
    LINES.extend(text.splitlines())
    print(text, flush=True)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def copies(folder: Path, count: int) -> None:
    """`count` corner models in `folder`: the default under its name, the others copies of
    the shipped corner models (with their cards) named obj-NNN-<source>."""
    sources = sorted(MODELS.glob("*corners*.onnx"))
    for suffix in (".onnx", ".json"):
        shutil.copyfile((MODELS / DEFAULT).with_suffix(suffix), folder / f"{DEFAULT}{suffix}")
    for i in range(count - 1):
        source = sources[i % len(sources)]
        for suffix in (".onnx", ".json"):
            name = f"obj-{i:03d}-{source.stem}{suffix}"
            shutil.copyfile(source.with_suffix(suffix), folder / name)


@dataclass
class Server:
    proc: subprocess.Popen[bytes]
    base: str
    ready_s: float

    def workers(self) -> list[psutil.Process]:
        """The live worker processes (not a killed one the supervisor has not reaped yet)."""
        out = []
        for child in psutil.Process(self.proc.pid).children():
            try:
                if "spawn_main" in " ".join(child.cmdline()):
                    out.append(child)
            except psutil.Error:  # gone, or a zombie
                continue
        return out

    def rss_mb(self) -> list[float]:
        """Resident MB of each worker process."""
        out = []
        for worker in self.workers():
            try:
                out.append(worker.memory_info().rss / 2**20)
            except psutil.NoSuchProcess:
                continue
        return sorted(out)

    def cpu_s(self) -> float:
        """CPU seconds the worker processes have used."""
        total = 0.0
        for worker in self.workers():
            try:
                times = worker.cpu_times()
            except psutil.Error:
                continue
            total += times.user + times.system
        return total

    def metric(self, name: str) -> float:
        """The sum of a series of /metrics over its labels and the workers."""
        text = httpx.get(self.base + "/metrics", timeout=10).text
        values = [
            float(line.rsplit(" ", 1)[1])
            for line in text.splitlines()
            if line.startswith(name + " ") or line.startswith(name + "{")
        ]
        return sum(values)


@contextmanager
def serve(folder: Path, memory_mb: float | None, log: Path, workers: int = 2) -> Iterator[Server]:
    """`python -m service.cli --workers N` on `folder`, timed until /readyz answers 200."""
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("POSE_")}
    env.update(PYTHONPATH=str(ROOT), POSE_ACCESS_LOG="false")
    if memory_mb is not None:
        env["POSE_MODEL_MEMORY_MB"] = str(memory_mb)
    command = [sys.executable, "-m", "service.cli", "--port", str(port), "--workers", str(workers)]
    command += ["--model-dir", str(folder), "--log-level", LOG_LEVEL]
    start = time.perf_counter()
    with log.open("ab") as sink:
        proc = subprocess.Popen(command, env=env, cwd=ROOT, stdout=sink, stderr=sink)
    base = f"http://127.0.0.1:{port}"
    try:
        while True:
            if proc.poll() is not None or time.perf_counter() - start > 300:
                raise SystemExit(f"error: the server did not become ready; see {log}")
            try:
                if httpx.get(base + "/readyz", timeout=2).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            time.sleep(0.05)
        yield Server(proc, base, time.perf_counter() - start)
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()


def use_models(server: Server, names: list[str]) -> tuple[list[float], list[float], list[str]]:
    """Ask each model once (timed: cold) then 5 times on new connections; the first answers'
    seconds and the workers' CPU seconds for them, and what went wrong."""
    firsts, cpu, problems = [], [], []
    for name in names:
        for attempt in range(6):
            start, used = time.perf_counter(), server.cpu_s()
            with httpx.Client(base_url=server.base, timeout=60) as client:
                r = client.post(f"/v1/models/{name}/predict", content=PHOTO, headers=JPEG)
            if attempt == 0:
                firsts.append(time.perf_counter() - start)
                cpu.append(server.cpu_s() - used)
            if r.status_code != 200:
                problems.append(f"{name}: {r.status_code} {r.text[:120]}")
    return firsts, cpu, problems


@dataclass
class Load:
    statuses: Counter[int] = field(default_factory=Counter)
    failed: list[str] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)


def client_loop(base: str, stop: threading.Event, load: Load) -> None:
    """One client on keep-alive connections, posting the photo until `stop`."""
    with httpx.Client(base_url=base, timeout=60) as client:
        while not stop.is_set():
            try:
                r = client.post("/v1/predict", content=PHOTO, headers=JPEG)
            except httpx.HTTPError as exc:
                with load.lock:
                    load.failed.append(type(exc).__name__)
                continue
            with load.lock:
                load.statuses[r.status_code] += 1


def kill_under_load(server: Server, clients: int, seconds: float) -> tuple[Load, float, float]:
    """Load for `seconds`, one worker SIGKILLed 5 s in: the load, when the replacement
    worker's process appeared and when /readyz answered 200 again (s after the kill)."""
    stop, load = threading.Event(), Load()
    threads = [
        threading.Thread(target=client_loop, args=(server.base, stop, load)) for _ in range(clients)
    ]
    for t in threads:
        t.start()
    try:
        time.sleep(5.0)
        victim = server.workers()[0]
        victim.send_signal(signal.SIGKILL)
        killed = time.perf_counter()
        spawned = ready = float("nan")
        while time.perf_counter() - killed < seconds - 5.0:
            pids = {w.pid for w in server.workers()}
            if math.isnan(spawned) and len(pids) == 2 and victim.pid not in pids:
                spawned = time.perf_counter() - killed
            if (
                not math.isnan(spawned)
                and math.isnan(ready)
                and httpx.get(server.base + "/readyz", timeout=5).status_code == 200
            ):
                ready = time.perf_counter() - killed
            time.sleep(0.05)
    finally:
        stop.set()
        for t in threads:
            t.join()
    while math.isnan(ready) and time.perf_counter() - killed < 120:
        if httpx.get(server.base + "/readyz", timeout=5).status_code == 200:
            ready = time.perf_counter() - killed
        time.sleep(0.1)
    return load, spawned, ready


def load_cpu_lines() -> list[str]:
    """CPU seconds to load each shipped corner graph from its ONNX file and from its
    optimized graph (what `service.pipeline.model.open_session` caches), in this process."""
    lines = []
    with tempfile.TemporaryDirectory(prefix="bench-models-ort-") as tmp:
        for path in sorted(MODELS.glob("*corners*.onnx")):
            target = Path(tmp) / f"{path.stem}.ort"
            start = time.process_time()
            PoseModel.load(path, optimized=target)  # from the ONNX file, writes the cache
            onnx_s = time.process_time() - start
            start = time.process_time()
            PoseModel.load(path, optimized=target)
            lines.append(
                f"{path.stem}: {onnx_s:.2f} s from ONNX, "
                f"{time.process_time() - start:.2f} s from the optimized graph"
            )
    return lines


def cold_line(server: Server, names: list[str], when: str) -> None:
    """Use `names` (`use_models`) and print their first answers' times."""
    firsts, cpu, problems = use_models(server, names)
    slowest = names[firsts.index(max(firsts))]
    say(
        f"cold first answers of {len(names)} models {when}: "
        f"median {statistics.median(firsts):.2f} s, slowest {max(firsts):.2f} s ({slowest}); "
        f"workers' CPU per first answer: median {statistics.median(cpu):.2f} s, most "
        f"{max(cpu):.2f} s; target <= {TARGET_COLD_S:g} s: {verdict(max(firsts) <= TARGET_COLD_S)}"
        f"; non-200 answers: {len(problems)} " + "; ".join(problems[:3])
    )


def verdict(ok: bool) -> str:
    return "ok" if ok else "MISSED"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", type=int, default=200, help="corner models in the folder")
    parser.add_argument("--used", type=int, default=20, help="different models used")
    parser.add_argument("--seconds", type=float, default=20.0, help="load around the kill")
    parser.add_argument("--clients", type=int, default=8, help="concurrent clients")
    parser.add_argument("--memory-mb", type=float, help="POSE_MODEL_MEMORY_MB (default: its)")
    parser.add_argument("--write-docs", action="store_true", help="update docs/benchmarks.md")
    args = parser.parse_args()
    say(
        f"machine: {platform.machine()}, {os.cpu_count()} CPUs, 2 workers, load "
        f"average {os.getloadavg()[0]:.1f} at the start"
    )
    say("CPU to load a graph (this process):", *load_cpu_lines(), sep="\n  ")
    log = Path(tempfile.mkdtemp(prefix="bench-models-")) / "serve.log"
    with tempfile.TemporaryDirectory(prefix="bench-models-") as tmp:
        folder = Path(tmp)
        copies(folder, args.models)
        with serve(MODELS, args.memory_mb, log) as small:
            small_rss = small.rss_mb()
        with serve(folder, args.memory_mb, log) as large:
            large_rss = large.rss_mb()
            say(
                f"ready: {len(list(MODELS.glob('*.onnx')))} models {small.ready_s:.1f} s "
                f"(workers {small_rss[0]:.0f}/{small_rss[-1]:.0f} MB), {args.models} models "
                f"{large.ready_s:.1f} s (workers {large_rss[0]:.0f}/{large_rss[-1]:.0f} MB); "
                f"target <= {TARGET_READY_S:g} s: {verdict(large.ready_s <= TARGET_READY_S)}"
            )
            every = sorted(p.stem for p in folder.glob("obj-*.onnx"))
            names = every[: args.used]
            cold_line(large, names, "right after ready (graphs optimized meanwhile, if at all)")
            rss = large.rss_mb()
            cold_line(large, every[-args.used :], "later (their optimized graphs written)")
            say(
                f"after {len(names)} models used: workers {rss[0]:.0f}/{rss[-1]:.0f} MB; "
                f"target <= {TARGET_RSS_MB:g} MB: {verdict(rss[-1] <= TARGET_RSS_MB)}"
            )
            say(
                "metrics (both workers): "
                f"loads {large.metric('pose_model_loads_total'):.0f}, "
                f"hits {large.metric('pose_model_cache_hits_total'):.0f}, "
                f"misses {large.metric('pose_model_cache_misses_total'):.0f}, "
                f"evictions {large.metric('pose_model_cache_evictions_total'):.0f}, "
                f"loaded {large.metric('pose_models_loaded'):.0f} models, "
                f"{large.metric('pose_model_loaded_bytes') / 2**20:.0f} MB estimated "
                f"(resident beyond the start: {sum(rss) - sum(large_rss):.0f} MB)"
            )
    with serve(MODELS, args.memory_mb, log) as server:
        load, spawned, ready = kill_under_load(server, args.clients, args.seconds)
    answered = sum(load.statuses.values())
    say(
        f"SIGKILL of a worker, {args.clients} clients for {args.seconds:g} s: {answered} answers "
        f"{dict(load.statuses)}, 503: {load.statuses[503]}, failed requests: {len(load.failed)} "
        f"{dict(Counter(load.failed))}; new worker process after {spawned:.1f} s, every "
        f"worker ready after {ready:.1f} s; target 0 x 503 and <= {TARGET_FAILED} failed: "
        f"{verdict(load.statuses[503] == 0 and len(load.failed) <= TARGET_FAILED)}"
    )
    say(f"load average at the end {os.getloadavg()[0]:.1f}")
    print(f"server log: {log}")
    if args.write_docs:
        when = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
        head = f"_Written by `benchmarks/bench_models.py --write-docs` on {when}._"
        items = [f"  * {ln.strip()}" if ln.startswith(" ") else f"* {ln}" for ln in LINES]
        write_section(DOCS, "bench_models", "Many models, a worker killed", [head, "", *items])


if __name__ == "__main__":
    main()
