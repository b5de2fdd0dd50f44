"""A shipped corner network read back from its ONNX graph, to fine-tune it when its
training checkpoint is not at hand
(`planar-pose train --init models/chessboard-corners-160x120.onnx`).

The export folds each batch norm into the convolution before it (W' = W g / sqrt(v + eps),
b' = beta - m g / sqrt(v + eps)) and names the convolution after its torch module
(`/down1/down1.0/down1.0.0/Conv` is `down1.0.0`, its batch norm `down1.0.1`); the other
parameters and buffers keep their state-dict names with the prefix `net.`. A folded pair
comes back as the convolution W' and a batch norm that adds b' (weight 1, running mean 0,
running variance 1 - eps): the graph's outputs in eval mode. `recalibrate_batch_norm` then
brings each pair back to the form training expects (unit-variance convolution outputs,
the batch norm's statistics those of training images), so that training mode starts where
the graph is.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import torch
from torch import nn

from train.network.base import NormalisedNet
from train.network.corners import ZERO_IF_ABSENT
from train.network.model import build_network

PREFIX = "net."


class OnnxWeightsError(ValueError):
    """An ONNX file that is not a corner network exported by planar-pose."""


def _graph(path: Path) -> tuple[dict[str, torch.Tensor], dict[str, list[str]], dict[str, Any]]:
    """ONNX file -> (initialisers by name, the weight and bias initialisers of each Conv node
    by the node's module path, the model card)."""
    import onnx
    from onnx import numpy_helper

    try:
        model = onnx.load(str(path))
    except Exception as exc:  # onnx raises DecodeError and others for a file that is not ONNX
        raise OnnxWeightsError(f"{path} is not a readable ONNX model: {exc}") from exc
    cards = [p.value for p in model.metadata_props if p.key == "model_card"]
    if not cards:
        raise OnnxWeightsError(f"{path} has no model card: not a planar-pose export")
    inits = {
        i.name: torch.from_numpy(numpy_helper.to_array(i).copy()) for i in model.graph.initializer
    }
    convs = {
        node.name.rsplit("/", 2)[-2]: list(node.input[1:])
        for node in model.graph.node
        if node.op_type == "Conv" and len(node.input) == 3 and node.input[1] in inits
    }
    return inits, convs, json.loads(cards[0])


def corner_net_from_onnx(
    path: Path, profile: dict[str, Any] | None = None
) -> tuple[NormalisedNet, dict[str, Any]]:
    """A planar-pose corner ONNX graph -> (the network with its weights, batch norms as
    the module doc says, and a parent record like a checkpoint's: data, config and best
    epoch from the model card); its geometry and camera model those of `profile` (a card's
    profile entry; None: the graph's own card's)."""
    path = Path(path)
    if not path.is_file():
        raise OnnxWeightsError(f"ONNX model not found: {path}")
    inits, convs, card = _graph(path)
    if "heat" not in convs or "input" not in card:
        raise OnnxWeightsError(f"{path} is not a planar-pose corner network")
    arch = "corners" if "up0.0" in convs else "corners-coarse"
    size = (int(card["input"][0]), int(card["input"][1]))
    net = build_network(arch, size, profile=card.get("profile") if profile is None else profile)
    state = net.state_dict()
    read = set()
    for name, module in net.named_modules():
        if not isinstance(module, nn.Conv2d) or name not in convs:
            continue
        weight, bias = (inits[n] for n in convs[name])
        state[f"{name}.weight"] = weight
        read.add(f"{name}.weight")
        norm = name[:-1] + "1"  # `convnet._conv`: Conv (bias-free) + BatchNorm + ReLU
        if f"{norm}.running_var" in state:
            batch_norm = net.get_submodule(norm)
            assert isinstance(batch_norm, nn.BatchNorm2d)
            eps = batch_norm.eps
            ones = torch.ones(weight.shape[0])
            state |= {f"{norm}.weight": ones, f"{norm}.bias": bias}
            state |= {f"{norm}.running_mean": 0 * ones, f"{norm}.running_var": (1 - eps) * ones}
            read |= {f"{norm}.{k}" for k in ("weight", "bias", "running_mean", "running_var")}
        else:
            state[f"{name}.bias"] = bias
            read.add(f"{name}.bias")
    for key in state:
        if PREFIX + key in inits:
            state[key] = inits[PREFIX + key].reshape(state[key].shape)
            read.add(key)
    unread = [k for k, _ in net.named_parameters() if k not in read and k not in ZERO_IF_ABSENT]
    if unread:
        raise OnnxWeightsError(f"{path}: no weights in the graph for {', '.join(unread)}")
    net.load_state_dict(state)
    training = card.get("training", {})
    parent = {
        "onnx": str(path),
        "data": training.get("data", []),
        "config": training.get("config", {}),
        "best": training.get("best_epoch", {}),
        "parent": training.get("fine_tuned_from"),
    }
    return net, parent


@torch.no_grad()
def recalibrate_batch_norm(net: NormalisedNet, x: torch.Tensor) -> None:
    """Give each convolution + batch norm pair (`convnet._conv`) the statistics of the
    images x [N, 3, H, W] (RGB in [0, 1]) without changing the pair's eval-mode output.

    The convolution's output channels are scaled to unit variance on x (a folded weight is
    the original times g / sqrt(v + eps), of any scale; Adam's steps are of a fixed size,
    so the scale is the weight's learning rate: unit variance is where a freshly initialised
    pair starts) and the batch norm's running mean and variance are those of that output,
    its weight and bias set so that its affine map per channel (y = a z + c) stays."""
    pairs = [
        (m[0], m[1])
        for m in net.modules()
        if isinstance(m, nn.Sequential)
        and len(m) > 1
        and isinstance(m[0], nn.Conv2d)
        and isinstance(m[1], nn.BatchNorm2d)
    ]
    seen: dict[nn.Module, torch.Tensor] = {}
    hooks = [
        norm.register_forward_pre_hook(lambda m, args: seen.__setitem__(m, args[0]))
        for _, norm in pairs
    ]
    net.eval()
    try:
        net.logits(x)
    finally:
        for hook in hooks:
            hook.remove()
    for conv, norm in pairs:
        z = seen[norm]
        mean, var = z.mean((0, 2, 3)), z.var((0, 2, 3), unbiased=False)
        old_mean, old_var = norm.running_mean, norm.running_var
        assert old_mean is not None and old_var is not None  # nn.BatchNorm2d's default
        a = norm.weight / (old_var + norm.eps).sqrt()
        c = norm.bias - old_mean * a
        sd = torch.sqrt(var + norm.eps)
        conv.weight.div_(sd[:, None, None, None])
        a, mean, var = a * sd, mean / sd, var / sd**2
        norm.weight.copy_(a * (var + norm.eps).sqrt())
        norm.bias.copy_(c + a * mean)
        old_mean.copy_(mean)
        old_var.copy_(var)
