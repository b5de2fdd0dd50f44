"""HTTP service throughput and latency: 1 worker process vs N workers vs the same work
in-process on all cores, in one run, with the ratios.

For a 640x480 JPEG (train/assets/real/chessboard-stereo/left01.jpg re-encoded as a 3-channel
JPEG, so decoding costs what a colour photo costs), in whole and sliding mode, at concurrency
1, 8 and 32:

* HTTP: `planar-pose-serve --workers 1` and `--workers N` (N = the CPUs, access log off);
  requests/s, p50/p99 latency and server CPU ms per request (the whole process tree), from
  `wrk` (C, one thread, raw image body) or, without wrk, an httpx client in another process;
* in-process: `service.pipeline.predictor.Predictor.predict` on the same bytes from c threads.

The three are measured back to back for each cell (both servers stay up), best of
`--repeat` rounds, so that the other work of a shared machine moves them alike.

Prints the table, the ratios (N workers / 1 worker; HTTP overhead = in-process req/s / HTTP
req/s) and the targets (whole mode, c=8: HTTP overhead with N workers <= 1.3x, p99 < 50 ms).
The load generator shares the CPUs with the server. `--write-docs` puts the result into
docs/benchmarks.md (section "Service"), with the date and the machine.

Then, in the same run, the service under stress (section "Service under stress"):

* a photo without the board (a 640x480 real photo of the corpus's negatives) against the
  board photo, through N workers at c=8 with the same load generator: requests/s, latency,
  server CPU ms per request and the ratio no board / board, with the zoom pass's default
  search (POSE_ZOOM_SEARCH_TILES=1) and with all 9 tiles (what it searched before; target
  <= 2x);
* the bomb: 16 black 7000x7000 PNGs in one multipart request (2.3 MB, 49 MP each): its
  answer and time, and the worker processes' RSS after a burst of them against before
  (target: 413 within 100 ms, or an answer within 2 s with RSS within 20 %); the same for
  the largest request the budget lets through, one such PNG;
* with `--recall SETS` (a folder of `planar-pose corpus sets SETS --size 2`): the accuracy
  the zoom pass buys on the real val and test sources, blur 0-3 (the evaluation path:
  `train.network.evaluate.network_batch`, then the graph with the pass off, searching 9
  tiles, searching the default's), and on the corpus photos as stored (blur 0) through
  `service.pipeline.predictor.Predictor`, whose tiles are cut from the upload (target: the gain
  within 1 point of the 9-tile search's).

    .venv/bin/python benchmarks/bench_service.py [--seconds 3] [--repeat 2] [--write-docs]
        [--recall SETS] [--stress-only]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing
import os
import platform
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import cv2
import httpx
import numpy as np
import psutil
from docs_section import write_section  # benchmarks/, the script's own folder

from service.pipeline.model import PoseModel
from service.pipeline.predictor import Predictor
from service.settings import Settings, cpu_count

ROOT = Path(__file__).resolve().parent.parent
PHOTO = ROOT / "train" / "assets" / "real" / "chessboard-stereo" / "left01.jpg"
DOCS = ROOT / "docs" / "benchmarks.md"
MARKERS = ("<!-- bench_service:start -->", "<!-- bench_service:end -->")
CONCURRENCY = (1, 8, 32)
MODES = ("whole", "sliding")
TARGET_OVERHEAD, TARGET_P99_MS = 1.3, 50.0
TARGET_NO_BOARD = 2.0  # a photo without the board, at most this many times a board photo
NEGATIVES = ROOT / "train" / "assets" / "real" / "corpus" / "negatives"
NO_BOARD = (
    NEGATIVES / "azure-samples__cognitive-services-sample-data-files" / "images" / "Colmar.jpg"
)
STRESS_KEY, STRESS_TITLE = "bench_service_stress", "Service under stress"

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


def tree_cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process and its children (the worker processes)."""
    total = 0.0
    root = psutil.Process(pid)
    for proc in [root, *root.children(recursive=True)]:
        try:
            t = proc.cpu_times()
            total += t.user + t.system
        except psutil.NoSuchProcess:
            continue
    return total


