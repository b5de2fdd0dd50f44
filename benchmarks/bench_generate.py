"""Synthetic data generation speed: renders per second in memory and the 16-set grid on disk.

Prints, in one run:

* images / second rendered in memory (`train.synth.generate.render_in_memory`, noC, blur 2, jitter
  on) at 160x120 and 80x60, in this process (OpenCV single-threaded, as in the workers) and
  with `--workers` processes (started and warmed up before timing), their ratio and the ratio
  to the target of 5000 img/s;
* the CPU seconds those runs used (this process and all its child processes, from /proc), so
  that on a shared machine "img per CPU-second x cores" tells what the same code does on
  free cores;
* the time to write the whole SPEC grid (16 sets x `--grid-count` images, PNG + labels +
  manifests) to a temporary folder, its ratio to the target (60 s for 16 x 5000 images) and
  its CPU seconds.

    .venv/bin/python benchmarks/bench_generate.py [--images 4000] [--workers 2]
        [--grid-count 5000] [--keep DIR]
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import cv2

from service.core.profile import load_profile
from train.synth.generate import (
    CHUNK,
    DatasetSpec,
    default_workers,
    grid_specs,
    make_datasets,
    render_in_memory,
)

TARGET_IMG_S = 5000.0
TARGET_GRID_S = 60.0
TICK = os.sysconf("SC_CLK_TCK")


def _stats() -> dict[int, list[str]]:
    """/proc/PID/stat fields after the command name, for every process (Linux)."""
    out = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                out[int(entry)] = Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
    return out


def cpu_seconds() -> float:
    """User + system CPU seconds of this process and its live descendants (e.g. workers)."""
    stats = _stats()
    children: dict[int, list[int]] = {}
    for pid, fields in stats.items():
        children.setdefault(int(fields[1]), []).append(pid)  # parent pid
    total, todo = time.process_time(), list(children.get(os.getpid(), []))
    while todo:
        pid = todo.pop()
        todo += children.get(pid, [])
        total += (int(stats[pid][11]) + int(stats[pid][12])) / TICK  # utime, stime
    return total


def measured(body: Callable[[], object]) -> tuple[float, float]:
    """(wall seconds, CPU seconds) of `body()`."""
    cpu, start = cpu_seconds(), time.perf_counter()
    body()
    return time.perf_counter() - start, cpu_seconds() - cpu


def in_memory(size: int, images: int, workers: int) -> tuple[float, float]:
    """(wall, CPU) seconds to render `images` noC blur-2 images of SPEC size 1/2 in memory."""
    profile = load_profile("chessboard")
    spec = DatasetSpec("noC", size, 2, images, 0, profile)
    warm = DatasetSpec("noC", size, 2, 2 * max(workers, 1) * CHUNK, 0, profile)
    render_in_memory(warm, workers)  # start the workers, load textures and backgrounds
    return measured(lambda: render_in_memory(spec, workers))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=4000, help="images per in-memory run")
    parser.add_argument("--workers", type=int, default=default_workers(), help="processes")
    parser.add_argument("--grid-count", type=int, default=5000, help="images per grid set")
    parser.add_argument("--keep", type=Path, help="write the grid here and keep it")
    args = parser.parse_args()
    cv2.setNumThreads(1)  # as in the worker processes
    n, images = args.workers, args.images
    print(f"load average before: {' '.join(f'{x:.1f}' for x in os.getloadavg())} on {n} cores")
    print(f"in memory, noC blur 2, jitter on, {images} images per run")
    print(
        f"size    | 1 process | {n} processes | {n}p/1p | vs 5000 img/s "
        f"| img per CPU-s | x {n} cores"
    )
    for size, name in ((2, "160x120"), (1, "80x60")):
        wall1, _ = in_memory(size, images, 1)
        wall, cpu = in_memory(size, images, n)
        one, many, per_cpu = images / wall1, images / wall, images / cpu
        print(
            f"{name:7} | {one:7.0f}/s | {many:11.0f}/s | {many / one:6.2f} | "
            f"{many / TARGET_IMG_S:12.2f}x | {per_cpu:13.0f} | {per_cpu * n:6.0f}/s"
        )

    root = args.keep or Path(tempfile.mkdtemp(prefix="bench-grid-"))
    specs = grid_specs(args.grid_count, 0, load_profile("chessboard"))
    total = sum(s.count for s in specs)
    jobs = [(s, root / s.name) for s in specs]
    seconds, cpu = measured(lambda: make_datasets(jobs, overwrite=True, workers=n))
    size_mb = sum(p.stat().st_size for p in root.rglob("*") if p.is_file()) / 1e6
    target = TARGET_GRID_S * total / 80_000
    print(
        f"grid on disk: 16 sets, {total} images, {size_mb:.0f} MB in {seconds:.1f} s "
        f"({total / seconds:.0f} img/s, {n} processes); target {target:.0f} s -> "
        f"{target / seconds:.2f}x; {cpu:.1f} CPU-s, i.e. {cpu / n:.1f} s on {n} free cores"
    )
    print(f"load average after: {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    if args.keep is None:
        shutil.rmtree(root)


if __name__ == "__main__":
    main()
