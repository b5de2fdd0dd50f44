"""Training speed of `train.network.fit` vs a plain PyTorch loop, and what the default's recipe
costs on this machine, measured in one run.

Prints ms per training image (forward + backward + optimiser step, batch 64) for the
project's training epoch (`train.network.fit._train_epoch`) on uint8 images in memory: the
SPEC network at both sizes (eager, compiled, with the batch-norm layers that `planar-pose
train` adds by default, and that with augmentation), the convnet, and the default's networks
(`corners-coarse`, `corners` at 160x120, with the options of the first recipe stage that
trains each: optimiser, corner loss, augmentation; in float32 and with `bf16`, the autocast
that the recipes ask for; eager, as the recipes train, and compiled); a plain eager loop over
the SPEC network on pre-made float tensors (the reference); the ratios, and the thesis's Torch7
training times (15 ms at 80x60, 71 ms at 160x120) for scale. Where the recipes' data sets
are on this machine (runs/default/data, made by scripts/train_default.sh), it also adds up
the training images of every stage of the default's recipe (epochs x each data set's train
split x its repeat) at the measured rate of its network and precision.

    .venv/bin/python benchmarks/bench_train.py [--images 512] [--threads 2] [--write-docs]
"""

from __future__ import annotations

import argparse
import csv
import datetime as dt
import functools
import os
import platform
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from docs_section import write_section  # benchmarks/, the script's own folder

from train.markdown import table
from train.network.config import load_config, read_recipe
from train.network.fit import (
    Augmenter,
    FitConfig,
    Split,
    _optimiser,
    _train_epoch,
    cpu_bf16_flags,
)
from train.network.model import PoseNet, build_network

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs" / "benchmarks.md"
THESIS_MS = {(80, 60): 15.0, (160, 120): 71.0}
BATCH = 64
#: The default's recipe, in the order scripts/train_default.sh runs it.
DEFAULT_RECIPE = (
    "chessboard-corners-160x120-stage1",
    "chessboard-corners-160x120-stage2",
    "chessboard-corners-160x120-stage3",
    "chessboard-corners-160x120",
)


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


def _split(size: tuple[int, int], n: int) -> Split:
    """n random images with random classes and a board's corners inside the image (px)."""
    rng = np.random.default_rng(0)
    w, h = size
    corners = np.tile(np.array([0.2, 0.2, 0.8, 0.2, 0.8, 0.8, 0.2, 0.8], np.float32), (n, 1))
    corners *= np.tile([w, h], 4).astype(np.float32)
    return Split(
        rng.integers(0, 256, (n, h, w, 3), dtype=np.uint8),
        rng.integers(0, 9, n).astype(np.int64),
        np.zeros(n, dtype=np.int64),
        [n],
        corners,
        np.ones(n, np.float32),
    )


def project_epoch_ms(
    size: tuple[int, int],
    n: int,
    augment: bool,
    compiled: bool,
    batch_norm: bool = False,
    arch: str = "spec",
    recipe: FitConfig | None = None,
) -> float:
    """`train.network.fit._train_epoch` on uint8 images in memory (conversion, augmentation,
    the corner loss of the networks that have one) -> ms per image; with the optimiser, loss
    weights and augmentation options of `recipe` where given (default: FitConfig's).

    With `compiled`, a first epoch compiles and warms up; the second is timed.
    """
    split = _split(size, n)
    base = recipe or FitConfig(datasets=[], out=Path("."))
    config = replace(base, datasets=[], out=Path("."), batch_size=BATCH, progress=False)
    torch.manual_seed(0)
    net = build_network(arch, size, batch_norm).to(memory_format=torch.channels_last)
    opt = _optimiser(config, net)
    step = torch.compile(net) if compiled else net
    augmenter = Augmenter(size, p_squash=config.squash) if augment else None
    pool = split.pool([])
    if compiled:
        _train_epoch(step, opt, split, pool, config, 1, augmenter)
    return _train_epoch(step, opt, split, pool, config, 2, augmenter)["ms_per_image"]


