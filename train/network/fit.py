"""Training and fine-tuning of the pose network (SPEC section 8), readable top to bottom.

`fit(config)` trains the network of `config.arch` (`train.network.model.build_network`) on
the `train` split of one or more data sets (same image size; `config.repeat` weights them),
keeps the best epoch by accuracy on the `val` split of `config.select` (default: the same data
sets), stops early when it stops improving and writes into `config.out`:

* `last.pt`   the state after the last finished epoch (what `resume` continues from);
* `best.pt`   the weights of the best validation epoch (what `export` takes);
* `log.jsonl` one JSON line per epoch (loss, accuracy, learning rate, time).

With `init`, the weights (and the input normalisation) come from a checkpoint, or from a
shipped corner model's ONNX graph: fine-tuning, e.g. on a real data set. A run is
deterministic on CPU for a seed: batches and augmentation draw from generators seeded by
(seed, epoch), so a resumed run ends where an uninterrupted one does.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from service.core.blur import blur_image
from service.core.dataset import load_dataset
from train.network.base import NormalisedNet
from train.network.config import FitConfig, canonical_arch
from train.network.model import arch_of, build_network, channel_stats, log_probabilities
from train.network.onnx_weights import (
    OnnxWeightsError,
    corner_net_from_onnx,
    recalibrate_batch_norm,
)

CHECKPOINT_FORMAT = "planar-pose-checkpoint/1"


class TrainingError(ValueError):
    """Bad training input (data set, checkpoint, options), with a message for the user."""


@dataclass
class Split:
    """Images uint8 [N, H, W, 3] (RGB) and labels int64 [N] of one split, all data sets."""

    images: np.ndarray
    labels: np.ndarray
    blur: np.ndarray  # int [N], the data set's blur level of each image
    counts: list[int]  # images per data set, in order
    corners: np.ndarray  # float32 [N, 8]: the object corners in pixels (nan where unknown)
    pixel_aspect: np.ndarray  # float32 [N] (`LoadedDataset.pixel_aspect`)

    def pool(self, repeat: list[int]) -> np.ndarray:
        """Indices of one epoch: data set k's images `repeat[k]` times (default once each)."""
        starts = np.cumsum([0, *self.counts])
        reps = repeat or [1] * len(self.counts)
        return np.concatenate(
            [
                np.tile(np.arange(a, b), r)
                for a, b, r in zip(starts[:-1], starts[1:], reps, strict=True)
            ]
        )


def load_split(paths: list[Path], split: str) -> tuple[Split, list[dict[str, Any]]]:
    """Concatenate `split` of data sets at `paths` -> (Split, their manifests + counts).

    Raises TrainingError for a missing folder, mixed image sizes or an empty split.
    """
    images, labels, blurs, corners, aspects, infos = [], [], [], [], [], []
    for path in paths:
        if not (path / "labels.csv").is_file():
            raise TrainingError(f"not a data set (no labels.csv): {path}")
        data = load_dataset(path, split=split)
        images.append(data.images)
        labels.append(data.labels)
        blurs.append(np.full(len(data.labels), int(data.manifest.get("blur", 0))))
        corners.append(data.corners().reshape(-1, 8))
        aspects.append(data.pixel_aspect())
        # the manifest's own "count" is the whole set's: this split's count comes last
        infos.append(
            {"path": str(path), **data.manifest, "split": split, "count": len(data.labels)}
        )
    sizes = {im.shape[1:3] for im in images if len(im)}
    if len(sizes) > 1:
        raise TrainingError(f"data sets have different image sizes (H, W): {sorted(sizes)}")
    out = Split(
        np.concatenate(images),
        np.concatenate(labels).astype(np.int64),
        np.concatenate(blurs),
        [len(lab) for lab in labels],
        np.concatenate(corners),
        np.concatenate(aspects),
    )
    return out, infos


def to_input(images: np.ndarray) -> torch.Tensor:
    """RGB uint8 [N, H, W, 3] -> float32 [N, 3, H, W] in [0, 1], channels-last in memory."""
    x = torch.from_numpy(images).permute(0, 3, 1, 2).float().div_(255.0)
    return x.contiguous(memory_format=torch.channels_last)


