"""HTTP service throughput and latency vs the same work in-process, whole vs sliding mode.

One run starts `planar-pose serve` on a free port (access log off) and, for a 640x480 JPEG
(train/assets/real/chessboard-stereo/left01.jpg re-encoded as a 3-channel JPEG, so decoding
costs what a colour photo costs), at concurrency 1, 8 and 32, in whole and sliding mode:

* HTTP: requests/s, p50/p99 latency, server CPU ms per request, from `wrk` (C, one thread,
  raw image body) or, without wrk, an httpx async client in a separate process;
* in-process: `service.predictor.Predictor.predict` on the same bytes from as many threads.

Prints the table, the ratios (HTTP overhead = in-process req/s / HTTP req/s; sliding cost =
whole req/s / sliding req/s) and the targets (>= 300 req/s whole at c=8 with p99 < 50 ms, HTTP
overhead <= 1.5x, sliding <= 5x whole). The load generator shares the CPUs with the server.

    .venv/bin/python benchmarks/bench_service.py [--seconds 5] [--loadgen wrk|httpx]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import cv2
import httpx
import numpy as np

from service.model import PoseModel
from service.predictor import Predictor
from service.settings import Settings

ROOT = Path(__file__).resolve().parent.parent
PHOTO = ROOT / "train" / "assets" / "real" / "chessboard-stereo" / "left01.jpg"
CONCURRENCY = (1, 8, 32)
MODES = ("whole", "sliding")

WRK_SCRIPT = """
local f = assert(io.open(os.getenv("BENCH_BODY"), "rb"))
wrk.method, wrk.body = "POST", f:read("*a")
f:close()
wrk.headers["Content-Type"] = "image/jpeg"
done = function(s, latency, _)
  local e = s.errors
  io.write(string.format('RESULT {"requests": %d, "seconds": %f, "errors": %d, "p50": %f, '
    .. '"p99": %f}\\n', s.requests, s.duration / 1e6,
    e.connect + e.read + e.write + e.status + e.timeout,
    latency:percentile(50) / 1e3, latency:percentile(99) / 1e3))