@functools.cache
def train_images(folder: Path) -> int | None:
    """Images of a data set's train split (labels.csv, read once), None when the set is not
    here."""
    labels = ROOT / folder / "labels.csv"
    if not labels.is_file():
        return None
    with labels.open(newline="", encoding="utf-8") as f:
        return sum(row["split"] == "train" for row in csv.DictReader(f))


def default_stages() -> list[tuple[str, str, FitConfig]]:
    """The default's recipe stages as (name, network, FitConfig): a stage that fine-tunes
    without naming its network keeps its parent's."""
    stages, arch = [], "spec"
    for name in DEFAULT_RECIPE:
        path = ROOT / "recipes" / f"{name}.toml"
        arch = read_recipe(path).get("arch", arch)
        stages.append((name, arch, load_config(path, {})))
    return stages


def bf16_units() -> str:
    """What the CPU has for bfloat16 (`train.network.fit.cpu_bf16_flags`), in words."""
    found = cpu_bf16_flags()
    if found is None:
        return "has unknown bfloat16 support"
    return f"has {' and '.join(found)}" if found else "has no bfloat16 units"


def recipe_rows(
    stages: list[tuple[str, str, FitConfig]], ms: dict[tuple[str, bool], float]
) -> tuple[list[list[str]], float | None]:
    """Per stage: (name, network, epochs, images per epoch, hours at the measured ms per
    image of its network in its precision, `ms[arch, bf16]`); and the total hours (None: a
    data set is missing)."""
    rows: list[list[str]] = []
    total = 0.0
    for name, arch, config in stages:
        counts = [train_images(d) for d in config.datasets]
        if any(c is None for c in counts):
            return rows, None
        repeat = config.repeat or [1] * len(counts)
        per_epoch = sum(c * r for c, r in zip(counts, repeat, strict=True) if c is not None)
        hours = config.epochs * per_epoch * ms[arch, config.bf16] / 3.6e6
        total += hours
        precision = "bfloat16" if config.bf16 else "float32"
        rows.append([name, arch, precision, str(config.epochs), str(per_epoch), f"{hours:.2f}"])
    return rows, total


SPEC_HEADER = [
    "size", "plain loop", "fit eager", "fit compiled", "+ batch norm", "+ augment",
    "convnet + augment", "compiled / plain", "thesis", "thesis / ours (+ augment)",
]  # fmt: skip


def spec_rows(images: int) -> list[list[str]]:
    """The SPEC network and the convnet at each thesis size: ms per training image of a plain
    loop and of `fit` (eager, compiled, + batch norm, + augmentation), against the thesis's."""
    rows = []
    for size in THESIS_MS:
        plain_loop_ms(size, BATCH)  # warm-up
        plain = plain_loop_ms(size, images)
        eager = project_epoch_ms(size, images, augment=False, compiled=False)
        ours = project_epoch_ms(size, images, augment=False, compiled=True)
        bn = project_epoch_ms(size, images, augment=False, compiled=True, batch_norm=True)
        aug = project_epoch_ms(size, images, augment=True, compiled=True, batch_norm=True)
        conv = project_epoch_ms(size, images, augment=True, compiled=True, arch="convnet")
        thesis = THESIS_MS[size]
        rows.append(
            [f"{size[0]}x{size[1]}"]
            + [f"{v:.2f}" for v in (plain, eager, ours, bn, aug, conv)]
            + [f"{ours / plain:.2f}x", f"{thesis:.0f}", f"{thesis / aug:.1f}x"]
        )
        print(" | ".join(rows[-1]))
    return rows