def wrk_run(url: str, body: Path, concurrency: int, seconds: float) -> Run:
    with tempfile.NamedTemporaryFile("w", suffix=".lua", delete=False) as script:
        script.write(WRK_SCRIPT)
    command = ["wrk", "-t1", f"-c{concurrency}", f"-d{max(1, round(seconds))}s"]
    out = subprocess.run(
        [*command, "--timeout", "10s", "-s", script.name, url],
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
    """The service's work without HTTP: `concurrency` threads calling the predictor."""
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


def start_server(port: int, workers: int, **settings: str) -> subprocess.Popen[bytes]:
    """`planar-pose-serve` with `workers` and POSE_* `settings`, once /readyz answers 200."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("POSE_")}
    env["POSE_ACCESS_LOG"] = "false"
    env.update({f"POSE_{k.upper()}": v for k, v in settings.items()})
    exe = str(Path(sys.executable).with_name("planar-pose-serve"))
    command = [exe, "--port", str(port), "--workers", str(workers), "--log-level", "warning"]
    proc = subprocess.Popen(command, env=env, cwd=ROOT)
    for _ in range(600):
        try:
            if httpx.get(f"http://127.0.0.1:{port}/readyz", timeout=1).status_code == 200:
                return proc
        except httpx.TransportError:
            pass
        time.sleep(0.1)
    proc.kill()
    raise SystemExit("error: the server did not become ready in 60 s")


Cells = dict[tuple[str, int], Run]


def http_cell(
    server: subprocess.Popen[bytes], url: str, body: Path, c: int, seconds: float, generate: object
) -> Run:
    """One load run against `url`, with the server tree's CPU time per request."""
    cpu0 = tree_cpu_seconds(server.pid)
    run: Run = generate(url, body, c, seconds)  # type: ignore[operator]
    run.cpu_ms = (tree_cpu_seconds(server.pid) - cpu0) * 1e3 / max(1, run.rps * seconds)
    return run


def best(runs: list[Run]) -> Run:
    """The run with the most requests/s (the least disturbed by other work)."""
    return max(runs, key=lambda r: r.rps)


def measure(
    workers: int, body: Path, data: bytes, predictor: Predictor, generate: object, args: object
) -> tuple[Cells, Cells, Cells]:
    """Every (mode, c) cell for 1 worker, N workers and in-process, measured back to back
    (so that the machine's load moves all three alike), best of `repeat` rounds."""
    seconds, repeat = args.seconds, args.repeat  # type: ignore[attr-defined]
    ports = free_port(), free_port()
    servers = start_server(ports[0], 1), start_server(ports[1], workers)
    one: Cells = {}
    many: Cells = {}
    local: Cells = {}
    try:
        for mode in MODES:
            urls = [f"http://127.0.0.1:{p}/v1/predict?mode={mode}" for p in ports]
            for url in urls:
                generate(url, body, 8, 1.0)  # type: ignore[operator]  # warm up
            for c in CONCURRENCY:
                rounds = [
                    (
                        http_cell(servers[0], urls[0], body, c, seconds, generate),
                        http_cell(servers[1], urls[1], body, c, seconds, generate),
                        in_process(predictor, data, mode, c, seconds),
                    )
                    for _ in range(repeat)
                ]
                picked = [best(list(runs)) for runs in zip(*rounds, strict=True)]
                one[mode, c], many[mode, c], local[mode, c] = picked
    finally:
        for server in servers:
            server.send_signal(signal.SIGTERM)
        for server in servers:
            server.wait(timeout=60)
    return one, many, local


def table(one: Cells, many: Cells, local: Cells, n: int) -> list[str]:
    """The result as Markdown table lines."""
    lines = [
        f"| mode | c | 1 worker req/s | p99 ms | {n} workers req/s | p50 ms | p99 ms | errors "
        f"| server CPU ms/req | in-process req/s | {n} w / 1 w | overhead {n} w | overhead 1 w |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for key, m in many.items():
        o, p = one[key], local[key]
        lines.append(
            f"| {key[0]} | {key[1]} | {o.rps:.1f} | {o.p99_ms:.1f} | {m.rps:.1f} | "
            f"{m.p50_ms:.1f} | {m.p99_ms:.1f} | {o.errors + m.errors} | {m.cpu_ms:.2f} | "
            f"{p.rps:.1f} | {m.rps / o.rps:.2f}x | {p.rps / m.rps:.2f}x | {p.rps / o.rps:.2f}x |"
        )
    return lines


def verdict(one: Cells, many: Cells, local: Cells, n: int) -> list[str]:
    """The targets, met or missed."""
    m8, o8, p8 = many["whole", 8], one["whole", 8], local["whole", 8]
    overhead = p8.rps / m8.rps
    ok = overhead <= TARGET_OVERHEAD and m8.p99_ms < TARGET_P99_MS
    return [
        f"- whole, c=8: {n} workers {m8.rps:.0f} req/s vs 1 worker {o8.rps:.0f} req/s "
        f"({m8.rps / o8.rps:.2f}x); in-process on all cores {p8.rps:.0f} req/s.",
        f"- target: HTTP overhead with {n} workers {overhead:.2f}x (<= {TARGET_OVERHEAD}x) and "
        f"p99 {m8.p99_ms:.1f} ms (< {TARGET_P99_MS:.0f} ms): {'met' if ok else 'MISSED'}.",
        f"- sliding vs whole, {n} workers, c=1: "
        f"{many['whole', 1].rps / many['sliding', 1].rps:.2f}x the cost.",
    ]


def no_board_jpeg() -> bytes:
    """A 640x480 photo without the board, re-encoded as photo_jpeg's."""
    image = cv2.imread(str(NO_BOARD), cv2.IMREAD_COLOR)
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90])
    assert ok and image.shape[:2] == (480, 640)
    return buf.tobytes()


