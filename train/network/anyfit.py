"""Training of the generic corner network (`corners-any`, `train.network.anynet`) on renders
of many textures drawn on the fly (`train.synth.stream`), and what makes it one object's.

`train_generic(config)` runs `config.steps` steps of `config.batch_size` renders, each image
its own object: corner loss (as `fit`: smooth L1 on the corners up to a half turn, "upper"
order) plus the presence logit's binary cross-entropy. It starts from a trained `CornerNet`
(`init`: a shipped corner graph, read back by `train.network.onnx_weights`) or from scratch.
Every `checkpoint_minutes` (and at the end) it writes into `config.out`:

* `last.pt`   weights, optimiser, schedule, step, history: running it again continues;
* `best.pt`   the weights with the best validation score so far (what `object new` takes);
* `log.jsonl` one JSON line per validation (step, loss, corner error px, presence accuracy,
  images / s).

The checkpoints are those of `train.network.fit` (`load_network` reads them, `fit(init=...)`
fine-tunes them, `export` exports them). Batches are drawn from generators seeded by
(seed, step), so a resumed run renders what an uninterrupted one would.

`object_network` gives a checkpoint of it to one object: the generic weights with the object's
picture and pattern, and its presence threshold measured on its renders
(`presence_threshold`).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from service.core.inputs import SIZES
from train.network.anynet import AnyCornerNet, grown_from, texture_tensor
from train.network.export import repo_path
from train.network.fit import (
    CHECKPOINT_FORMAT,
    Augmenter,
    _corner_loss,
    _save,
    load_network,
    to_input,
    training_device,
)
from train.network.onnx_weights import corner_net_from_onnx, recalibrate_batch_norm
from train.synth.stream import Batch, TextureStream

#: What the cards of the generic network's models say it was trained on.
DATA_NOTE = (
    "renders of the texture bank (train/synth/textures.py: procedural shapes, text, stripes, "
    "noise, markers, checkers, and crops of the shipped photographs), one object per image, "
    "drawn on the fly (train/synth/stream.py); not the held-back test textures, the book "
    "or the ChArUco board"
)


@dataclass
class GenericConfig:
    """A run of `train_generic` (module doc); `threads` 0: torch's default."""

    out: Path
    steps: int = 6000
    batch_size: int = 24
    lr: float = 5e-4
    seed: int = 0
    threads: int = 1
    device: str = "auto"
    init: Path | None = None
    checkpoint_minutes: float = 5.0
    eval_every: int = 100
    val_count: int = 192
    corner_weight: float = 5.0
    corner_beta: float = 0.01

    def to_json(self) -> dict[str, Any]:
        """JSON-ready copy (paths as strings), with what `export`'s card reads."""
        out = asdict(self) | {"out": str(self.out), "init": self.init and str(self.init)}
        return out | {"epochs": None, "optimizer": "adam", "schedule": "cosine", "augment": True}


def textures_of(batch: Batch) -> tuple[torch.Tensor, torch.Tensor]:
    """A batch's objects -> pictures [N, 3, 64, 64] in [0, 1] and aspects [N] (h / w cm)."""
    pictures = torch.stack([texture_tensor(t.rgb) for t in batch.textures])
    aspect = torch.tensor([t.height_cm / t.width_cm for t in batch.textures], dtype=torch.float32)
    return pictures, aspect


