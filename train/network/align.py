"""Sub-pixel object corners: Gauss-Newton alignment of the object's texture to the image
(the chessboard's checker pattern, or any profile's texture through `train.network.pattern`).

The heat-map corners of `train.network.corners` are a few pixels off (median 2.3-3 px on
real photos at 160x120), and a camera near a region boundary needs better. Starting from
them, `TextureAlign` moves the four corners until the image, sampled through the corners'
homography at P points of the board, matches the blurred checker pattern up to a gain and an
offset (variable projection: both are solved in closed form at every step). The gain's sign
is free, so the half turn (which inverts the pattern of a 10 x 7 board) aligns as well as the
true order; the parity is read afterwards. A texture's half turn is no inversion: it is
aligned in both orders and the better kept (`TextureAlign.forward`). Every step is plain
tensor algebra (the 8x8 normal equations are solved by 8 steps of conjugate gradients,
`solve_spd`), so it exports to ONNX.

    image    grey [N, 1, H, W] in [0, 1], Gaussian-blurred (`blur_px`), and its x / y gradients
    points   P (s, t) in the board's unit square, `inset` squares in from its edges (the
             margin around the squares differs from board to board); template T [P]: the
             checker (+1 white, -1 black, square (0, 0) black) blurred by `sigma_sq` squares
    step     J [N, 8, P] = image gradient . d(u, v)/d(corners) (finite differences of the
             homography), r = g - a T - b; (J J' + damping diag) d = -J r, |d| <= max_step px
    guard    an image keeps the aligned corners where they moved at most `max_move` px and
             raised |corr(g, T)|; otherwise its corners come back unchanged
    lens     given a `Lens`, a ninth parameter: the radial distortion k1 of the camera. The
             corners are then where the image shows them (distorted), the homography maps
             the unit square onto them undistorted (`Lens.undistort`) and the points it
             projects are distorted again (`Lens.distort`), so the bend of the board's
             lines in the image tells k1; a normal prior around the lens's k1 (sd
             `radial_sd`, weighed against the fit's residual variance) holds it where the
             image says little, and where the pattern correlates at most `k1_min_corr` at
             the start (a small or blurred board) k1 is not fitted at all
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from train.network.pattern import Pattern


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


def project_uv(H: torch.Tensor, st: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Homographies [..., 3, 3] and points [P, 2] -> image coordinates u, v [..., P]."""
    p = H[..., :, :2] @ st.T + H[..., :, 2:]  # [..., 3, P]
    w = torch.where(p[..., 2, :].abs() < 1e-6, torch.full_like(p[..., 2, :], 1e-6), p[..., 2, :])
    return p[..., 0, :] / w, p[..., 1, :] / w


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


