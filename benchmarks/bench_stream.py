"""Frames per second through the live stream (WS /v1/stream) vs the same frames through
POST /v1/predict one request each, at 640x480, in whole and sliding mode.

One run starts `uvicorn service.app:app` on a free port (the shipped default model, access log
off) and sends 640x480 colour JPEGs (the real chessboard photos re-encoded as 3-channel JPEGs,
cycled) for `--seconds` per cell:

* requests c=1: one POST /v1/predict per frame, the next when the answer is in (keep-alive);
* requests c=2: the same from two connections at once;
* stream w=1: one socket, each frame sent when the previous answer is in;
* stream w=2: one socket, two frames in flight (what the SDK does by default).

Per cell: frames/s, p50/p99 latency (send to answer) and the server's CPU ms per frame. Prints
the table and the ratios stream/requests at equal frames in flight, then the target (stream w=1
at least the fps of requests c=1 at 640x480 whole, with a lower p99). The load generator shares
the CPUs with the server. `--write docs/benchmarks.md` puts the table in that file's "Live
stream" section (between its markers; the rest of the file is left alone).

    .venv/bin/python benchmarks/bench_stream.py [--seconds 4] [--write docs/benchmarks.md]
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import cv2
import httpx
import numpy as np
import psutil
from docs_section import write_section  # benchmarks/, the script's own folder
from websockets.sync.client import connect

ROOT = Path(__file__).resolve().parent.parent
REAL = ROOT / "train" / "assets" / "real" / "chessboard-stereo"
MODEL = ROOT / "models" / "chessboard-corners-160x120.onnx"
MODES = ("whole", "sliding")


@dataclass
class Cell:
    name: str
    frames: int
    seconds: float
    latencies_s: list[float]
    cpu_s: float

    @property
    def fps(self) -> float:
        return self.frames / self.seconds

    def p(self, q: float) -> float:
        return float(np.percentile(self.latencies_s, q)) * 1e3

    @property
    def cpu_ms(self) -> float:
        return self.cpu_s * 1e3 / max(1, self.frames)


def frames_640x480() -> list[bytes]:
    """The real photos (640x480 grey) as 3-channel JPEGs, as a colour camera sends them."""
    out = []
    for path in sorted(REAL.glob("*.jpg")):
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
        assert bgr.shape[:2] == (480, 640), path
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, 90])
        assert ok
        out.append(buf.tobytes())
    return out


def start_server() -> tuple[subprocess.Popen[bytes], str]:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    env = {k: v for k, v in os.environ.items() if not k.startswith("POSE_")}
    env |= {"POSE_MODEL_PATH": str(MODEL), "POSE_ACCESS_LOG": "false"}
    command = [sys.executable, "-m", "uvicorn", "service.app:app", "--port", str(port)]
    proc = subprocess.Popen(
        [*command, "--log-level", "warning", "--no-access-log"],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline:
        try:
            if httpx.get(url + "/readyz", timeout=2).status_code == 200:
                return proc, url
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    proc.kill()
    raise SystemExit("the server did not become ready in 90 s")


def requests_loop(url: str, mode: str, frames: list[bytes], stop_at: float) -> list[float]:
    """POST one frame per request until `stop_at`; the latencies."""
    latencies = []
    with httpx.Client(base_url=url, timeout=30) as http:
        i = 0
        while time.perf_counter() < stop_at:
            t0 = time.perf_counter()
            answer = http.post(
                f"/v1/predict?mode={mode}",
                content=frames[i % len(frames)],
                headers={"content-type": "image/jpeg"},
            )
            answer.raise_for_status()
            latencies.append(time.perf_counter() - t0)
            i += 1
    return latencies


def stream_loop(
    url: str, mode: str, frames: list[bytes], stop_at: float, window: int
) -> list[float]:
    """Send frames on one socket with `window` in flight until `stop_at`; the latencies."""
    ws_url = "ws" + url.removeprefix("http") + f"/v1/stream?mode={mode}"
    sent: dict[int, float] = {}
    latencies: list[float] = []
    credit = threading.Semaphore(window)
    done = threading.Event()
    with connect(ws_url, compression=None) as ws:
        assert json.loads(ws.recv(timeout=30))["event"] == "ready"

        def send() -> None:
            seq = 0
            while time.perf_counter() < stop_at:
                credit.acquire()
                sent[seq] = time.perf_counter()
                ws.send(frames[seq % len(frames)])
                seq += 1
            done.set()

        sender = threading.Thread(target=send, daemon=True)
        sender.start()
        while not (done.is_set() and len(latencies) == len(sent)):
            try:
                answer = json.loads(ws.recv(timeout=0.05))
            except TimeoutError:
                continue
            assert "error" not in answer and answer["dropped"] == 0, answer
            latencies.append(time.perf_counter() - sent[answer["seq"]])
            credit.release()
        sender.join()
    return latencies


def measure(
    name: str, pid: int, seconds: float, loops: list[Callable[[float], list[float]]]
) -> Cell:
    """Run `loops` side by side for `seconds` (after a short warm-up)."""
    for loop in loops:
        loop(time.perf_counter() + 0.3)
    server = psutil.Process(pid)
    cpu0 = sum(server.cpu_times()[:2])
    start = time.perf_counter()
    with ThreadPoolExecutor(len(loops)) as pool:
        results = list(pool.map(lambda loop: loop(start + seconds), loops))
    elapsed = time.perf_counter() - start
    cpu = sum(server.cpu_times()[:2]) - cpu0
    latencies = [x for r in results for x in r]
    return Cell(name, len(latencies), elapsed, latencies, cpu)


def run_mode(
    url: str, pid: int, mode: str, frames: list[bytes], seconds: float, rounds: int
) -> list[Cell]:
    """The 4 cells of `mode`, measured in `rounds` interleaved rounds of seconds/rounds each
    (so that a change in the machine's load hits every cell alike), merged."""

    def req(stop: float) -> list[float]:
        return requests_loop(url, mode, frames, stop)

    def stream(window: int) -> Callable[[float], list[float]]:
        return lambda stop: stream_loop(url, mode, frames, stop, window)

    plans = {
        "requests c=1": [req],
        "requests c=2": [req, req],
        "stream w=1": [stream(1)],
        "stream w=2": [stream(2)],
    }
    merged = {name: Cell(name, 0, 0.0, [], 0.0) for name in plans}
    for _ in range(rounds):
        for name, loops in plans.items():
            cell = measure(name, pid, seconds / rounds, loops)
            m = merged[name]
            m.frames, m.seconds, m.cpu_s = (
                m.frames + cell.frames,
                m.seconds + cell.seconds,
                m.cpu_s + cell.cpu_s,
            )
            m.latencies_s += cell.latencies_s
    return list(merged.values())


def table(results: dict[str, list[Cell]]) -> list[str]:
    lines = [
        "| mode | how | frames/s | p50 ms | p99 ms | server CPU ms/frame |",
        "|---|---|---|---|---|---|",
    ]
    for mode, cells in results.items():
        for c in cells:
            lines.append(
                f"| {mode} | {c.name} | {c.fps:.1f} | {c.p(50):.2f} | {c.p(99):.2f} | "
                f"{c.cpu_ms:.2f} |"
            )
    return lines


def ratios(results: dict[str, list[Cell]]) -> list[str]:
    lines = []
    for mode, (r1, r2, s1, s2) in results.items():
        lines.append(
            f"{mode}: stream w=1 / requests c=1 = {s1.fps / r1.fps:.2f}x fps, "
            f"p99 {s1.p(99):.2f} vs {r1.p(99):.2f} ms; stream w=2 / requests c=2 = "
            f"{s2.fps / r2.fps:.2f}x fps, p99 {s2.p(99):.2f} vs {r2.p(99):.2f} ms"
        )
    r1, _, s1, _ = results["whole"]
    met = s1.fps >= r1.fps and s1.p(99) < r1.p(99)
    lines.append(
        f"target (stream >= requests fps at 640x480 whole, lower p99): {'met' if met else 'missed'}"
    )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=4.0, help="per cell")
    parser.add_argument("--rounds", type=int, default=4, help="interleaved rounds per mode")
    parser.add_argument("--write", type=Path, help="put the results in this markdown file")
    args = parser.parse_args()
    frames = frames_640x480()
    load0 = os.getloadavg()[0]
    when = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    machine = f"{platform.machine()}, {os.cpu_count()} CPUs, {platform.python_version()}"
    header = (
        f"`.venv/bin/python benchmarks/bench_stream.py --seconds {args.seconds:g} "
        f"--rounds {args.rounds}`, {when}, "
        f"{machine}, load average {load0:.2f} at start; {len(frames)} real 640x480 photos "
        "as colour JPEGs, cycled; client and server share the CPUs."
    )
    print(header)
    server, url = start_server()
    try:
        results = {
            mode: run_mode(url, server.pid, mode, frames, args.seconds, args.rounds)
            for mode in MODES
        }
    finally:
        server.terminate()
        server.wait(timeout=30)
    lines = table(results)
    notes = ratios(results)
    notes.append(
        "requests are sent with httpx (the SDK's HTTP library), frames with websockets (the "
        "SDK's stream library): frames/s and latency include each client's own CPU on the "
        "shared cores; the server CPU column is the server's cost per frame alone"
    )
    notes.append(f"load average {os.getloadavg()[0]:.2f} at end")
    print("\n".join(lines), "", *notes, sep="\n")
    if args.write:
        write_section(
            args.write,
            "bench_stream",
            "Live stream",
            [header, "", *lines, "", *(f"* {n}" for n in notes)],
        )
        print(f"wrote the live stream section of {args.write}")


if __name__ == "__main__":
    main()
