"""Synthetic data generation speed: renders per second in memory and the 16-set grid on disk.

Prints, in one run, images / second rendered in memory (`train.datasets.render_in_memory`,
noC, blur 2, jitter on) at 80x60 and 160x120 with 1 process and with `--workers` processes
(started and warmed up before timing), their ratio, the ratio to the target (5000 img/s),
then the time to write the whole SPEC grid (16 sets x `--grid-count` images, PNG + labels +
manifests) to a temporary folder and its ratio to the target (60 s for 16 x 5000 images).

    .venv/bin/python benchmarks/bench_generate.py [--images 4000] [--workers 2]
        [--grid-count 5000] [--keep DIR]
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

from train.datasets import (
    CHUNK,
    DatasetSpec,
    default_workers,
    grid_specs,
    make_datasets,
    render_in_memory,
)
from train.profile import load_profile

TARGET_IMG_S = 5000.0
TARGET_GRID_S = 60.0


def in_memory_rate(size: int, images: int, workers: int) -> float:
    """Images / second of rendering `images` noC blur-2 images of SPEC size 1/2 in memory."""
    spec = DatasetSpec("noC", size, 2, images, 0, load_profile("chessboard"))
    warm = DatasetSpec("noC", size, 2, 4 * CHUNK, 1, spec.profile)
    render_in_memory(warm, workers)  # start the workers, load textures and backgrounds
    start = time.perf_counter()
    rendered, _ = render_in_memory(spec, workers)
    seconds = time.perf_counter() - start
    assert len(rendered) == images
    return images / seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=4000, help="images per in-memory run")
    parser.add_argument("--workers", type=int, default=default_workers(), help="processes")
    parser.add_argument("--grid-count", type=int, default=5000, help="images per grid set")
    parser.add_argument("--keep", type=Path, help="write the grid here and keep it")
    args = parser.parse_args()

    print(f"in memory, noC blur 2, jitter on, {args.images} images per run")
    n = args.workers
    print(f"size    | 1 process | {n} processes | {n}p/1p | vs 5000 img/s")
    for size, name in ((2, "160x120"), (1, "80x60")):
        one = in_memory_rate(size, args.images, 1)
        many = in_memory_rate(size, args.images, args.workers)
        print(
            f"{name:7} | {one:6.0f}/s  | {many:9.0f}/s  | {many / one:5.2f} | "
            f"{many / TARGET_IMG_S:5.2f}x"
        )

    root = args.keep or Path(tempfile.mkdtemp(prefix="bench-grid-"))
    specs = grid_specs(args.grid_count, 0, load_profile("chessboard"))
    total = sum(s.count for s in specs)
    start = time.perf_counter()
    make_datasets([(s, root / s.name) for s in specs], overwrite=True, workers=args.workers)
    seconds = time.perf_counter() - start
    size_mb = sum(p.stat().st_size for p in root.rglob("*") if p.is_file()) / 1e6
    target = TARGET_GRID_S * total / 80_000
    print(
        f"grid on disk: 16 sets, {total} images, {size_mb:.0f} MB in {seconds:.1f} s "
        f"({total / seconds:.0f} img/s, {args.workers} processes); "
        f"target {target:.0f} s -> {target / seconds:.2f}x"
    )
    if args.keep is None:
        shutil.rmtree(root)


if __name__ == "__main__":
    main()