def step_loss(
    net: AnyCornerNet,
    x: torch.Tensor,
    corners: np.ndarray,
    textures: tuple[torch.Tensor, torch.Tensor],
    config: GenericConfig,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Input [N, 3, H, W] in [0, 1], the corners [N, 8] px (nan: absent) and the objects'
    pictures -> (loss, predicted corners [N, 4, 2] px, presence logits [N])."""
    pictures, aspect = (t.to(x.device) for t in textures)
    heat, offset, presence = net.encode_with((x - net.mean) / net.std, pictures, aspect)
    q = net._soft_argmax(heat, offset)
    w, h = x.shape[3], x.shape[2]
    predicted = (q * net.px_to_unit - 1.0).reshape(-1, 8)
    present = torch.from_numpy(np.isfinite(corners).all(1).astype(np.float32)).to(x.device)
    loss = config.corner_weight * _corner_loss(
        predicted, corners, w, h, config.corner_beta, net.corner_order
    ) + F.binary_cross_entropy_with_logits(presence, present)
    return loss, q, presence


def corner_error(q: torch.Tensor, corners: np.ndarray) -> np.ndarray:
    """Mean distance px [M] of predicted corners [N, 4, 2] to the known ones [N, 8] (nan:
    absent, left out), the best of the four cyclic orders (the quarter and half turns are
    read from the texture afterwards, `AnyCornerNet.observe`)."""
    known = np.isfinite(corners).all(1)
    truth = torch.from_numpy(corners[known].reshape(-1, 4, 2))
    pred = q.detach().cpu()[torch.from_numpy(known)]
    errors = torch.stack([(pred - torch.roll(truth, k, 1)).norm(dim=2).mean(1) for k in range(4)])
    return errors.amin(0).numpy()


@torch.no_grad()
def validate(
    net: AnyCornerNet, val: Batch, config: GenericConfig, device: torch.device
) -> dict[str, float]:
    """Loss, median corner error px and presence accuracy of `net` on a fixed batch."""
    net.eval()
    losses, errors, right = [], [], 0
    for i in range(0, len(val.classes), 64):
        part = Batch(
            val.images[i : i + 64], val.corners[i : i + 64], val.classes[i : i + 64],
            val.textures[i : i + 64],
        )  # fmt: skip
        x = to_input(part.images).to(device)
        loss, q, presence = step_loss(net, x, part.corners, textures_of(part), config)
        losses.append(float(loss) * len(part.classes))
        errors.append(corner_error(q, part.corners))
        right += int(((presence.cpu() > 0).numpy() == (part.classes > 0)).sum())
    n = len(val.classes)
    err = np.concatenate(errors)
    return {
        "val_loss": sum(losses) / n,
        "val_corner_px": float(np.median(err)),
        "val_corners_within_2px": float((err < 2).mean()),
        "val_presence": right / n,
    }


def _initial(config: GenericConfig, stream: TextureStream) -> tuple[AnyCornerNet, dict[str, Any]]:
    """The network to start from (module doc) and its parent record (empty: from scratch)."""
    net = AnyCornerNet(SIZES[2])
    if config.init is None:
        first = stream.batch(256, np.random.default_rng([config.seed, 1]))
        mean = torch.from_numpy(first.images.reshape(-1, 3).mean(0) / 255.0)
        std = torch.from_numpy(first.images.reshape(-1, 3).std(0) / 255.0)
        net.set_normalisation(mean.float(), std.float())
        return net, {}
    if config.init.suffix == ".onnx":
        parent, record = corner_net_from_onnx(config.init)
        first = stream.batch(256, np.random.default_rng([config.seed, 1]))
        recalibrate_batch_norm(parent, to_input(first.images))
    else:
        parent, saved = load_network(config.init)
        record = {"checkpoint": str(config.init), "steps": saved.get("epoch")}
        record["parent"] = lineage(saved.get("parent"))
    return grown_from(parent, net), record  # type: ignore[arg-type]


def lineage(parent: dict[str, Any] | None) -> dict[str, Any] | None:
    """A checkpoint's parent record without weights: where each ancestor came from (ONNX
    graph or checkpoint) and its steps, oldest last."""
    if not parent:
        return None
    keep: dict[str, Any] = {k: parent[k] for k in ("steps", "epoch") if k in parent}
    keep |= {k: repo_path(Path(parent[k])) for k in ("onnx", "checkpoint") if k in parent}
    return keep | {"parent": lineage(parent.get("parent"))}


def rebuild_command(config: dict[str, Any], parent: dict[str, Any] | None) -> str:
    """The command line that runs a generic training run again, from its config
    (`GenericConfig.to_json`) and what it started from (`lineage`: the checkpoint or graph
    of the run it continued; None: from scratch)."""
    start = parent and (parent.get("checkpoint") or parent.get("onnx"))
    return (
        f"python scripts/train_any.py {config['out']} --steps {config['steps']} "
        f"--batch-size {config['batch_size']} --lr {config['lr']} "
        f"--threads {config['threads']} --init {start or 'none'}"
    )


def _payload(net: AnyCornerNet, config: GenericConfig, state: dict[str, Any]) -> dict[str, Any]:
    """A checkpoint in `train.network.fit`'s format (`load_network` reads it)."""
    settings = config.to_json()
    rebuild = [rebuild_command(settings, lineage(state.get("parent")))]
    return {
        "format": CHECKPOINT_FORMAT,
        "size": list(net.size),
        "batch_norm": True,
        "arch": "corners-any",
        "config": settings | {"extra": {"rebuild": rebuild}},
        "data": [{"path": "texture bank (on the fly)", "note": DATA_NOTE, "split": "train",
                  "count": state["step"] * config.batch_size}],
        "profile": {},
        "epoch": state["step"],
        "best": state["best"],
        "history": state["history"],
        "parent": state.get("parent"),
        "model": net.state_dict(),
    }  # fmt: skip


