"""What every pose network shares: input normalisation inside the module, and a conv block.

Input of every network: float32 [N, 3, H, W], RGB in [0, 1] (what
`service.core.preprocess.to_network_input` makes). `train.network.model` builds the networks
by architecture name; `ConvNet`, `CornerNet` (the corner networks) and the SPEC `PoseNet`
derive from `NormalisedNet`.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


class NormalisedNet(nn.Module):
    """Base of the pose networks: input normalisation, then `features`, then `classifier`.

    `mean` and `std` (3 values, RGB, in [0, 1] units) are buffers: set them from the training
    set with `set_normalisation`, they travel with the state dict and the ONNX graph.
    Subclasses set `size` (W, H), `batch_norm`, `features` and `classifier`.
    """

    size: tuple[int, int]
    batch_norm: bool
    features: nn.Module
    classifier: nn.Module
    #: where a network has a corner head, the order `fit._corner_loss` matches it in
    corner_order: str
    mean: torch.Tensor  # buffer [1, 3, 1, 1]
    std: torch.Tensor  # buffer [1, 3, 1, 1]

    def __init__(self) -> None:
        super().__init__()
        self.register_buffer("mean", torch.full((1, 3, 1, 1), 0.5))
        self.register_buffer("std", torch.full((1, 3, 1, 1), 0.25))

    def set_normalisation(self, mean: torch.Tensor, std: torch.Tensor) -> None:
        """Store per-channel mean and std (3,) of the training images (RGB, [0, 1] units)."""
        self.mean.copy_(torch.as_tensor(mean, dtype=torch.float32).reshape(1, 3, 1, 1))
        self.std.copy_(
            torch.as_tensor(std, dtype=torch.float32).clamp_min(1e-3).reshape(1, 3, 1, 1)
        )

    def logits(self, x: torch.Tensor) -> torch.Tensor:
        """RGB [N, 3, H, W] in [0, 1] -> unnormalised scores [N, 9]."""
        return self.classifier(self.features((x - self.mean) / self.std))

    def forward(self, x: torch.Tensor) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """RGB [N, 3, H, W] in [0, 1] -> log-probabilities [N, 9] (a network with a corner head
        adds its corners in training mode)."""
        return F.log_softmax(self.logits(x), dim=1)


def conv_block(cin: int, cout: int, k: int = 3, stride: int = 1) -> nn.Sequential:
    """Convolution (k x k, `stride`, same padding, no bias), batch norm, ReLU: [N, cin, H, W]
    -> [N, cout, H / stride, W / stride]."""
    return nn.Sequential(
        nn.Conv2d(cin, cout, k, stride, k // 2, bias=False),
        nn.BatchNorm2d(cout),
        nn.ReLU(inplace=True),
    )