def corner_rows(
    first: dict[str, FitConfig], images: int
) -> tuple[list[list[str]], dict[tuple[str, bool], float]]:
    """Each corner network's first recipe stage at 160x120, float32 / bfloat16, eager /
    compiled -> (table rows, {(arch, bf16): eager ms per image})."""
    measured = {  # (arch, bf16, compiled) -> ms per image
        (arch, bf16, compiled): project_epoch_ms(
            (160, 120),
            images,
            augment=True,
            compiled=compiled,
            arch=arch,
            recipe=replace(config, bf16=bf16),
        )
        for arch, config in first.items()
        for bf16 in (False, True)
        for compiled in (False, True)
    }
    corner_ms = {(a, bf16): ms for (a, bf16, compiled), ms in measured.items() if not compiled}
    rows = []
    for arch, config in first.items():
        fp32, bf16 = corner_ms[arch, False], corner_ms[arch, True]
        recipe_ms = corner_ms[arch, config.bf16]
        compiled_ms = [measured[arch, b, True] for b in (False, True)]
        rows.append(
            [arch, f"{fp32:.2f}", f"{bf16:.2f}", f"{fp32 / bf16:.2f}x"]
            + [f"{ms:.2f}" for ms in compiled_ms]
            + [f"{THESIS_MS[160, 120] / recipe_ms:.1f}x"]
        )
        print(" | ".join(rows[-1]))
    return rows, corner_ms


def recipe_lines(
    stages: list[tuple[str, str, FitConfig]], corner_ms: dict[tuple[str, bool], float]
) -> list[str]:
    """The default's recipe added up at the measured rates (hours), or why not."""
    rows, total = recipe_rows(stages, corner_ms)
    _, all_bf16 = recipe_rows([(n, a, replace(c, bf16=True)) for n, a, c in stages], corner_ms)
    if total is None:
        return [
            "The default's recipe was not added up: its data sets are not on this machine "
            "(runs/default/data; scripts/train_default.sh makes them)."
        ]
    return [
        "The default's recipe (scripts/train_default.sh, stage 2) at these rates: training "
        "steps only (no validation, data generation, export or evaluation):",
        "",
        *table(["recipe", "network", "precision", "epochs", "images / epoch", "hours"], rows),
        "",
        f"In all {total:.1f} hours of training steps on this machine; with `bf16` in "
        f"every stage {all_bf16:.1f} hours.",
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=512, help="images per measurement")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0 = default)")
    parser.add_argument("--write-docs", action="store_true", help="update docs/benchmarks.md")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    when = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    header = (
        f"`.venv/bin/python benchmarks/bench_train.py --images {args.images}"
        f"{f' --threads {args.threads}' if args.threads else ''}`, {when}, "
        f"{platform.machine()}, {os.cpu_count()} CPUs, torch {torch.__version__} with "
        f"{torch.get_num_threads()} threads, batch {BATCH}, load average "
        f"{os.getloadavg()[0]:.2f} at start. ms per training image."
    )
    print(header)
    spec = spec_rows(args.images)
    stages = default_stages()
    first: dict[str, FitConfig] = {}  # each network's first stage
    for _, arch, config in stages:
        first.setdefault(arch, config)
    key_rows, corner_ms = corner_rows(first, args.images)
    lines = [
        header,
        "",
        "The SPEC network (batch norm folded away on export) and the convnet:",
        "",
        *table(SPEC_HEADER, spec),
        "",
        "The default's networks at 160x120, with the optimiser, corner loss and "
        "augmentation of the first recipe stage that trains each, in float32 and with "
        f"`bf16` (torch.autocast; this CPU {bf16_units()}), eager (as the recipes train) "
        "and compiled (`compile = true`: torch.compile of the step, after a warm-up epoch):",
        "",
        *table(
            ["network", "float32", "bfloat16 (`bf16`)", "float32 / bfloat16"]
            + ["float32 compiled", "bfloat16 compiled"]
            + ["thesis (71 ms) / ours, as the recipe trains"],
            key_rows,
        ),
        "",
        *recipe_lines(stages, corner_ms),
    ]
    print("\n".join(lines[-3:]))
    if args.write_docs:
        write_section(DOCS, "bench_train", "Training", lines)
        print(f"wrote {DOCS}")


if __name__ == "__main__":
    main()