def bomb_body(count: int) -> tuple[bytes, str]:
    """A multipart body of `count` black 7000x7000 PNGs and its content type."""
    png = cv2.imencode(".png", np.zeros((7000, 7000, 3), np.uint8))[1].tobytes()
    boundary = "bench-bomb"
    part = (
        f'--{boundary}\r\nContent-Disposition: form-data; name="image"; filename="b.png"\r\n'
        "Content-Type: image/png\r\n\r\n"
    ).encode()
    body = b"".join(part + png + b"\r\n" for _ in range(count)) + f"--{boundary}--\r\n".encode()
    return body, f"multipart/form-data; boundary={boundary}"


def workers_rss(server: subprocess.Popen[bytes]) -> float:
    """MB resident in the worker processes of a `planar-pose-serve --workers N`."""
    total = 0
    for proc in psutil.Process(server.pid).children():
        try:
            if "spawn_main" in " ".join(proc.cmdline()):
                total += proc.memory_info().rss
        except psutil.NoSuchProcess:
            continue
    return total / 1e6


def burst(
    url: str, body: bytes, media: str, requests: int, at_once: int
) -> list[tuple[int, float]]:
    """(status, seconds) of `requests` POSTs of `body`, `at_once` at a time."""

    def one(_: int) -> tuple[int, float]:
        t0 = time.perf_counter()
        r = httpx.post(url, content=body, headers={"content-type": media}, timeout=300)
        return r.status_code, time.perf_counter() - t0

    with ThreadPoolExecutor(at_once) as pool:
        return list(pool.map(one, range(requests)))


def bomb_lines(server: subprocess.Popen[bytes], url: str, body: Path) -> list[str]:
    """The bomb request (one after another, then 4 at once) and the largest one the budget
    lets through, against `server`: status, time, and the workers' RSS after a burst
    against before (warmed up)."""
    burst(url, body.read_bytes(), "image/jpeg", 40, 4)
    lines = []
    for count, requests, at_once in ((16, 10, 1), (16, 20, 4), (1, 8, 2)):
        payload, media = bomb_body(count)
        before = workers_rss(server)
        answers = burst(url, payload, media, requests, at_once)
        time.sleep(0.5)
        after = workers_rss(server)
        statuses = sorted({s for s, _ in answers})
        seconds = np.array([t for _, t in answers])
        lines.append(
            f"| {count} x 7000x7000 PNG ({len(payload) / 1e6:.1f} MB) | {requests}, "
            f"{'one after another' if at_once == 1 else f'{at_once} at once'} | "
            f"{', '.join(map(str, statuses))} | {1e3 * np.median(seconds):.0f} | "
            f"{1e3 * seconds.max():.0f} | {before:.0f} | {after:.0f} | {after / before:.2f}x |"
        )
    return lines


