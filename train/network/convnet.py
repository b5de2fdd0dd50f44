"""A stronger small pose CNN than the SPEC network, for the same input and output.

Input: float32 [N, 3, H, W], RGB in [0, 1], H x W = 60 x 80 or 120 x 160; normalisation
inside the module (`train.network.model.NormalisedNet`). Output of `forward`:
log-probabilities [N, 9].

    stem   conv 5x5, 3 -> 24, stride 1 (80x60) or 2 (160x120): a 80x60 x 24 map either way
    block  conv 3x3 24 -> 32                          80x60
    pool   max 2x2                                    40x30
    block  conv 3x3 32 -> 48, conv 3x3 48 -> 48       40x30
    pool   max 2x2                                    20x15
    block  conv 3x3 48 -> 96, conv 3x3 96 -> 96       20x15
    pool   max 2x2                                    10x7
    block  conv 3x3 96 -> 128                         10x7
    head   adaptive average pool 3x4 -> 1536 -> dropout -> linear 128 -> ReLU -> linear 9
           (and, in training, linear 128 -> 8: the object's four corners in the image)

Every conv is followed by batch norm and ReLU. Max pooling keeps the sign of the features
(the square-colour parity that tells a half turn apart is a sign cue, which the SPEC network's
L2 pooling discards); the 3x4 pooled head keeps where in the image a feature is, which the
x/y side needs, at a fixed size for both inputs. Batch norm stays in the exported graph
(onnxruntime folds it into the convolutions when it loads the model).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from service.core.inputs import SIZES, size_index
from service.core.regions import NUM_CLASSES
from train.network.base import NormalisedNet, conv_block

HEAD_GRID = (3, 4)  # (H, W) of the pooled map the classifier reads
FEATURE_HW = (7, 10)  # (H, W) of the last convolution's map, for both input sizes


def _pool_matrix(n_in: int, n_out: int) -> torch.Tensor:
    """[n_out, n_in] averaging weights of adaptive average pooling along one axis (PyTorch's
    windows: start floor(i * n_in / n_out), end ceil((i + 1) * n_in / n_out))."""
    m = torch.zeros(n_out, n_in)
    for i in range(n_out):
        a, b = (i * n_in) // n_out, -(-((i + 1) * n_in) // n_out)
        m[i, a:b] = 1.0 / (b - a)
    return m


class GridPool(nn.Module):
    """Adaptive average pooling of a fixed [N, C, H, W] map to [N, C, h, w], as two matrix
    products, so that it exports to ONNX whatever the sizes (ONNX has no adaptive pooling
    when h, w do not divide H, W). Same values as `nn.AdaptiveAvgPool2d((h, w))`."""

    rows: torch.Tensor  # buffer [h, H]
    cols: torch.Tensor  # buffer [w, W]

    def __init__(self, in_hw: tuple[int, int], out_hw: tuple[int, int]) -> None:
        super().__init__()
        self.register_buffer("rows", _pool_matrix(in_hw[0], out_hw[0]), persistent=False)
        self.register_buffer("cols", _pool_matrix(in_hw[1], out_hw[1]), persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.matmul(torch.matmul(self.rows, x), self.cols.t())


class ConvNet(NormalisedNet):
    """The network above for an input `size` (W, H) of 80x60 or 160x120."""

    corner_order = "either"  # `fit._corner_loss`: the better of the two half-turn orders

    def __init__(self, size: tuple[int, int] = SIZES[2], dropout: float = 0.2) -> None:
        super().__init__()
        size = (int(size[0]), int(size[1]))
        if size not in SIZES.values():
            known = ", ".join(f"{w}x{h}" for w, h in SIZES.values())
            raise ValueError(
                f"unsupported input size {size[0]}x{size[1]}; the network takes {known}"
            )
        self.size = size
        self.batch_norm = True
        stride = size_index(size)  # 1 at 80x60, 2 at 160x120: the same maps after it
        self.features = nn.Sequential(
            conv_block(3, 24, 5, stride),
            conv_block(24, 32),
            nn.MaxPool2d(2),
            conv_block(32, 48),
            conv_block(48, 48),
            nn.MaxPool2d(2),
            conv_block(48, 96),
            conv_block(96, 96),
            nn.MaxPool2d(2),
            conv_block(96, 128),
            GridPool(FEATURE_HW, HEAD_GRID),
        )
        self.hidden = nn.Sequential(
            nn.Flatten(),
            nn.Dropout(dropout),
            nn.Linear(128 * HEAD_GRID[0] * HEAD_GRID[1], 128),
            nn.ReLU(inplace=True),
        )
        self.classifier = nn.Linear(128, NUM_CLASSES)
        self.corners = nn.Linear(128, 8)

    def logits(self, x: torch.Tensor) -> torch.Tensor:
        """RGB [N, 3, H, W] in [0, 1] -> unnormalised scores [N, 9]."""
        return self.classifier(self.hidden(self.features((x - self.mean) / self.std)))

    def forward(self, x: torch.Tensor) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """RGB [N, 3, H, W] in [0, 1] -> log-probabilities [N, 9]; in training mode also the
        predicted object corners [N, 8] ((u, v) x 4, image coordinates scaled to [-1, 1]), an
        auxiliary target (as the training-mode auxiliary outputs of torchvision's Inception)."""
        if not self.training:
            return super().forward(x)
        h = self.hidden(self.features((x - self.mean) / self.std))
        return F.log_softmax(self.classifier(h), dim=1), self.corners(h)
