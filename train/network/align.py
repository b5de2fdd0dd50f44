"""Sub-pixel board corners: Gauss-Newton alignment of the checker pattern to the image.

The heat-map corners of `train.network.keypoint` are a few pixels off (median 2.3-3 px on
real photos at 160x120), and a camera near a region boundary needs better. Starting from
them, `CheckerAlign` moves the four corners until the image, sampled through the corners'
homography at P points of the board, matches the blurred checker pattern up to a gain and an
offset (variable projection: both are solved in closed form at every step). The gain's sign
is free, so the half turn (which inverts the pattern of a 10 x 7 board) aligns as well as the
true order; the parity is read afterwards. Every step is plain tensor algebra (the 8x8 normal
equations are solved by 8 steps of conjugate gradients, `solve_spd`), so it exports to ONNX.

    image    grey [N, 1, H, W] in [0, 1], Gaussian-blurred (`blur_px`), and its x / y gradients
    points   P (s, t) in the board's unit square, `inset` squares in from its edges (the
             margin around the squares differs from board to board); template T [P]: the
             checker (+1 white, -1 black, square (0, 0) black) blurred by `sigma_sq` squares
    step     J [N, 8, P] = image gradient . d(u, v)/d(corners) (finite differences of the
             homography), r = g - a T - b; (J J' + damping diag) d = -J r, |d| <= max_step px
    guard    an image keeps the aligned corners where they moved at most `max_move` px and
             raised |corr(g, T)|; otherwise its corners come back unchanged
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn


def square_homography(q: torch.Tensor) -> torch.Tensor:
    """Corners [N, 4, 2] px -> [N, 3, 3] homography of the unit square (0,0), (1,0), (1,1),
    (0,1) onto them (Heckbert's closed form: exports to ONNX, no solver)."""
    x0, x1, x2, x3 = q[:, 0, 0], q[:, 1, 0], q[:, 2, 0], q[:, 3, 0]
    y0, y1, y2, y3 = q[:, 0, 1], q[:, 1, 1], q[:, 2, 1], q[:, 3, 1]
    dx1, dx2, dx3 = x1 - x2, x3 - x2, x0 - x1 + x2 - x3
    dy1, dy2, dy3 = y1 - y2, y3 - y2, y0 - y1 + y2 - y3
    den = dx1 * dy2 - dx2 * dy1
    den = torch.where(den.abs() < 1e-6, torch.full_like(den, 1e-6), den)
    g = (dx3 * dy2 - dx2 * dy3) / den
    h = (dx1 * dy3 - dx3 * dy1) / den
    one = torch.ones_like(g)
    rows = [
        torch.stack([x1 - x0 + g * x1, x3 - x0 + h * x3, x0], 1),
        torch.stack([y1 - y0 + g * y1, y3 - y0 + h * y3, y0], 1),
        torch.stack([g, h, one], 1),
    ]
    return torch.stack(rows, 1)


def project(H: torch.Tensor, st: torch.Tensor) -> torch.Tensor:
    """Homographies [..., 3, 3] and points [P, 2] -> image points [..., P, 2]."""
    p = H[..., :, :2] @ st.T + H[..., :, 2:]  # [..., 3, P]
    w = torch.where(p[..., 2, :].abs() < 1e-6, torch.full_like(p[..., 2, :], 1e-6), p[..., 2, :])
    return torch.stack([p[..., 0, :] / w, p[..., 1, :] / w], -1)


def solve_spd(A: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Solve A x = b for symmetric positive definite A [N, n, n], b [N, n] -> x [N, n]:
    n steps of conjugate gradients with a Jacobi preconditioner (exact in exact arithmetic;
    a few matrix products per step, no linear-algebra operator, so it exports to ONNX)."""
    inv_diag = 1.0 / torch.diagonal(A, dim1=1, dim2=2).clamp_min(1e-12)
    x = torch.zeros_like(b)
    r = b
    z = inv_diag * r
    p = z
    rz = (r * z).sum(1, keepdim=True)
    for _ in range(A.shape[-1]):
        Ap = (A @ p[:, :, None])[:, :, 0]
        alpha = rz / (p * Ap).sum(1, keepdim=True).clamp_min(1e-30)
        x = x + alpha * p
        r = r - alpha * Ap
        z = inv_diag * r
        rz_next = (r * z).sum(1, keepdim=True)
        p = z + rz_next / rz.clamp_min(1e-30) * p
        rz = rz_next
    return x


def _blurred_wave(u: np.ndarray, sigma: float) -> np.ndarray:
    """The square wave +1 on [0, 1), -1 on [1, 2), ... (squares) blurred by a Gaussian of
    `sigma` squares, at positions u [K] -> [K]."""
    offsets = np.linspace(-4 * sigma, 4 * sigma, 161)
    weights = np.exp(-0.5 * (offsets / max(sigma, 1e-6)) ** 2)
    wave = 1.0 - 2.0 * (np.floor(u[:, None] + offsets[None]) % 2)
    return (wave * weights).sum(1) / weights.sum()


def _gaussian_kernel(sigma: float) -> torch.Tensor:
    """Normalised 1-D Gaussian [2r + 1], r = ceil(2.5 sigma)."""
    r = max(1, math.ceil(2.5 * sigma))
    x = torch.arange(-r, r + 1, dtype=torch.float32)
    k = torch.exp(-0.5 * (x / sigma) ** 2)
    return k / k.sum()


class CheckerAlign(nn.Module):
    """The alignment above for images of `size` (W, H) px and a board of `squares` (along x,
    y), `per_square` points per square and axis; `steps` Gauss-Newton steps (0: corners
    returned unchanged)."""

    def __init__(
        self,
        size: tuple[int, int],
        squares: tuple[int, int] = (10, 7),
        per_square: int = 4,
        inset: float = 0.25,
        sigma_sq: float = 0.2,
        blur_px: float = 1.0,
        steps: int = 6,
        max_step: float = 1.0,
        max_move: float = 8.0,
        damping: float = 1e-2,
    ) -> None:
        super().__init__()
        self.steps, self.max_step, self.max_move, self.damping = steps, max_step, max_move, damping
        axes = []
        for n in squares:
            k = round((n - 2 * inset) * per_square)
            axes.append(inset + (np.arange(k) + 0.5) * (n - 2 * inset) / k)  # squares
        u, v = np.meshgrid(*axes, indexing="xy")
        template = -_blurred_wave(u.ravel(), sigma_sq) * _blurred_wave(v.ravel(), sigma_sq)
        st = np.stack([u.ravel() / squares[0], v.ravel() / squares[1]], 1)
        self.register_buffer("st", torch.tensor(st, dtype=torch.float32), persistent=False)
        self.register_buffer(
            "template", torch.tensor(template, dtype=torch.float32), persistent=False
        )
        self.register_buffer("blur", _gaussian_kernel(blur_px), persistent=False)
        self.register_buffer(
            "px_to_unit", torch.tensor([2.0 / size[0], 2.0 / size[1]]), persistent=False
        )
        # the 8 corner coordinates, one at a time: finite differences of the homography
        self.register_buffer("basis", torch.eye(8).reshape(8, 4, 2), persistent=False)

    def _image(self, x: torch.Tensor) -> torch.Tensor:
        """RGB [N, 3, H, W] in [0, 1] -> blurred grey, d/du, d/dv [N, 3, H, W]."""
        k = self.blur
        r = k.numel() // 2
        g = F.pad(x.mean(1, keepdim=True), (r, r, r, r), mode="replicate")
        g = F.conv2d(g, k.reshape(1, 1, 1, -1))
        g = F.conv2d(g, k.reshape(1, 1, -1, 1))
        p = F.pad(g, (1, 1, 1, 1), mode="replicate")
        gu = 0.5 * (p[:, :, 1:-1, 2:] - p[:, :, 1:-1, :-2])
        gv = 0.5 * (p[:, :, 2:, 1:-1] - p[:, :, :-2, 1:-1])
        return torch.cat([g, gu, gv], 1)

    def _fit(
        self, image: torch.Tensor, q: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Image [N, 3, H, W] (grey, gradients), corners [N, 4, 2] -> the image values minus
        the fitted template r [N, P], the projected Jacobian J [N, 8, P], corr(g, T) [N],
        the in-image mask [N, P]."""
        n, h, w = image.shape[0], image.shape[2], image.shape[3]
        eps = 0.05
        # the corners, then each of their 8 coordinates moved by eps: [N, 9, 4, 2]
        qe = torch.cat([q[:, None], q[:, None] + eps * self.basis[None]], 1)
        uve = project(square_homography(qe.reshape(-1, 4, 2)), self.st).reshape(n, 9, -1, 2)
        uv = uve[:, 0]  # [N, P, 2]
        duv = (uve[:, 1:] - uv[:, None]) / eps  # [N, 8, P, 2]
        grid = ((uv + 0.5) * self.px_to_unit - 1.0).clamp(-2.0, 2.0)[:, None]  # [N, 1, P, 2]
        sampled = F.grid_sample(image, grid, align_corners=False, padding_mode="border")[:, :, 0]
        g, gu, gv = sampled[:, 0], sampled[:, 1], sampled[:, 2]  # [N, P]
        inside = (uv[..., 0] >= 0) & (uv[..., 0] <= w - 1) & (uv[..., 1] >= 0)
        m = (inside & (uv[..., 1] <= h - 1)).to(g.dtype)
        count = m.sum(1, keepdim=True).clamp_min(1.0)
        tc = (self.template[None] - (m * self.template).sum(1, keepdim=True) / count) * m
        gc = (g - (m * g).sum(1, keepdim=True) / count) * m
        tt = (tc * tc).sum(1, keepdim=True).clamp_min(1e-9)
        gain = (tc * gc).sum(1, keepdim=True) / tt
        r = gc - gain * tc
        J = gu[:, None] * duv[..., 0] + gv[:, None] * duv[..., 1]  # [N, 8, P]
        Jc = (J - (J * m[:, None]).sum(2, keepdim=True) / count[:, None]) * m[:, None]
        Jp = Jc - (Jc * tc[:, None]).sum(2, keepdim=True) / tt[:, None] * tc[:, None]
        gg = (gc * gc).sum(1) + 1e-6 * count[:, 0]  # a flat image correlates with nothing
        corr = (tc * gc).sum(1) / (tt[:, 0] * gg).sqrt()
        return r, Jp, corr, m

    def forward(self, x: torch.Tensor, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """RGB [N, 3, H, W] in [0, 1] and corners [N, 4, 2] px (either half-turn order) ->
        aligned corners [N, 4, 2] px (same order) and corr(image, checker) [N] at them
        (> 0: the order is the true one)."""
        image = self._image(x)
        r, J, corr0, _ = self._fit(image, q)
        start = q
        eye = torch.eye(8, dtype=q.dtype)[None]
        for step in range(self.steps):
            if step:
                r, J, _, _ = self._fit(image, q)
            A = J @ J.transpose(1, 2)
            A = A + self.damping * A * eye + 1e-6 * eye
            d = -solve_spd(A, (J * r[:, None]).sum(2))
            q = q + d.clamp(-self.max_step, self.max_step).reshape(-1, 4, 2)
        corr = self._fit(image, q)[2] if self.steps else corr0
        moved = (q - start).norm(dim=2).amax(1)
        keep = (moved <= self.max_move) & (corr.abs() > corr0.abs())
        return (
            torch.where(keep[:, None, None], q, start),
            torch.where(keep, corr, corr0),
        )
