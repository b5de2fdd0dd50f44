"""A grid-keypoint pose network: the keypoint network reading all the board's square corners.

The class follows from the board's homography, and four corners found to a pixel or two are
not enough for it: with the true camera, 1 px of corner noise costs a real photo's class a
sixth of the time. This network locates all 11 x 8 corners of the 10 x 7 squares (the four
outer ones among them) and fits the homography to the 88 points by least squares, each point
weighted by how sharp its heat map is, so that the errors of single points average out:

    points    the U-Net of `train.network.keypoint`, 88 heat maps [N, 88, 30, 40] at stride
              4, soft-argmax -> points [N, 88, 2] px and their spread [N, 88] px^2
    fit       homography of the unit square onto the points: weighted linear least squares
              (DLT with h33 = 1, Hartley-normalised), solved by Gauss-Jordan elimination of
              the 8 x 8 normal equations, unrolled (exports to ONNX)
    rest      as the keypoint network: parity, camera centre, presence, class probabilities

Points are indexed k = j * 11 + i for the corner at unit-square (s, t) = (i / 10, j / 7); a
half turn reverses the order. Training sets the target of every point from the labelled four
corners (`point_targets`); points whose target lies outside the image are not trained.
Input: float32 [N, 3, 120, 160], RGB in [0, 1]. Output of `forward`: log-probabilities [N, 9].
"""

from __future__ import annotations

import math

import torch
from torch import nn

from train.network.keypoint import SQUARES, STRIDE, KeypointNet

POINTS = (SQUARES[0] + 1, SQUARES[1] + 1)  # square corners along the board's width, height
UNIT_SCALE = math.sqrt(2.0) / 0.5  # unit-square points centred on (0.5, 0.5) -> mean norm ~ sqrt 2


def solve_spd(M: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Solutions x [N, n] of M x = b for symmetric positive definite M [N, n, n], b [N, n]:
    Gauss-Jordan elimination without pivoting (safe for SPD), unrolled over the n columns."""
    n = M.shape[1]
    aug = torch.cat([M, b[:, :, None]], 2)  # [N, n, n + 1]
    eye = torch.eye(n, dtype=M.dtype, device=M.device)
    for k in range(n):
        pivot_row = aug[:, k, :] / aug[:, k, k : k + 1]  # [N, n + 1]
        aug = aug - aug[:, :, k : k + 1] * pivot_row[:, None, :]
        aug = aug + eye[k][None, :, None] * pivot_row[:, None, :]
    return aug[:, :, n]


def fit_homography(st: torch.Tensor, uv: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """Weighted least-squares homography [N, 3, 3] mapping unit-square points st [K, 2] onto
    image points uv [N, K, 2] px, point weights [N, K] >= 0 (at least 4 points not on a line
    with weight > 0). Linear DLT with h33 = 1 on Hartley-normalised points."""
    n, k = uv.shape[:2]
    centre = (uv * weight[..., None]).sum(1) / weight.sum(1, keepdim=True)  # [N, 2]
    spread = ((uv - centre[:, None]).norm(dim=2) * weight).sum(1) / weight.sum(1)
    scale = math.sqrt(2.0) / spread.clamp_min(1e-3)  # [N]
    un = (uv - centre[:, None]) * scale[:, None, None]  # [N, K, 2]
    sn = ((st - 0.5) * UNIT_SCALE)[None].expand(n, k, 2)
    x, y, u, v = sn[..., 0], sn[..., 1], un[..., 0], un[..., 1]
    one, zero = torch.ones_like(x), torch.zeros_like(x)
    rows_u = torch.stack([x, y, one, zero, zero, zero, -u * x, -u * y], 2)  # [N, K, 8]
    rows_v = torch.stack([zero, zero, zero, x, y, one, -v * x, -v * y], 2)
    A = torch.cat([rows_u, rows_v], 1) * torch.cat([weight, weight], 1)[..., None].sqrt()
    r = torch.cat([u, v], 1) * torch.cat([weight, weight], 1).sqrt()  # [N, 2K]
    M = A.transpose(1, 2) @ A + 1e-6 * torch.eye(8, dtype=uv.dtype, device=uv.device)
    h = solve_spd(M, (A.transpose(1, 2) @ r[..., None])[..., 0])  # [N, 8]
    Hn = torch.cat([h, torch.ones_like(h[:, :1])], 1).reshape(n, 3, 3)
    # H = T_uv^-1 Hn T_st. T_st = [[a, 0, -a/2], [0, a, -a/2], [0, 0, 1]] (a = UNIT_SCALE)
    # normalises the unit square; T_uv^-1 = [[1/s, 0, cu], [0, 1/s, cv], [0, 0, 1]] undoes
    # the image normalisation
    a = UNIT_SCALE
    Hn = torch.stack(
        [a * Hn[:, :, 0], a * Hn[:, :, 1], Hn[:, :, 2] - a / 2 * (Hn[:, :, 0] + Hn[:, :, 1])], 2
    )
    top = Hn[:, :2, :] / scale[:, None, None] + centre[:, :, None] * Hn[:, 2:, :]
    return torch.cat([top, Hn[:, 2:, :]], 1)


class GridNet(KeypointNet):
    """The network above; arguments as `KeypointNet`'s."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self.heat = nn.Conv2d(self.heat.in_channels, POINTS[0] * POINTS[1], 1)
        i, j = torch.meshgrid(torch.arange(POINTS[0]), torch.arange(POINTS[1]), indexing="xy")
        st = torch.stack([i / SQUARES[0], j / SQUARES[1]], -1).reshape(-1, 2).float()
        self.register_buffer("point_st", st)
        # a point's weight is 1 / (spread + floor), the floor a heat-map pixel's variance
        # (u and v of a uniform STRIDE-px square), px^2
        self.register_buffer("spread_floor", torch.tensor(STRIDE**2 / 6.0))

    def _board(self, heat: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Heat-map logits [N, 88, h, w] -> the points [N, 88, 2] px and the least-squares
        homography [N, 3, 3] of the unit square onto them."""
        q, var = self._soft_argmax(heat)
        weight = 1.0 / (var.clamp_min(0.0) + self.spread_floor)
        return q, fit_homography(self.point_st, q, weight)

    def point_targets(self, corners: torch.Tensor) -> torch.Tensor:
        """The four corners [B, 8] ((u, v) x 4, any image coordinates) -> all points [B, 176]
        in the same coordinates, through the homography of the unit square onto the corners."""
        H = self.homography(corners.reshape(-1, 4, 2))
        st1 = torch.cat([self.point_st, torch.ones_like(self.point_st[:, :1])], 1)
        p = torch.einsum("nij,kj->nki", H, st1)
        return (p[..., :2] / p[..., 2:]).reshape(len(corners), -1)

    def grow_from(self, parent: KeypointNet) -> None:
        """Start from a trained four-corner `KeypointNet`: all its weights and buffers, and its
        four corner heat maps for the four outer points (the inner points' maps start fresh)."""
        state = {k: v for k, v in parent.state_dict().items() if not k.startswith("heat.")}
        self.load_state_dict(state, strict=False)
        last = POINTS[0] * POINTS[1] - 1
        outer = [0, POINTS[0] - 1, last, last - (POINTS[0] - 1)]  # corners 0..3
        with torch.no_grad():
            self.heat.weight[outer] = parent.heat.weight
            self.heat.bias[outer] = parent.heat.bias