def stress(workers: int, body: Path, generate: object, args: object) -> list[str]:
    """The no-board photo against the board photo through `workers` workers at c=8, with the
    zoom pass's default search and with all 9 tiles, and the bomb requests (module doc)."""
    seconds, repeat = args.seconds, args.repeat  # type: ignore[attr-defined]
    no_board = body.with_name("no-board.jpg")
    no_board.write_bytes(no_board_jpeg())
    configs = {"default": {}, "9 tiles (before)": {"zoom_search_tiles": "9"}}
    ports = {name: free_port() for name in configs}
    servers = {name: start_server(ports[name], workers, **cfg) for name, cfg in configs.items()}
    cells: dict[tuple[str, str], Run] = {}
    try:
        photos = {"board": body, "no board": no_board}
        for name in configs:
            url = f"http://127.0.0.1:{ports[name]}/v1/predict"
            for photo in photos.values():
                generate(url, photo, 8, 1.0)  # type: ignore[operator]  # warm up
        rounds = [
            {
                (name, kind): http_cell(
                    servers[name],
                    f"http://127.0.0.1:{ports[name]}/v1/predict",
                    photo,
                    8,
                    seconds,
                    generate,
                )
                for name in configs
                for kind, photo in photos.items()
            }
            for _ in range(repeat)
        ]
        cells = {key: best([r[key] for r in rounds]) for key in rounds[0]}
        bombs = bomb_lines(
            servers["default"], f"http://127.0.0.1:{ports['default']}/v1/predict", body
        )
    finally:
        for server in servers.values():
            server.send_signal(signal.SIGTERM)
        for server in servers.values():
            server.wait(timeout=60)
    lines = [
        f"No board vs board, 640x480 JPEGs, {workers} workers, c=8, {seconds:g} s per cell, "
        f"{repeat} rounds (the table: the best of them), the same load generator:",
        "",
        "| zoom search | photo | req/s | p50 ms | p99 ms | errors | server CPU ms/req |",
        "|---|---|---|---|---|---|---|",
    ]
    for (name, kind), run in cells.items():
        lines.append(
            f"| {name} | {kind} | {run.rps:.1f} | {run.p50_ms:.1f} | {run.p99_ms:.1f} | "
            f"{run.errors} | {run.cpu_ms:.2f} |"
        )
    lines.append("")
    for name in configs:
        # paired: the two photos measured back to back in each round, the median of the rounds
        rate = [r[name, "board"].rps / r[name, "no board"].rps for r in rounds]
        cpu = [r[name, "no board"].cpu_ms / r[name, "board"].cpu_ms for r in rounds]
        by_rate, by_cpu = float(np.median(rate)), float(np.median(cpu))
        lines.append(
            f"- {name}: a photo without the board costs {by_rate:.2f}x the board photo per "
            f"request by req/s ({min(rate):.2f}-{max(rate):.2f}x over the rounds), "
            f"{by_cpu:.2f}x by server CPU ({min(cpu):.2f}-{max(cpu):.2f}x), medians of the "
            f"rounds (target <= {TARGET_NO_BOARD:g}x: "
            f"{'met' if max(by_rate, by_cpu) <= TARGET_NO_BOARD else 'MISSED'})."
        )
    lines += [
        "",
        "The bomb, against the default's workers (RSS: the worker processes, warmed up by 40 "
        "board photos; after: 0.5 s after the burst):",
        "",
        "| request | requests | status | median ms | max ms | RSS before MB | after MB | "
        "after / before |",
        "|---|---|---|---|---|---|---|---|",
        *bombs,
    ]
    return lines