class Lens(NamedTuple):
    """One radial coefficient k1 about a principal point, in an image's pixels. Point (u, v)
    px has normalised coordinates x = ((u, v) - centre) * scale (square pixels over the focal
    length); an image point x_d is undistorted to x_u = x_d / (1 + k1 |x_d|^2) (the map the
    pose uses, `CornerNet.undistorted`), and `distort` is its exact inverse. Tensors are
    per image [N, ...]; coordinates u, v [N, ...] and k1 broadcastable to them. The maps work
    on u and v apart: onnxruntime is slow on broadcasts over a last axis of 2."""

    centre: torch.Tensor  # [N, 2] px: the principal point
    scale: torch.Tensor  # [N, 2] px -> normalised coordinates along u and v
    k1: torch.Tensor  # [N] the prior: where a fit starts and what it is drawn to

    def _radial(
        self, u: torch.Tensor, v: torch.Tensor, factor: Callable[[torch.Tensor], torch.Tensor]
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """u, v [N, ...] px -> the points moved about the centre by `factor(|x|^2)`."""
        shape = (u.shape[0],) + (1,) * (u.dim() - 1)
        cu, cv = self.centre[:, 0].reshape(shape), self.centre[:, 1].reshape(shape)
        x = (u - cu) * self.scale[:, 0].reshape(shape)
        y = (v - cv) * self.scale[:, 1].reshape(shape)
        f = factor(x * x + y * y)
        return cu + (u - cu) * f, cv + (v - cv) * f

    def distort_uv(
        self, u: torch.Tensor, v: torch.Tensor, k1: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Undistorted u, v [N, ...] px -> where the image shows them: x_d = x_u 2 / (1 +
        sqrt(1 - 4 k1 |x_u|^2)), the root of |x_u| = |x_d| / (1 + k1 |x_d|^2) that is |x_u|
        near the centre (clamped where a pincushion lens has none)."""
        return self._radial(u, v, lambda r2: 2 / (1 + (1 - 4 * k1 * r2).clamp_min(0.0).sqrt()))

    def undistort_uv(
        self, u: torch.Tensor, v: torch.Tensor, k1: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Image u, v [N, ...] px -> undistorted, x_d / (1 + k1 |x_d|^2)."""
        return self._radial(u, v, lambda r2: 1 / (1 + k1 * r2))

    def distort(self, p: torch.Tensor, k1: torch.Tensor) -> torch.Tensor:
        """Undistorted points [N, ..., 2] px (k1 broadcastable to [N, ...]) -> image points."""
        return torch.stack(self.distort_uv(p[..., 0], p[..., 1], k1), -1)

    def undistort(self, p: torch.Tensor, k1: torch.Tensor) -> torch.Tensor:
        """Image points [N, ..., 2] px (k1 broadcastable to [N, ...]) -> undistorted."""
        return torch.stack(self.undistort_uv(p[..., 0], p[..., 1], k1), -1)


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


class TextureAlign(nn.Module):
    """The alignment above for images of `size` (W, H) px and a board of `squares` (along x,
    y), `per_square` points per square and axis; `steps` Gauss-Newton steps (0: corners
    returned unchanged). With a `Lens`, k1 is fitted too (prior sd `radial_sd`, within
    `k1_range`, at most `max_k1_step` per step). With a `pattern` that is not the checker
    (`train.network.pattern`), its cells take the squares' place and the template is its
    texture blurred by `sigma_sq` cells."""

    # buffers
    st: torch.Tensor  # [P, 2] the points in the unit square
    template: torch.Tensor  # [P] the blurred texture there
    blur: torch.Tensor  # the Gaussian kernel of `blur_px`
    px_to_unit: torch.Tensor  # [2]
    basis: torch.Tensor  # [8, 4, 2]
    k1_axis: torch.Tensor  # [9]

    def __init__(
        self,
        size: tuple[int, int],
        squares: tuple[int, int] = (10, 7),
        pattern: Pattern | None = None,
        per_square: int = 4,
        inset: float = 0.25,
        sigma_sq: float = 0.2,
        blur_px: float = 1.0,
        steps: int = 6,
        max_step: float = 1.0,
        max_move: float = 8.0,
        damping: float = 1e-2,
        radial_sd: float = 0.1,
        k1_range: tuple[float, float] = (-1.2, 0.3),
        max_k1_step: float = 0.1,
        k1_min_corr: float = 0.3,
    ) -> None:
        super().__init__()
        self.steps, self.max_step, self.max_move, self.damping = steps, max_step, max_move, damping
        self.radial_sd, self.k1_range, self.max_k1_step = radial_sd, k1_range, max_k1_step
        self.k1_min_corr = k1_min_corr
        texture = pattern if pattern is not None and not pattern.checker else None
        self.textured = texture is not None
        if texture is not None:
            squares = texture.cells
        axes = []
        for n in squares:
            k = round((n - 2 * inset) * per_square)
            axes.append(inset + (np.arange(k) + 0.5) * (n - 2 * inset) / k)  # squares
        u, v = np.meshgrid(*axes, indexing="xy")
        st = np.stack([u.ravel() / squares[0], v.ravel() / squares[1]], 1)
        if texture is not None:
            template = texture.sample(st, blur_cells=sigma_sq)
        else:
            template = -_blurred_wave(u.ravel(), sigma_sq) * _blurred_wave(v.ravel(), sigma_sq)
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
        # the k1 entry of the 9 parameters (its prior's place in the normal equations)
        self.register_buffer("k1_axis", torch.eye(9)[8], persistent=False)

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

    def _points(
        self, q: torch.Tensor, lens: Lens | None, k1: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Corners [N, 4, 2] (and k1 [N]) -> the board's points in the image [N, P, 2] and
        the derivatives of their u and v [N, 8 or 9, P] by the 8 corner coordinates (and k1),
        by finite differences."""
        n, eps, eps_k1 = q.shape[0], 0.05, 0.01
        # the corners, then each of their 8 coordinates moved by eps: [N, 9, 4, 2]
        qe = torch.cat([q[:, None], q[:, None] + eps * self.basis[None]], 1)
        if lens is None:
            u, v = project_uv(square_homography(qe.reshape(-1, 4, 2)), self.st)
            u, v = u.reshape(n, 9, -1), v.reshape(n, 9, -1)
            steps = torch.full((8,), eps).to(q)
        else:  # ... and k1 moved by eps_k1: [N, 10, 4, 2], k1 per set [N, 10, 1]
            qe = torch.cat([qe, q[:, None]], 1)
            ke = torch.cat([k1[:, None].expand(n, 9), k1[:, None] + eps_k1], 1)[:, :, None]
            u, v = project_uv(square_homography(lens.undistort(qe, ke).reshape(-1, 4, 2)), self.st)
            u, v = lens.distort_uv(u.reshape(n, 10, -1), v.reshape(n, 10, -1), ke)
            steps = torch.cat([torch.full((8,), eps), torch.full((1,), eps_k1)]).to(q)
        du = (u[:, 1:] - u[:, :1]) / steps[None, :, None]
        dv = (v[:, 1:] - v[:, :1]) / steps[None, :, None]
        return torch.stack([u[:, 0], v[:, 0]], -1), du, dv

    def _fit(
        self, image: torch.Tensor, q: torch.Tensor, lens: Lens | None, k1: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Image [N, 3, H, W] (grey, gradients), corners [N, 4, 2] (and k1 [N] with a `lens`)
        -> the image values minus the fitted template r [N, P], the projected Jacobian J
        [N, 8 or 9, P], corr(g, T) [N], the in-image mask [N, P]."""
        h, w = image.shape[2], image.shape[3]
        uv, du, dv = self._points(q, lens, k1)
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
        J = gu[:, None] * du + gv[:, None] * dv  # [N, 8 or 9, P]
        Jc = (J - (J * m[:, None]).sum(2, keepdim=True) / count[:, None]) * m[:, None]
        Jp = Jc - (Jc * tc[:, None]).sum(2, keepdim=True) / tt[:, None] * tc[:, None]
        gg = (gc * gc).sum(1) + 1e-6 * count[:, 0]  # a flat image correlates with nothing
        corr = (tc * gc).sum(1) / (tt[:, 0] * gg).sqrt()
        return r, Jp, corr, m

    def forward(
        self, x: torch.Tensor, q: torch.Tensor, lens: Lens | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """RGB [N, 3, H, W] in [0, 1], corners [N, 4, 2] px (either half-turn order) and the
        camera's `lens` (None: no distortion) -> aligned corners [N, 4, 2] px (same order),
        corr(image, checker) [N] at them (> 0: the order is the true one) and the lens's k1
        [N] (the prior where the image kept its corners; 0 without a lens).

        The checker's half turn inverts it, which the free gain absorbs; a texture's does not
        (its template, half turned, matches nothing and the corners drift): a textured
        pattern is aligned in both orders and each image keeps the one whose correlation is
        the larger (positive: the true order), returned in the order it came in."""
        image = self._image(x)
        if not self.textured:
            return self._align(image, q, lens)
        kept, turned = self._align(image, q, lens), self._align(image, torch.roll(q, 2, 1), lens)
        pick = turned[1] > kept[1]
        return (
            torch.where(pick[:, None, None], torch.roll(turned[0], 2, 1), kept[0]),
            torch.where(pick, -turned[1], kept[1]),
            torch.where(pick, turned[2], kept[2]),
        )

    def _align(
        self, image: torch.Tensor, q: torch.Tensor, lens: Lens | None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """`forward` on the blurred grey image and its gradients [N, 3, H, W], the corners
        in the order given."""
        k0 = torch.zeros_like(q[:, 0, 0]) if lens is None else lens.k1 * torch.ones_like(q[:, 0, 0])
        corr0 = self._fit(image, q, None, k0)[2]
        # k1 is fitted only where the pattern is plain to start with; elsewhere (a blurred or
        # tiny board) the corners align without distortion and the lens keeps its prior
        fitted = (corr0.abs() > self.k1_min_corr).to(q.dtype)
        k1 = k0 * fitted
        start = q
        eye = torch.eye(8 if lens is None else 9, dtype=q.dtype, device=q.device)[None]
        for _ in range(self.steps):
            r, J, _, m = self._fit(image, q, lens, k1)
            if lens is not None:  # k1's column only where it is fitted
                J = J * (1 - (1 - fitted)[:, None] * self.k1_axis)[:, :, None]
            A = J @ J.transpose(1, 2)
            A = A + self.damping * A * eye + 1e-6 * eye
            b = (J * r[:, None]).sum(2)
            if lens is not None:  # the prior N(k0, radial_sd^2), weighed by the residual variance
                noise = (r * r).sum(1) / m.sum(1).clamp_min(1.0)
                weight = (fitted * noise / self.radial_sd**2)[:, None]
                A = A + weight[:, :, None] * self.k1_axis[:, None] * self.k1_axis
                b = b + weight * (k1 - k0)[:, None] * self.k1_axis
            d = -solve_spd(A, b)
            q = q + d[:, :8].clamp(-self.max_step, self.max_step).reshape(-1, 4, 2)
            if lens is not None:
                k1 = (k1 + d[:, 8].clamp(-self.max_k1_step, self.max_k1_step)).clamp(*self.k1_range)
        corr = self._fit(image, q, lens, k1)[2] if self.steps else corr0
        moved = (q - start).norm(dim=2).amax(1)
        keep = (moved <= self.max_move) & (corr.abs() > corr0.abs())
        return (
            torch.where(keep[:, None, None], q, start),
            torch.where(keep, corr, corr0),
            torch.where(keep & (fitted > 0), k1, k0),
        )
