"""The pose-class CNN of SPEC section 8, with the input normalisation inside the module.

Input: float32 [N, 3, H, W], RGB in [0, 1] (what `service.core.preprocess.to_network_input` makes).
Output of `PoseNet.forward`: log-probabilities float32 [N, 9] (log-softmax).

    conv 5x5 3->64, tanh, L2 pool 4x4/4, conv 5x5 64->64, tanh, L2 pool 4x4/4,
    flatten (384 | 3072) -> linear -> tanh (128 | 1024) -> linear -> 9 -> log-softmax

Training may use `PoseNet(size, batch_norm=True)`: batch normalisation before each tanh and
after each pooling. It only reparameterises the same function class (the L2-pooled maps are
all positive with a large common mode, which makes plain SGD slow and unstable); in eval mode
every one of those layers is a per-channel affine map, and `fold_batch_norm` merges them into
the neighbouring convolution / linear layers, giving exactly the SPEC network above.
"""

from __future__ import annotations

from typing import Any, get_args

import torch
import torch.nn.functional as F
from torch import nn

from service.core.inputs import SIZES
from service.core.profile import focal_prior_of
from service.core.regions import NUM_CLASSES
from train.network.anynet import AnyCornerNet
from train.network.base import NormalisedNet
from train.network.config import CORNER_ARCHS, Arch, canonical_arch
from train.network.convnet import ConvNet
from train.network.corners import CornerNet
from train.network.pattern import pattern_of, texture_of

#: Supported input sizes (W, H) -> hidden width of the classifier (SPEC section 8 table).
HIDDEN_UNITS: dict[tuple[int, int], int] = {SIZES[1]: 128, SIZES[2]: 1024}

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


class PoseNet(NormalisedNet):
    """SPEC network for an input `size` (W, H) of 80x60 or 160x120."""

    features: nn.Sequential
    classifier: nn.Sequential

    def __init__(self, size: tuple[int, int] = SIZES[1], batch_norm: bool = False) -> None:
        super().__init__()
        self.size = check_size(size)
        self.batch_norm = batch_norm
        fh, fw = feature_shape(self.size)
        hidden = HIDDEN_UNITS[self.size]

        def norm(n: int, one_d: bool = False) -> nn.Module:
            if not batch_norm:
                return nn.Identity()
            return nn.BatchNorm1d(n) if one_d else nn.BatchNorm2d(n)

        # Fixed indices (Identity without batch_norm): conv 0 and 5, linear 1 and 4.
        self.features = nn.Sequential(
            nn.Conv2d(3, CHANNELS, CONV_KERNEL),
            norm(CHANNELS),
            nn.Tanh(),
            L2Pool2d(POOL),
            norm(CHANNELS),
            nn.Conv2d(CHANNELS, CHANNELS, CONV_KERNEL),
            norm(CHANNELS),
            nn.Tanh(),
            L2Pool2d(POOL),
            norm(CHANNELS),
        )
        self.classifier = nn.Sequential(
            nn.Flatten(),
            nn.Linear(CHANNELS * fh * fw, hidden),
            norm(hidden, one_d=True),
            nn.Tanh(),
            nn.Linear(hidden, NUM_CLASSES),
        )