def recall_lines(sets: Path) -> list[str]:
    """The zoom pass's accuracy on the real val and test sources (module doc)."""
    from service.core.dataset import load_dataset
    from service.pipeline.zoom import GRID, SEARCH_TILES, zoomed
    from train.network.evaluate import network_batch

    model = PoseModel.load(Settings().resolved_model_path)
    variants = {"off": 0, "9 tiles": GRID * GRID, f"{SEARCH_TILES} tile(s)": SEARCH_TILES}
    lines = [
        f"The zoom pass on the real val and test sources (`{sets}`, `planar-pose corpus sets "
        "--size 2`: the evaluation path, tiles enlarged from the 160x120 images), accuracy %:",
        "",
        "| split | blur | photos | pass off | search 9 tiles | search "
        f"{SEARCH_TILES} | gain, 9 tiles | gain, {SEARCH_TILES} | kept within 1 point |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for split in ("val", "test"):
        for blur in range(4):
            data = load_dataset(sets / f"real-s2-b{blur}", split=split)
            acc = {}
            for name, tiles in variants.items():
                right = 0
                for i in range(0, len(data.labels), 32):
                    batch = network_batch(data.images[i : i + 32], model.input_size)
                    aspect = data.pixel_aspect()[i : i + 32]
                    if tiles:
                        answer = zoomed(model, batch, aspect, search_tiles=tiles)
                    else:
                        answer = model.run(batch, aspect)
                    right += int((answer.probabilities.argmax(1) == data.labels[i : i + 32]).sum())
                acc[name] = 100 * right / len(data.labels)
            a = list(acc.values())
            lines.append(
                f"| {split} | {blur} | {len(data.labels)} | {a[0]:.1f} | {a[1]:.1f} | {a[2]:.1f} "
                f"| {a[1] - a[0]:+.1f} | {a[2] - a[0]:+.1f} | "
                f"{'yes' if a[2] - a[0] >= a[1] - a[0] - 1 else 'NO'} |"
            )
    lines += ["", *service_recall_lines(sets, model)]
    return lines


def service_recall_lines(sets: Path, model: PoseModel) -> list[str]:
    """The same through `Predictor` on the corpus photos as stored (blur 0; tiles cut from
    the upload where it has the pixels)."""
    from service.core.dataset import load_dataset
    from service.pipeline.zoom import GRID, SEARCH_TILES

    corpus = ROOT / "train" / "assets" / "real" / "corpus"
    variants: dict[str, dict[str, object]] = {
        "off": {"zoom": False},
        "no search": {"zoom_search": False},
        "9 tiles": {"zoom_search_tiles": GRID * GRID},
        f"{SEARCH_TILES} tile(s)": {"zoom_search_tiles": SEARCH_TILES},
    }
    lines = [
        "The same through the service's `Predictor` on the corpus photos as stored (at most "
        "640 px wide, blur 0; the tiles cut from the upload):",
        "",
        "| split | photos | " + " | ".join(variants) + " | kept within 1 point |",
        "|---|---|" + "---|" * len(variants) + "---|",
    ]
    for split in ("val", "test"):
        rows = load_dataset(sets / "real-s2-b0", split=split).rows
        photos = []
        for row in rows:
            source = row["source"]
            stem = Path(row["file"]).stem.removeprefix(source + "__")
            kind = "boards" if (corpus / "boards" / source).is_dir() else "negatives"
            (path,) = (corpus / kind / source / "images").glob(stem + ".*")
            photos.append(((None, path.read_bytes()), int(row["class"])))
        acc = []
        for options in variants.values():
            settings = Settings(exif_focal=False, **options)  # type: ignore[arg-type]
            predictor = Predictor(model, settings)
            right = 0
            for i in range(0, len(photos), 16):
                chunk = photos[i : i + 16]
                results = predictor.predict([p for p, _ in chunk], "whole").results
                right += sum(r.class_id == y for r, (_, y) in zip(results, chunk, strict=True))
            acc.append(100 * right / len(photos))
        kept = acc[3] - acc[0] >= acc[2] - acc[0] - 1
        lines.append(
            f"| {split} | {len(photos)} | "
            + " | ".join(f"{a:.1f}" for a in acc)
            + f" | {'yes' if kept else 'NO'} |"
        )
    return lines


def write_docs(lines: list[str]) -> None:
    """Replace the service section of docs/benchmarks.md (create the file if needed)."""
    text = DOCS.read_text() if DOCS.exists() else "# Benchmarks\n"
    if MARKERS[0] not in text:
        text += f"\n## Service\n\n{MARKERS[0]}\n{MARKERS[1]}\n"
    start, end = (text.index(m) for m in MARKERS)
    body = "\n".join(lines)
    DOCS.write_text(text[: start + len(MARKERS[0])] + f"\n{body}\n" + text[end:])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=3.0, help="per measurement")
    parser.add_argument("--repeat", type=int, default=2, help="rounds per cell, best kept")
    parser.add_argument("--workers", type=int, default=cpu_count(), help="N (default: CPUs)")
    parser.add_argument(
        "--loadgen", choices=("wrk", "httpx"), default="wrk" if shutil.which("wrk") else "httpx"
    )
    parser.add_argument("--write-docs", action="store_true", help="update docs/benchmarks.md")
    parser.add_argument("--recall", type=Path, help="real data sets folder: the zoom's accuracy")
    parser.add_argument("--stress-only", action="store_true", help="only 'Service under stress'")
    args = parser.parse_args()
    if args.workers < 2:
        raise SystemExit("error: --workers must be at least 2 (it is compared with 1 worker)")

    data = photo_jpeg()
    body = Path(tempfile.mkdtemp()) / "photo.jpg"
    body.write_bytes(data)
    settings = Settings()
    predictor = Predictor(PoseModel.load(settings.resolved_model_path), settings)
    generate = wrk_run if args.loadgen == "wrk" else httpx_run
    load0, started = os.getloadavg()[0], datetime.now(UTC)
    print(f"640x480 JPEG, {len(data)} bytes; load generator: {args.loadgen}; {cpu_count()} CPUs")

    cpu = platform.processor() or platform.machine()
    if not args.stress_only:
        table_section(args, body, data, predictor, generate, load0, started, cpu)
    stress_lines = stress(args.workers, body, generate, args)
    if args.recall is not None:
        stress_lines += ["", *recall_lines(args.recall)]
    command = " ".join(["benchmarks/bench_service.py", *sys.argv[1:]])
    head = (
        f"`.venv/bin/python {command}`, {started:%Y-%m-%d %H:%M} UTC: {cpu}, {cpu_count()} "
        f"CPUs, load generator {args.loadgen} (on the same CPUs), load average {load0:.2f} at "
        f"start and {os.getloadavg()[0]:.2f} at end."
    )
    print("\n".join([head, "", *stress_lines]))
    if args.write_docs:
        write_section(DOCS, STRESS_KEY, STRESS_TITLE, [head, "", *stress_lines])


