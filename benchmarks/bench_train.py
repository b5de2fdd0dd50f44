"""Training speed of `train.network.fit` vs a plain PyTorch loop, both sizes, measured in one run.

Prints ms / image (forward + backward + SGD step, batch 64) for the project's training epoch
(`train.network.fit._train_epoch`: eager, compiled, compiled with the batch-norm layers that
`planar-pose train` adds by default, and that with augmentation) and for a plain eager loop
over the SPEC network on pre-made float tensors (the reference), the ratio between them, and
the thesis's Torch7 training times (15 ms at 80x60, 71 ms at 160x120) for scale.

    .venv/bin/python benchmarks/bench_train.py [--images 512] [--threads 2]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from train.network.fit import Augmenter, FitConfig, Split, _optimiser, _train_epoch
from train.network.model import PoseNet, build_network

THESIS_MS = {(80, 60): 15.0, (160, 120): 71.0}
BATCH = 64


def plain_loop_ms(size: tuple[int, int], n: int) -> float:
    """Reference: the same network, float NCHW tensors made up front, SGD with momentum."""
    torch.manual_seed(0)
    net = PoseNet(size).train()
    opt = torch.optim.SGD(net.parameters(), lr=0.01, momentum=0.9)
    x = torch.rand(n, 3, size[1], size[0])
    y = torch.randint(0, 9, (n,))
    start = time.perf_counter()
    for i in range(0, n, BATCH):
        loss = F.nll_loss(net(x[i : i + BATCH]), y[i : i + BATCH])
        opt.zero_grad()
        loss.backward()
        opt.step()
    return 1000 * (time.perf_counter() - start) / n


def project_epoch_ms(
    size: tuple[int, int],
    n: int,
    augment: bool,
    compiled: bool,
    batch_norm: bool = False,
    arch: str = "spec",
) -> float:
    """`train.network.fit._train_epoch` on uint8 images in memory (conversion, augmentation).

    With `compiled`, a first epoch compiles and warms up; the second is timed.
    """
    rng = np.random.default_rng(0)
    split = Split(
        rng.integers(0, 256, (n, size[1], size[0], 3), dtype=np.uint8),
        rng.integers(0, 9, n).astype(np.int64),
        np.zeros(n, dtype=np.int64),
        [n],
    )
    config = FitConfig(datasets=[], out=Path("."), batch_size=BATCH, progress=False)
    torch.manual_seed(0)
    net = build_network(arch, size, batch_norm).to(memory_format=torch.channels_last)
    opt = _optimiser(config, net)
    step = torch.compile(net) if compiled else net
    augmenter = Augmenter(size) if augment else None
    pool = split.pool([])
    if compiled:
        _train_epoch(step, opt, split, pool, config, 1, augmenter)
    return _train_epoch(step, opt, split, pool, config, 2, augmenter)["ms_per_image"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=512, help="images per measurement")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0 = default)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, batch {BATCH}")
    print(
        "size     | plain loop | fit eager | fit compiled | +batch norm | +augment "
        "| convnet +augment | compiled/plain | thesis | thesis/ours"
    )
    for size in THESIS_MS:
        plain_loop_ms(size, BATCH)  # warm-up
        plain = plain_loop_ms(size, args.images)
        eager = project_epoch_ms(size, args.images, augment=False, compiled=False)
        ours = project_epoch_ms(size, args.images, augment=False, compiled=True)
        bn = project_epoch_ms(size, args.images, augment=False, compiled=True, batch_norm=True)
        aug = project_epoch_ms(size, args.images, augment=True, compiled=True, batch_norm=True)
        conv = project_epoch_ms(size, args.images, augment=True, compiled=True, arch="convnet")
        thesis = THESIS_MS[size]
        print(
            f"{size[0]}x{size[1]:<4} | {plain:8.2f}ms | {eager:7.2f}ms | {ours:10.2f}ms | "
            f"{bn:9.2f}ms | {aug:6.2f}ms | {conv:14.2f}ms | {ours / plain:14.2f} | {thesis:4.0f}ms "
            f"| {thesis / aug:9.1f}x"
        )


if __name__ == "__main__":
    main()