end
"""


@dataclass
class Run:
    rps: float
    p50_ms: float
    p99_ms: float
    errors: int = 0
    cpu_ms: float = float("nan")  # server CPU per request


def photo_jpeg() -> bytes:
    image = cv2.imread(str(PHOTO), cv2.IMREAD_COLOR)
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90])
    assert ok and image.shape[:2] == (480, 640)
    return buf.tobytes()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def wrk_run(url: str, body: Path, concurrency: int, seconds: float) -> Run:
    with tempfile.NamedTemporaryFile("w", suffix=".lua", delete=False) as script:
        script.write(WRK_SCRIPT)
    out = subprocess.run(
        [
            "wrk",
            "-t1",
            f"-c{concurrency}",
            f"-d{max(1, round(seconds))}s",
            "--timeout",
            "10s",
            "-s",
            script.name,
            url,
        ],
        capture_output=True,
        text=True,
        env={**os.environ, "BENCH_BODY": str(body)},
        check=True,
    ).stdout
    os.unlink(script.name)
    line = next(x for x in out.splitlines() if x.startswith("RESULT "))
    r = json.loads(line[len("RESULT ") :])
    return Run(r["requests"] / r["seconds"], r["p50"], r["p99"], r["errors"])


def _httpx_worker(
    url: str, body: bytes, concurrency: int, seconds: float, out: multiprocessing.Queue
) -> None:
    async def main() -> tuple[list[float], int]:
        latencies: list[float] = []
        errors = 0
        limits = httpx.Limits(max_connections=concurrency)
        async with httpx.AsyncClient(limits=limits, timeout=30) as client:
            deadline = time.perf_counter() + seconds

            async def loop() -> None:
                nonlocal errors
                while time.perf_counter() < deadline:
                    t0 = time.perf_counter()
                    r = await client.post(url, content=body, headers={"content-type": "image/jpeg"})
                    latencies.append(time.perf_counter() - t0)
                    errors += r.status_code != 200

            await asyncio.gather(*(loop() for _ in range(concurrency)))
        return latencies, errors

    out.put(asyncio.run(main()))


def httpx_run(url: str, body: Path, concurrency: int, seconds: float) -> Run:
    queue: multiprocessing.Queue = multiprocessing.Queue()
    t0 = time.perf_counter()
    proc = multiprocessing.Process(
        target=_httpx_worker, args=(url, body.read_bytes(), concurrency, seconds, queue)
    )
    proc.start()
    latencies, errors = queue.get()
    proc.join()
    wall = time.perf_counter() - t0
    ms = np.array(latencies) * 1e3
    return Run(len(ms) / wall, *np.percentile(ms, [50, 99]).tolist(), errors)


def in_process(
    predictor: Predictor, data: bytes, mode: str, concurrency: int, seconds: float
) -> Run:
    deadline = time.perf_counter() + seconds

    def loop() -> list[float]:
        out = []
        while time.perf_counter() < deadline:
            t0 = time.perf_counter()
            predictor.predict([(None, data)], mode)  # type: ignore[arg-type]
            out.append(time.perf_counter() - t0)
        return out

    t0 = time.perf_counter()
    with ThreadPoolExecutor(concurrency) as pool:
        latencies = [x for part in pool.map(lambda _: loop(), range(concurrency)) for x in part]
    wall = time.perf_counter() - t0
    ms = np.array(latencies) * 1e3
    return Run(len(ms) / wall, *np.percentile(ms, [50, 99]).tolist())


def start_server(port: int) -> subprocess.Popen[bytes]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("POSE_")}
    env["POSE_ACCESS_LOG"] = "false"
    exe = str(Path(sys.executable).with_name("planar-pose"))
    proc = subprocess.Popen([exe, "serve", "--port", str(port)], env=env, cwd=ROOT)
    for _ in range(300):
        try:
            if httpx.get(f"http://127.0.0.1:{port}/readyz", timeout=1).status_code == 200:
                return proc
        except httpx.TransportError:
            time.sleep(0.1)
    proc.kill()
    raise SystemExit("the server did not become ready")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="per measurement")
    parser.add_argument(
        "--loadgen", choices=("wrk", "httpx"), default="wrk" if shutil.which("wrk") else "httpx"
    )
    args = parser.parse_args()

    data = photo_jpeg()
    body = Path(tempfile.mkdtemp()) / "photo.jpg"
    body.write_bytes(data)
    settings = Settings()
    predictor = Predictor(PoseModel.load(settings.resolved_model_path), settings)
    generate = wrk_run if args.loadgen == "wrk" else httpx_run
    print(
        f"640x480 JPEG, {len(data)} bytes; load generator: {args.loadgen}; "
        f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f} at start"
    )

    port = free_port()
    server = start_server(port)
    http: dict[tuple[str, int], Run] = {}
    local: dict[tuple[str, int], Run] = {}
    try:
        for mode in MODES:
            url = f"http://127.0.0.1:{port}/v1/predict?mode={mode}"
            generate(url, body, 8, 1.0)  # warm up
            for c in CONCURRENCY:
                cpu0 = cpu_seconds(server.pid)
                run = generate(url, body, c, args.seconds)
                run.cpu_ms = (cpu_seconds(server.pid) - cpu0) * 1e3 / max(1, run.rps * args.seconds)
                http[mode, c] = run
                local[mode, c] = in_process(predictor, data, mode, c, args.seconds)
    finally:
        server.send_signal(signal.SIGTERM)
        server.wait(timeout=30)

    print(
        f"\n{'mode':8}{'c':>4} | {'HTTP req/s':>10}{'p50 ms':>8}{'p99 ms':>8}{'errors':>7}"
        f"{'srv CPU ms/req':>15} | {'in-proc req/s':>13}{'p50 ms':>8}{'p99 ms':>8} | overhead"
    )
    for (mode, c), h in http.items():
        p = local[mode, c]
        print(
            f"{mode:8}{c:>4} | {h.rps:>10.1f}{h.p50_ms:>8.2f}{h.p99_ms:>8.2f}{h.errors:>7}"
            f"{h.cpu_ms:>15.2f} | {p.rps:>13.1f}{p.p50_ms:>8.2f}{p.p99_ms:>8.2f} | "
            f"{p.rps / h.rps:>6.2f}x"
        )
    print("\nsliding vs whole cost (whole req/s / sliding req/s):")
    for c in CONCURRENCY:
        print(
            f"  c={c:<3} HTTP {http['whole', c].rps / http['sliding', c].rps:5.2f}x   "
            f"in-process {local['whole', c].rps / local['sliding', c].rps:5.2f}x"
        )
    w8 = http["whole", 8]
    overhead = max(local[k].rps / http[k].rps for k in http)
    sliding = http["whole", 1].rps / http["sliding", 1].rps
    print("\ntargets:")
    print(
        f"  whole c=8: {w8.rps:.0f} req/s (>= 300) and p99 {w8.p99_ms:.1f} ms (< 50): "
        f"{'met' if w8.rps >= 300 and w8.p99_ms < 50 else 'MISSED'}"
    )
    print(
        f"  HTTP overhead, worst cell: {overhead:.2f}x (<= 1.5): "
        f"{'met' if overhead <= 1.5 else 'MISSED'}"
    )
    print(
        f"  sliding vs whole, HTTP c=1: {sliding:.2f}x (<= 5): "
        f"{'met' if sliding <= 5 else 'MISSED'}"
    )
    print(f"load average {os.getloadavg()[0]:.2f} at end (the machine is shared)")


if __name__ == "__main__":
    main()