def table_section(
    args: argparse.Namespace,
    body: Path,
    data: bytes,
    predictor: Predictor,
    generate: object,
    load0: float,
    started: datetime,
    cpu: str,
) -> None:
    """The table of the section "Service" (module doc), printed and written with --write-docs."""
    one, many, local = measure(args.workers, body, data, predictor, generate, args)
    lines = [
        f"_Written by `benchmarks/bench_service.py{' --write-docs' if args.write_docs else ''}` "
        f"on {started:%Y-%m-%d %H:%M} UTC: {cpu}, {cpu_count()} CPUs, Python "
        f"{platform.python_version()}, load generator {args.loadgen} (on the same CPUs), "
        f"{args.seconds:g} s per cell, best of {args.repeat}, load average {load0:.2f} at "
        f"start and {os.getloadavg()[0]:.2f} at end. Model: the default "
        f"(`{predictor.model.path.name}`, input "
        f"{predictor.model.input_size[0]}x{predictor.model.input_size[1]}, version "
        f"{predictor.model.card.get('version', '?')})._",
        "",
        *table(one, many, local, args.workers),
        "",
        "Overhead = in-process req/s (the predictor from c threads, all cores) / HTTP req/s.",
        "",
        *verdict(one, many, local, args.workers),
    ]
    print("\n".join(lines))
    if args.write_docs:
        write_docs(lines)


if __name__ == "__main__":
    main()
