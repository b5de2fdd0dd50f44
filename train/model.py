"""The pose-class CNN of SPEC section 8, with the input normalisation inside the module.

Input: float32 [N, 3, H, W], RGB in [0, 1] (what `service.preprocess.to_network_input` makes).
Output of `PoseNet.forward`: log-probabilities float32 [N, 9] (log-softmax).

    conv 5x5 3->64, tanh, L2 pool 4x4/4, conv 5x5 64->64, tanh, L2 pool 4x4/4,
    flatten (384 | 3072) -> linear -> tanh (128 | 1024) -> linear -> 9 -> log-softmax
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from service.regions import NUM_CLASSES

#: Supported input sizes (W, H) -> hidden width of the classifier (SPEC section 8 table).
HIDDEN_UNITS: dict[tuple[int, int], int] = {(80, 60): 128, (160, 120): 1024}

CONV_KERNEL = 5
POOL = 4
CHANNELS = 64


class L2Pool2d(nn.Module):
    """L2 pooling: sqrt of the sum of squares over each k x k window, stride k.

    Same values as `nn.LPPool2d(2, k)` for real inputs, written with ops that export to ONNX
    as Mul, AveragePool, Mul, Sqrt. [N, C, H, W] -> [N, C, H // k, W // k].
    """

    def __init__(self, kernel: int = POOL) -> None:
        super().__init__()
        self.kernel = kernel

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        k = self.kernel
        return torch.sqrt(F.avg_pool2d(x * x, k, k) * float(k * k))


def feature_shape(size: tuple[int, int]) -> tuple[int, int]:
    """(H, W) of the last pooled feature map for an input `size` = (W, H), e.g. 80x60 -> (2, 3)."""
    w, h = size
    for _ in range(2):
        w, h = (w - CONV_KERNEL + 1) // POOL, (h - CONV_KERNEL + 1) // POOL
    return h, w


def check_size(size: tuple[int, int]) -> tuple[int, int]:
    """Return `size` as (W, H) ints, or raise ValueError if the network is not defined for it."""
    size = (int(size[0]), int(size[1]))
    if size not in HIDDEN_UNITS:
        known = ", ".join(f"{w}x{h}" for w, h in HIDDEN_UNITS)
        raise ValueError(f"unsupported input size {size[0]}x{size[1]}; the network takes {known}")
    return size


class PoseNet(nn.Module):
    """SPEC network for an input `size` (W, H) of 80x60 or 160x120.

    `mean` and `std` (3 values, RGB, in [0, 1] units) are buffers: set them from the training
    set with `set_normalisation`, they travel with the state dict and the ONNX graph.
    """

    def __init__(self, size: tuple[int, int] = (80, 60)) -> None:
        super().__init__()
        self.size = check_size(size)
        fh, fw = feature_shape(self.size)
        hidden = HIDDEN_UNITS[self.size]
        self.register_buffer("mean", torch.full((1, 3, 1, 1), 0.5))
        self.register_buffer("std", torch.full((1, 3, 1, 1), 0.25))
        self.features = nn.Sequential(
            nn.Conv2d(3, CHANNELS, CONV_KERNEL),
            nn.Tanh(),
            L2Pool2d(POOL),
            nn.Conv2d(CHANNELS, CHANNELS, CONV_KERNEL),
            nn.Tanh(),
            L2Pool2d(POOL),
        )
        self.classifier = nn.Sequential(
            nn.Flatten(),
            nn.Linear(CHANNELS * fh * fw, hidden),
            nn.Tanh(),
            nn.Linear(hidden, NUM_CLASSES),
        )

    def set_normalisation(self, mean: torch.Tensor, std: torch.Tensor) -> None:
        """Store per-channel mean and std (3,) of the training images (RGB, [0, 1] units)."""
        self.mean.copy_(torch.as_tensor(mean, dtype=torch.float32).reshape(1, 3, 1, 1))
        self.std.copy_(
            torch.as_tensor(std, dtype=torch.float32).clamp_min(1e-3).reshape(1, 3, 1, 1)
        )

    def logits(self, x: torch.Tensor) -> torch.Tensor:
        """RGB [N, 3, H, W] in [0, 1] -> unnormalised scores [N, 9]."""
        return self.classifier(self.features((x - self.mean) / self.std))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """RGB [N, 3, H, W] in [0, 1] -> log-probabilities [N, 9]."""
        return F.log_softmax(self.logits(x), dim=1)


class Probabilities(nn.Module):
    """Wrap a PoseNet so it outputs probabilities [N, 9] (softmax): the exported graph."""

    def __init__(self, net: PoseNet) -> None:
        super().__init__()
        self.net = net

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        return F.softmax(self.net.logits(image), dim=1)


def channel_stats(images_u8: torch.Tensor, chunk: int = 512) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-channel mean and std (3,) in [0, 1] units of uint8 images [N, H, W, 3]."""
    total = torch.zeros(3, dtype=torch.float64)
    total_sq = torch.zeros(3, dtype=torch.float64)
    for start in range(0, len(images_u8), chunk):
        x = images_u8[start : start + chunk].reshape(-1, 3).to(torch.float64) / 255.0
        total += x.sum(0)
        total_sq += (x * x).sum(0)
    count = images_u8.numel() // 3
    mean = total / count
    std = (total_sq / count - mean * mean).clamp_min(0.0).sqrt()
    return mean.float(), std.float()