def _bn_affine(bn: nn.Module, n: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Eval-mode batch norm as y = a * x + c per channel -> (a, c), each (n,); identity if none."""
    if not isinstance(bn, nn.BatchNorm1d | nn.BatchNorm2d):
        return torch.ones(n), torch.zeros(n)
    mean, var = bn.running_mean, bn.running_var
    assert mean is not None and var is not None, "the networks' norms track running statistics"
    a = bn.weight / torch.sqrt(var + bn.eps)
    return a, bn.bias - a * mean


@torch.no_grad()
def fold_batch_norm(net: PoseNet) -> PoseNet:
    """The plain SPEC network computing what `net` computes in eval mode (a copy).

    A norm after a layer scales its output rows; a norm after a pooling is an affine map of
    the next layer's input (exact: the convolutions have no padding). A `net` without batch
    norm is copied unchanged.
    """
    plain = PoseNet(net.size)
    plain.mean.copy_(net.mean)
    plain.std.copy_(net.std)
    f, c = net.features, net.classifier
    # (layer, norm of its input or None, norm of its output) in the training network.
    layers: list[tuple[nn.Module, nn.Module | None, nn.Module]] = [
        (f[0], None, f[1]),
        (f[5], f[4], f[6]),
        (c[1], f[9], c[2]),
    ]
    targets = [plain.features[0], plain.features[5], plain.classifier[1]]
    for (layer, before, after), target in zip(layers, targets, strict=True):
        # the fixed indices above are biased convolutions / linears
        assert isinstance(layer, nn.Conv2d | nn.Linear) and layer.bias is not None
        assert isinstance(target, nn.Conv2d | nn.Linear) and target.bias is not None
        weight, bias = layer.weight.clone(), layer.bias.clone()
        if before is not None:
            a_in, c_in = _bn_affine(before, CHANNELS)
            per_input = weight.shape[1] // CHANNELS  # spatial positions per channel (flatten)
            a_in, c_in = a_in.repeat_interleave(per_input), c_in.repeat_interleave(per_input)
            if weight.dim() == 4:  # conv: input channels are dim 1, summed over the kernel
                bias += (weight.sum((2, 3)) * c_in).sum(1)
                weight *= a_in.reshape(1, -1, 1, 1)
            else:
                bias += weight @ c_in
                weight *= a_in.reshape(1, -1)
        a_out, c_out = _bn_affine(after, weight.shape[0])
        target.weight.copy_(weight * a_out.reshape(-1, *([1] * (weight.dim() - 1))))
        target.bias.copy_(bias * a_out + c_out)
    plain.classifier[4].load_state_dict(c[4].state_dict())
    return plain


#: Architectures: "spec" (`PoseNet`, SPEC section 8), "convnet" (`train.network.convnet`),
#: "corners-coarse" and "corners" (`train.network.corners`, heat maps at stride 4 / 2).
ARCHS: tuple[str, ...] = get_args(Arch)


def build_network(
    arch: str, size: tuple[int, int], batch_norm: bool = True, profile: dict[str, Any] | None = None
) -> NormalisedNet:
    """A fresh network of architecture `arch` for input `size` (W, H); `profile` (a data set
    manifest's profile: width_cm, height_cm, z_split_cm, focal_prior) sets the geometry, the
    focal-length prior and the texture (`train.network.pattern`) of the corner network
    (default: the chessboard's)."""
    if arch == "spec":
        return PoseNet(size, batch_norm=batch_norm)
    if arch == "convnet":
        return ConvNet(size)
    arch = canonical_arch(arch)
    if arch == "corners-any":
        return any_corner_net(size, profile)
    if arch in CORNER_ARCHS:
        stride = 2 if arch == "corners" else 4
        if not profile:
            return CornerNet(size, stride=stride)
        w_cm, h_cm = float(profile["width_cm"]), float(profile["height_cm"])
        return CornerNet(
            size,
            board_cm=(w_cm, h_cm),
            z_split_cm=float(profile["z_split_cm"]),
            focal_scale=focal_prior_of(profile),
            stride=stride,
            pattern=pattern_of(profile),
        )
    raise ValueError(f"unknown architecture {arch!r}; known: {', '.join(ARCHS)}")


def any_corner_net(size: tuple[int, int], profile: dict[str, Any] | None) -> AnyCornerNet:
    """The generic corner network (`train.network.anynet`) for the object of a data set
    manifest's `profile` (its size, region split, focal prior, texture and picture); None: the
    generic network with no object (the chessboard's geometry, a grey placeholder picture)."""
    if not profile:
        return AnyCornerNet(size)
    return AnyCornerNet(
        size,
        board_cm=(float(profile["width_cm"]), float(profile["height_cm"])),
        z_split_cm=float(profile["z_split_cm"]),
        focal_scale=focal_prior_of(profile),
        pattern=pattern_of(profile),
        texture=texture_of(profile),
    )


def arch_of(net: NormalisedNet) -> str:
    """The architecture name of a network built by `build_network`."""
    if isinstance(net, PoseNet):
        return "spec"
    if isinstance(net, ConvNet):
        return "convnet"
    if isinstance(net, AnyCornerNet):
        return "corners-any"
    return "corners" if getattr(net, "stride", 4) == 2 else "corners-coarse"


def export_form(net: NormalisedNet) -> NormalisedNet:
    """The network as exported, in eval mode: the SPEC network with its batch norm folded
    away (`fold_batch_norm`); other architectures unchanged."""
    return (fold_batch_norm(net) if isinstance(net, PoseNet) else net).eval()


def takes_pixel_aspect(net: NormalisedNet) -> bool:
    """Whether the network reads the pixel aspect of its input (the corner networks, whose
    class comes from the geometry of the board's corners)."""
    return hasattr(net, "answer")


def log_probabilities(
    net: NormalisedNet, x: torch.Tensor, pixel_aspect: torch.Tensor | None = None
) -> torch.Tensor:
    """Eval-mode log-probabilities [N, 9] of RGB [N, 3, H, W] in [0, 1]; the pixel aspect
    [N] (`service.core.preprocess.NetworkFrame.pixel_aspect`) goes to the networks that read
    it."""
    if takes_pixel_aspect(net):
        out: torch.Tensor = net(x, pixel_aspect)
        return out
    return net(x)


class Probabilities(nn.Module):
    """Wrap a pose network so it outputs probabilities [N, 9] (softmax) and, for a network
    with an `answer` (the corner network, which also takes the pixel aspect [N], the
    view [N, 3] and the known focal length [N]), its corners [N, 4, 2] px, pattern
    evidence [N] and corners without the lens's distortion [N, 4, 2] px: the exported
    graph."""

    def __init__(self, net: NormalisedNet) -> None:
        super().__init__()
        self.net = net

    def forward(
        self,
        image: torch.Tensor,
        pixel_aspect: torch.Tensor | None = None,
        view: torch.Tensor | None = None,
        focal: torch.Tensor | None = None,
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        answer = getattr(self.net, "answer", None)
        if answer is None:
            return F.softmax(self.net.logits(image), dim=1)
        log_p, corners, pattern, undistorted = answer(image, pixel_aspect, view, focal)
        return F.softmax(log_p, dim=1), corners, pattern, undistorted


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