class Augmenter:
    """On-the-fly augmentation of a training batch, RGB uint8 [B, H, W, 3] -> the network's
    input float32 [B, 3, H, W] in [0, 1].

    * blur: an image of a blur-0 data set gets, with probability `p_blur`, a SPEC blur level
      drawn from 1..3 (the same kernels as the data sets, `service.core.blur`), so that one network
      sees all levels;
    * crop: with probability `p_crop`, a crop of U(0.85, 1) of the width and height at a
      random place, resized back: the camera centre (so the class) is unchanged, the image
      is what a camera with a longer focal length and a shifted principal point sees; or,
      with probability `p_squash`, a band of the full width and U(0.7, 1) of the height
      that keeps the object's corners inside where it can: a wide photo (16:9 is a band of
      0.75) squashed to the input size, as the service does;
    * photometric: contrast x U(0.7, 1.3), brightness + U(-25, 25), per-channel gain
      U(0.9, 1.1), grey level with probability `p_grey` (real photos may be grey), Gaussian
      noise with sigma U(0, 6) grey levels.

    No mirror, rotation or large shift: those would change the pose class.
    """

    def __init__(
        self,
        size: tuple[int, int],
        p_blur: float = 0.5,
        p_grey: float = 0.2,
        p_crop: float = 0.5,
        p_squash: float = 0.0,
    ) -> None:
        self.size = size
        self.p_blur = p_blur
        self.p_grey = p_grey
        self.p_crop = p_crop
        self.p_squash = p_squash

    def crop(
        self, image: np.ndarray, corners: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """A random crop (see the class doc), resized back to the image size, and the
        corners (8,) px moved with it."""
        import cv2

        h, w = image.shape[:2]
        # drawn only when on, so that the recipes without it keep their random streams
        if self.p_squash > 0 and rng.random() < self.p_squash:
            cw, ch = w, int(round(h * rng.uniform(0.7, 1.0)))
            v = corners[1::2]
            lo, hi = (0, h - ch) if np.isnan(v).any() else (v.max() + 1 - ch, v.min())
            lo, hi = int(np.clip(np.ceil(lo), 0, h - ch)), int(np.clip(np.floor(hi), 0, h - ch))
            x0, y0 = 0, int(rng.integers(min(lo, hi), max(lo, hi) + 1))
        else:
            cw, ch = int(round(w * rng.uniform(0.85, 1.0))), int(round(h * rng.uniform(0.85, 1.0)))
            x0, y0 = int(rng.integers(w - cw + 1)), int(rng.integers(h - ch + 1))
        out = cv2.resize(image[y0 : y0 + ch, x0 : x0 + cw], (w, h), interpolation=cv2.INTER_AREA)
        scale = np.tile([w / cw, h / ch], 4)
        return out, (corners + 0.5 - np.tile([x0, y0], 4)) * scale - 0.5

    def __call__(
        self,
        images: np.ndarray,
        blur: np.ndarray,
        rng: np.random.Generator,
        corners: np.ndarray | None = None,
    ) -> tuple[torch.Tensor, np.ndarray]:
        """Augmented network input float32 [B, 3, H, W] in [0, 1] (channels-last, as
        `to_input`) and the corners [B, 8] px (nan if not given)."""
        n = len(images)
        out = images.copy()
        corners = np.full((n, 8), np.nan, np.float32) if corners is None else corners.copy()
        for i in np.flatnonzero(rng.random(n) < self.p_crop):
            out[i], corners[i] = self.crop(out[i], corners[i], rng)
        levels = np.where(
            (blur == 0) & (rng.random(n) < self.p_blur), rng.integers(1, 4, size=n), 0
        )
        for i in np.flatnonzero(levels):
            out[i] = blur_image(out[i], int(levels[i]), self.size)
        return self.photometric(to_input(out), rng), corners

    def photometric(self, x: torch.Tensor, rng: np.random.Generator) -> torch.Tensor:
        """The photometric part on the input [B, 3, H, W] in [0, 1], in torch (the noise is
        most of the augmentation's time in numpy); its parameters, and the seed of the noise,
        come from `rng`."""
        n = len(x)

        def per_image(values: np.ndarray) -> torch.Tensor:  # [B] or [B, 3] -> [B, 3 | 1, 1, 1]
            t = torch.from_numpy(values.astype(np.float32))
            return t.reshape(n, -1, 1, 1)

        grey = torch.from_numpy(rng.random(n) < self.p_grey).reshape(n, 1, 1, 1)
        x = torch.where(grey, x.mean(1, keepdim=True), x)
        gain = per_image(rng.uniform(0.7, 1.3, (n, 1)) * rng.uniform(0.9, 1.1, (n, 3)))
        shift = per_image(rng.uniform(-25, 25, n) / 255)
        sigma = per_image(rng.uniform(0, 6, n) / 255)
        noise = torch.Generator().manual_seed(int(rng.integers(2**62)))
        mean = x.mean((1, 2, 3), keepdim=True)
        x = (x - mean) * gain + mean + shift + sigma * torch.randn(x.shape, generator=noise)
        return x.clamp_(0.0, 1.0).contiguous(memory_format=torch.channels_last)


def load_network(path: Path) -> tuple[NormalisedNet, dict[str, Any]]:
    """A checkpoint written by `fit` -> (network with its weights, the checkpoint dict)."""
    if not Path(path).is_file():
        raise TrainingError(f"checkpoint not found: {path}")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # torch raises several types for a file that is not a checkpoint
        raise TrainingError(f"{path} is not a readable PyTorch checkpoint: {exc}") from exc
    if not isinstance(checkpoint, dict) or checkpoint.get("format") != CHECKPOINT_FORMAT:
        raise TrainingError(f"{path} is not a planar-pose training checkpoint")
    arch = canonical_arch(str(checkpoint.get("arch", "spec")))
    size, batch_norm = tuple(checkpoint["size"]), bool(checkpoint.get("batch_norm"))
    net = build_network(arch, size, batch_norm, checkpoint.get("profile"))
    net.load_state_dict(checkpoint["model"])
    return net, checkpoint


def _optimiser(config: FitConfig, net: NormalisedNet) -> torch.optim.Optimizer:
    if config.optimizer == "sgd":
        return torch.optim.SGD(
            net.parameters(),
            lr=config.lr,
            momentum=config.momentum,
            weight_decay=config.weight_decay,
        )
    if config.optimizer == "adam":
        return torch.optim.Adam(net.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    raise TrainingError(f"unknown optimiser {config.optimizer!r} (sgd or adam)")


def _schedule(
    config: FitConfig, opt: torch.optim.Optimizer
) -> torch.optim.lr_scheduler.LRScheduler:
    if config.schedule == "cosine":
        return torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(config.epochs, 1))
    if config.schedule == "step":
        step = max(1, round(2 * config.epochs / 3))
        return torch.optim.lr_scheduler.StepLR(opt, step_size=step, gamma=0.1)
    if config.schedule == "constant":
        return torch.optim.lr_scheduler.ConstantLR(opt, factor=1.0, total_iters=0)
    raise TrainingError(f"unknown schedule {config.schedule!r} (cosine, step or constant)")


def training_device(name: str) -> torch.device:
    """The device `FitConfig.device` names: "auto" is CUDA where torch sees a GPU, else CPU."""
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda" and not torch.cuda.is_available():
        raise TrainingError("--device cuda: torch sees no CUDA GPU on this machine")
    return torch.device(name)


def cpu_bf16_flags() -> list[str] | None:
    """The CPU's bfloat16 units among amx_bf16, avx512_bf16 (Linux /proc/cpuinfo flags);
    None where the flags cannot be read."""
    try:
        flags = set(Path("/proc/cpuinfo").read_text().split())
    except OSError:
        return None
    return [f for f in ("amx_bf16", "avx512_bf16") if f in flags]


def native_bf16(device: str) -> bool:
    """Whether the training device (`training_device`'s name) computes bfloat16 natively:
    the GPU says so, or the CPU has bfloat16 units (`cpu_bf16_flags`)."""
    if device != "cpu" and torch.cuda.is_available():
        return bool(torch.cuda.is_bf16_supported())
    return bool(cpu_bf16_flags())


@torch.no_grad()
def evaluate_split(net: NormalisedNet, split: Split, batch: int = 256) -> tuple[float, float]:
    """(mean NLL loss, accuracy) of `net` on a split, no augmentation, on the net's device."""
    net.eval()
    device = next(net.parameters()).device
    loss, correct = 0.0, 0
    for i in range(0, len(split.labels), batch):
        y = torch.from_numpy(split.labels[i : i + batch]).to(device)
        x = to_input(split.images[i : i + batch]).to(device)
        aspect = torch.from_numpy(split.pixel_aspect[i : i + batch]).to(device)
        out = log_probabilities(net, x, aspect)
        loss += F.nll_loss(out, y, reduction="sum").item()
        correct += int((out.argmax(1) == y).sum())
    n = max(len(split.labels), 1)
    return loss / n, correct / n


def _save(path: Path, payload: dict[str, Any]) -> None:
    tmp = path.with_suffix(".tmp")
    torch.save(payload, tmp)
    tmp.replace(path)


def fit(config: FitConfig, resume: bool = False) -> dict[str, Any]:
    """Train as `config` says; return the summary (best epoch, accuracies, ms / image)."""
    if config.epochs < 1 or config.batch_size < 1:
        raise TrainingError("epochs and batch size must be >= 1")
    if config.threads:
        torch.set_num_threads(config.threads)
    train, train_info = load_split(config.datasets, "train")
    val, _ = load_split(config.select or config.datasets, "val")
    pool = train.pool(config.repeat)
    if len(train.labels) == 0:
        raise TrainingError(f"no 'train' split images in {[str(p) for p in config.datasets]}")
    size = (train.images.shape[2], train.images.shape[1])

    torch.manual_seed(config.seed)
    net, parent = _initial_network(config, train, size, train_info[0].get("profile"))
    device = training_device(config.device)
    net = net.to(device).to(memory_format=torch.channels_last)
    opt = _optimiser(config, net)
    sched = _schedule(config, opt)
    augmenter = Augmenter(size, p_squash=config.squash) if config.augment else None
    # The compiled module shares its parameters with `net` (used for evaluation and saving).
    step_net = torch.compile(net) if config.compile else net

    config.out.mkdir(parents=True, exist_ok=True)
    log_path = config.out / "log.jsonl"
    state: dict[str, Any] = {
        "format": CHECKPOINT_FORMAT,
        "size": list(size),
        "batch_norm": net.batch_norm,
        "arch": arch_of(net),
        "config": config.to_json(),
        "data": train_info,
        "profile": train_info[0].get("profile", {}),
        "parent": None if parent is None else _provenance(parent, config.init),
        "epoch": 0,
        "best": {"epoch": 0, "val_accuracy": -1.0, "val_loss": math.inf},
        "bad_epochs": 0,
        "history": [],
    }
    if resume:
        _resume(config.out / "last.pt", size, net, opt, sched, state)
    elif log_path.exists():
        log_path.unlink()

    for epoch in range(state["epoch"] + 1, config.epochs + 1):
        if config.patience and state["bad_epochs"] >= config.patience:
            break
        row = _train_epoch(net, step_net, opt, train, pool, config, epoch, augmenter)
        sched.step()
        row["val_loss"], row["val_accuracy"] = (
            evaluate_split(net, val)
            if len(val.labels)
            else (row["train_loss"], row["train_accuracy"])
        )
        improved = _record(state, row, log_path)
        payload = {**state, "model": net.state_dict()}
        if improved:
            _save(config.out / "best.pt", payload)
        _save(
            config.out / "last.pt",
            {**payload, "optimizer": opt.state_dict(), "scheduler": sched.state_dict()},
        )
        if config.progress:
            tqdm.write(
                f"epoch {epoch}: train loss {row['train_loss']:.4f} acc {row['train_accuracy']:.3f}"
                f" | val loss {row['val_loss']:.4f} acc {row['val_accuracy']:.3f}"
                f" | {row['ms_per_image']:.2f} ms/image"
            )
    history = state["history"]
    return {
        "out": str(config.out),
        "epochs_run": state["epoch"],
        "best": state["best"],
        "stopped_early": state["epoch"] < config.epochs,
        "ms_per_image": float(np.mean([r["ms_per_image"] for r in history])) if history else None,
    }


def _initial_network(
    config: FitConfig, train: Split, size: tuple[int, int], profile: dict[str, Any] | None
) -> tuple[NormalisedNet, dict[str, Any] | None]:
    """The network to train and the parent checkpoint (fine-tuning keeps the parent's
    architecture, weights and normalisation; an ONNX `init` is read back by
    `train.network.onnx_weights`, its batch norms set from up to 1024 training images), or
    a new `config.arch` network for the first data set's object `profile` (manifest),
    normalised to the training images (parent None)."""
    if config.init is not None:
        from_onnx = config.init.suffix == ".onnx"
        if from_onnx:
            try:
                net, parent = corner_net_from_onnx(config.init)
            except OnnxWeightsError as exc:
                raise TrainingError(f"--init {exc}") from None
        else:
            net, parent = load_network(config.init)
        if net.size != size:
            raise TrainingError(
                f"--init {config.init} takes {net.size[0]}x{net.size[1]} "
                f"images but the data sets are {size[0]}x{size[1]}"
            )
        if from_onnx:  # after the size check: the images must fit the network
            sample = np.random.default_rng(config.seed).permutation(len(train.labels))[:1024]
            recalibrate_batch_norm(net, to_input(train.images[np.sort(sample)]))
        if config.arch == "corners" and arch_of(net) == "corners-coarse":
            return _grown(net, build_network(config.arch, size, profile=profile)), parent
        return net, parent
    try:
        net = build_network(config.arch, size, config.batch_norm, profile)
    except ValueError as exc:
        raise TrainingError(f"--arch {config.arch}: {exc}") from exc
    mean, std = channel_stats(torch.from_numpy(train.images))
    net.set_normalisation(mean, std)
    return net, None


def _grown(parent: NormalisedNet, net: NormalisedNet) -> NormalisedNet:
    """`net` with every parameter and buffer of `parent` that has the same name and shape
    (the layers `net` adds or reshapes keep their fresh initialisation)."""
    own = net.state_dict()
    net.load_state_dict(
        {k: v for k, v in parent.state_dict().items() if k in own and own[k].shape == v.shape},
        strict=False,
    )
    return net


def _resume(
    last: Path,
    size: tuple[int, int],
    net: NormalisedNet,
    opt: torch.optim.Optimizer,
    sched: torch.optim.lr_scheduler.LRScheduler,
    state: dict[str, Any],
) -> None:
    """Load the weights, optimiser, schedule and history of `last` (last.pt) into the run."""
    saved_net, saved = load_network(last)
    if tuple(saved["size"]) != size:
        raise TrainingError(f"{last} was trained on other image sizes than these data sets")
    if saved_net.batch_norm != net.batch_norm:
        flag = "--batch-norm" if saved_net.batch_norm else "--no-batch-norm"
        raise TrainingError(f"{last} was trained with {flag}: resume with the same option")
    net.load_state_dict(saved["model"])
    opt.load_state_dict(saved["optimizer"])
    sched.load_state_dict(saved["scheduler"])
    state.update({k: saved[k] for k in ("epoch", "best", "bad_epochs", "history", "parent")})


def _record(state: dict[str, Any], row: dict[str, Any], log_path: Path) -> bool:
    """Add an epoch's row to the history and log.jsonl; True when it is the best so far
    (validation accuracy, then loss)."""
    best = state["best"]
    improved = (row["val_accuracy"], -row["val_loss"]) > (best["val_accuracy"], -best["val_loss"])
    if improved:
        state["best"] = {k: row[k] for k in ("epoch", "val_accuracy", "val_loss")}
        state["bad_epochs"] = 0
    else:
        state["bad_epochs"] += 1
    state["epoch"] = row["epoch"]
    state["history"].append(row)
    with log_path.open("a") as fh:
        fh.write(json.dumps(row) + "\n")
    return improved


def _train_epoch(
    net: NormalisedNet,
    step: Callable[[torch.Tensor], torch.Tensor | tuple[torch.Tensor, torch.Tensor]],
    opt: torch.optim.Optimizer,
    train: Split,
    pool: np.ndarray,
    config: FitConfig,
    epoch: int,
    augmenter: Augmenter | None,
) -> dict[str, Any]:
    """One pass over `pool` (indices into the training split) in a seeded order -> the
    epoch's log row.

    `step` is `net`'s forward (compiled or not). Only full batches are used (the order
    changes every epoch), so a compiled step always sees one batch shape; a split smaller than
    a batch is one batch.
    """
    net.train()
    gen = torch.Generator().manual_seed(config.seed * 100_003 + epoch)
    rng = np.random.default_rng([config.seed, epoch])
    order = pool[torch.randperm(len(pool), generator=gen).numpy()]
    loss_sum, correct, seen = 0.0, 0, 0
    lr = opt.param_groups[0]["lr"]
    start = time.perf_counter()
    n_batches = max(1, len(order) // config.batch_size)
    device = next(net.parameters()).device
    bar = tqdm(
        range(0, n_batches * config.batch_size, config.batch_size),
        desc=f"epoch {epoch}/{config.epochs}",
        leave=False,
        disable=not config.progress,
    )
    for i in bar:
        idx = np.sort(order[i : i + config.batch_size])
        images, corners = train.images[idx], train.corners[idx]
        if augmenter is not None:
            x, corners = augmenter(images, train.blur[idx], rng, corners)
        else:
            x = to_input(images)
        x, y = x.to(device), torch.from_numpy(train.labels[idx]).to(device)
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=config.bf16):
            out = step(x)
        if isinstance(out, tuple):  # (log-probabilities, corners) of a net with a corner head
            out, predicted = out[0].float(), out[1].float()
            loss = F.nll_loss(out, y) + config.corner_weight * _corner_loss(
                predicted, corners, x.shape[3], x.shape[2], config.corner_beta, net.corner_order
            )
        else:
            out = out.float()
            loss = F.nll_loss(out, y)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        loss_sum += loss.item() * len(idx)
        correct += int((out.argmax(1) == y).sum())
        seen += len(idx)
        bar.set_postfix(loss=f"{loss_sum / seen:.3f}", acc=f"{correct / seen:.3f}")
    elapsed = time.perf_counter() - start
    return {
        "epoch": epoch,
        "lr": lr,
        "train_loss": loss_sum / seen,
        "train_accuracy": correct / seen,
        "seconds": elapsed,
        "ms_per_image": 1000.0 * elapsed / seen,
    }


def _corner_loss(
    predicted: torch.Tensor,
    corners: np.ndarray,
    w: int,
    h: int,
    beta: float = 0.1,
    order: str = "either",
) -> torch.Tensor:
    """Smooth L1 between predicted corners [B, 8] (image coordinates scaled to [-1, 1]) and
    the known ones (px, nan where unknown: class 0, photos without corners).

    The half turn is what only the squares' colour parity tells; the corners alone are a
    geometry task (where the board is, which sides are long, which edges are near). `order`
    says which of the two orders a half turn apart is the target: "either" takes the better
    of the two for each image (the class head learns the parity); "upper" takes the one whose
    corner 0 is higher in the image than corner 2, a rule a heat map can follow (with "either",
    a soft-argmax that cannot decide averages two opposite corners). "top" takes, of the four
    cyclic orders, the one whose corner 0 is the highest in the image: a rule for an object
    whose picture does not say which of its sides is the width (a near-square one), the
    quarter turn then read from the texture (`train.network.anynet.AnyCornerNet.observe`).
    """
    known = torch.from_numpy(np.isfinite(corners).all(axis=1)).to(predicted.device)
    if not bool(known.any()):
        return predicted.sum() * 0.0
    scale = np.tile([2.0 / w, 2.0 / h], 4).astype(np.float32)
    target = torch.from_numpy(np.nan_to_num(corners) * scale - 1.0).to(predicted.device)[known]
    turned = torch.roll(target, shifts=4, dims=1)  # corners 2, 3, 0, 1
    pred = predicted[known]
    if order == "top":  # the cyclic order (of four) whose corner 0 is the highest in the image
        rolls = torch.stack([torch.roll(target, shifts=2 * k, dims=1) for k in range(4)], 1)
        first = rolls[:, :, 1].argmin(1)  # [M]: the roll with the smallest v of corner 0
        chosen = rolls[torch.arange(len(first), device=rolls.device), first]
        return F.smooth_l1_loss(pred, chosen, beta=beta)
    if order == "upper":
        upper = (target[:, 1] <= target[:, 5])[:, None]
        return F.smooth_l1_loss(pred, torch.where(upper, target, turned), beta=beta)
    losses = [
        F.smooth_l1_loss(pred, t, beta=beta, reduction="none").mean(dim=1) for t in (target, turned)
    ]
    return torch.minimum(*losses).mean()


def _provenance(parent: dict[str, Any], path: Path | None) -> dict[str, Any]:
    """What a fine-tuned model inherits: the parent's data, config and best epoch."""
    return {
        "checkpoint": str(path),
        "data": parent.get("data", []),
        "config": parent.get("config", {}),
        "best": parent.get("best", {}),
        "parent": parent.get("parent"),
    }