def train_generic(
    config: GenericConfig, say: Any = print, stream: TextureStream | None = None
) -> dict[str, Any]:
    """Train (or continue) the generic network as `config` says (module doc) on `stream`
    (default: the texture bank on the shipped backgrounds) -> the state (step, best,
    history)."""
    if config.threads:
        torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    config.out.mkdir(parents=True, exist_ok=True)
    stream = stream if stream is not None else TextureStream(SIZES[2])
    device = training_device(config.device)
    last = config.out / "last.pt"
    saved = torch.load(last, map_location="cpu", weights_only=False) if last.is_file() else None
    if saved is not None:
        net, parent = AnyCornerNet(SIZES[2]), saved.get("parent") or {}
        net.load_state_dict(saved["model"])
    else:
        net, parent = _initial(config, stream)
    net = net.to(device)
    opt = torch.optim.Adam(net.parameters(), lr=config.lr)
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda s: 0.5 * (1 + math.cos(math.pi * min(s, config.steps) / config.steps))
    )
    state: dict[str, Any] = {"step": 0, "best": {"val_loss": math.inf}, "history": []}
    if saved is not None:
        opt.load_state_dict(saved["optimizer"])
        sched.load_state_dict(saved["scheduler"])
        state |= {"step": saved["epoch"], "best": saved["best"], "history": saved["history"]}
    state["parent"] = parent
    val = stream.batch(config.val_count, np.random.default_rng([config.seed, 2]))
    _loop(net, opt, sched, stream, val, config, state, device, say)
    return state


def _loop(
    net: AnyCornerNet,
    opt: torch.optim.Optimizer,
    sched: torch.optim.lr_scheduler.LRScheduler,
    stream: TextureStream,
    val: Batch,
    config: GenericConfig,
    state: dict[str, Any],
    device: torch.device,
    say: Any,
) -> None:
    """The training steps from `state["step"]` on, with validation and checkpoints."""
    augmenter = Augmenter(SIZES[2], p_squash=0.25)
    saved_at, start, seen, loss_sum = time.monotonic(), time.monotonic(), 0, 0.0
    while state["step"] < config.steps:
        net.train()
        step = state["step"] + 1
        rng = np.random.default_rng([config.seed, 3, step])
        batch = stream.batch(config.batch_size, rng)
        x, corners = augmenter(batch.images, np.zeros(len(batch.classes), int), rng, batch.corners)
        loss, _, _ = step_loss(net, x.to(device), corners, textures_of(batch), config)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        state["step"], seen, loss_sum = step, seen + config.batch_size, loss_sum + loss.item()
        done = step == config.steps
        if step % config.eval_every == 0 or done:
            rate = seen / (time.monotonic() - start)
            row = {"step": step, "train_loss": loss_sum / (seen / config.batch_size),
                   "images_per_s": rate, "lr": sched.get_last_lr()[0]}  # fmt: skip
            row |= validate(net, val, config, device)
            state["history"].append(row)
            with (config.out / "log.jsonl").open("a") as fh:
                fh.write(json.dumps(row) + "\n")
            say(json.dumps({k: round(v, 4) if isinstance(v, float) else v for k, v in row.items()}))
            if row["val_loss"] < state["best"]["val_loss"]:
                state["best"] = {"step": step, "val_loss": row["val_loss"],
                                 "val_corner_px": row["val_corner_px"]}  # fmt: skip
                _save(config.out / "best.pt", _payload(net, config, state))
            start, seen, loss_sum = time.monotonic(), 0, 0.0
        if done or time.monotonic() - saved_at > 60 * config.checkpoint_minutes:
            payload = _payload(net, config, state)
            payload |= {"optimizer": opt.state_dict(), "scheduler": sched.state_dict()}
            _save(config.out / "last.pt", payload)
            saved_at = time.monotonic()
