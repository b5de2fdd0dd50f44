"""The corner network (architectures `corners`, `corners-coarse`): the class comes from geometry,
not from a classifier.

The x/y side of the camera is a small perspective effect (a camera 5 cm off the board's axis
at 60 cm makes the near edge of the board about 1 px longer than the far one at 160x120), and
it has to be read after the board's in-plane orientation, which only the colour parity of
the squares tells. A classifier head does not learn that composition (it stayed at chance
on the x/y side, `docs/results.md`). This network finds the board's four corners instead,
and the class follows from them as the SPEC labels define it:

    corners   U-Net: encoder 160x120 -> 10x7 (ReLU + batch norm + max pooling), decoder back
              to 40x30 (or, `stride` 2, to 80x60 with the stem's features); 4 heat maps
              [N, 4, 30, 40] (or [N, 4, 60, 80]) and each cell's offset of each corner from
              the cell [N, 8, ...] px, soft-argmax of cell + offset -> corners [N, 4, 2] px:
              the offsets carry a corner beyond the frame (a board the frame cuts), where
              the heat map alone cannot reach
    align     the corners moved to sub-pixel accuracy by aligning the checker pattern to the
              image, and the lens's radial distortion k1 fitted with them where the pattern
              is plain (`train.network.align`: Gauss-Newton, no weights; not in training,
              where the class loss does not depend on them)
    pose      homography of the board rectangle onto the corners undistorted with that k1
              (the prior `RADIAL_PRIOR` where it was not fitted; closed form), pose with a
              pinhole camera (principal point at the image centre, pixels of the given
              aspect, the focal length that makes
              the board's axes orthogonal, drawn to a prior where the view says little,
              shorter where the fitted k1 is a stronger barrel than a lens's own,
              or the caller's own where it knows it: `focal`), camera centre c [N, 3] cm
              in the object frame
    parity    the image sampled at the 70 square centres through the homography, correlated
              with the checker pattern: its sign says whether the corner order is the true one
              or a half turn (which maps c to (-cx, -cy, cz)); also with the board rendered
              through the homography and blurred by the SPEC's heaviest blur (and by that blur
              on a tile enlarged 2x, the zoom pass's), which inverts the pattern of squares
              under about 5 px: the template that correlates most answers
    presence  a logit from the pooled encoder: object in view or not (class 0), or'ed with the
              correlation of the image with the checker pattern at the aligned corners
    classes   P(cx >= 0), P(cy >= 0), P(cz < z_split) as normal CDFs of c with a spread that
              grows with the distance, mixed over the two half-turn readings by the parity
              confidence, times P(present); class 0 gets 1 - P(present)

The heat-map channels are trained on the corners up to a half turn: of the two orders, the
target is the one whose corner 0 is the upper end of the 0-2 diagonal (`fit._corner_loss`);
parity is not learned. Input: float32 [N, 3, 120, 160], RGB in [0, 1], and optionally the
pixel aspect [N] (`camera_centre`; 1 where not given). Output of `forward`: log-probabilities
[N, 9]; `answer` also gives the aligned corners in the object's order and the checker
pattern's evidence of the board (the exported graph's outputs `corners` and `pattern`), and
takes where the input lies in the camera's frame (`view`: a crop of the frame, enlarged, is
answered with the frame's camera; the service's zoom pass, `service/pipeline/zoom.py`) and the
camera's focal length where the caller knows it (`focal`, 0: unknown).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from service.core.blur import KERNELS, gaussian_taps
from service.core.geometry import intrinsics
from service.core.inputs import SIZES
from service.core.pose import FOCAL_BOUNDS, FOCAL_PRIOR
from service.core.profile import DEFAULT_PROFILE, load_profile
from service.core.regions import QUADRANT_SIGNS, Z_SPLIT_CM
from train.network.align import Lens, TextureAlign, square_homography
from train.network.base import NormalisedNet, conv_block
from train.network.pattern import CHECKER_SQUARES, Pattern

SIZE = SIZES[2]
# The focal length (`CornerNet.focal_length`): Zhang's constraints with a prior. The prior
# and the bounds (`service.core.pose`, which the service's pose shares) are x the SPEC
# camera's focal length, the weight in the units of the normalised constraints; chosen on the
# corpus's val and train sources with the SPEC-camera and long-lens renders as second checks
# (docs/camera_model.md, docs/decisions.md).
FOCAL_PRIOR_WEIGHT = 0.01
# The prior of the radial distortion k1 the corner alignment fits per image and the corners
# are undistorted with before the pose (`lens`, `undistorted`), in normalised coordinates of
# the prior camera: the corpus's calibrated train and val cameras range from -0.55 to +0.22
# (median -0.29, mean -0.16), the renders draw it from -0.45..0.05; chosen on the val
# sources (docs/camera_model.md)
RADIAL_PRIOR = -0.2
# The strongest barrel distortion taken for a lens's own (k1 in normalised coordinates of its
# own focal length f; the corpus's calibrated cameras reach -0.55). The fitted k1 is in the
# prior camera's coordinates, k1 (f0 / f)^2, so one beyond this limit says the focal length is
# shorter than the prior f0: the prior becomes f0 sqrt(BARREL_LIMIT / k1) (`prior_focal`).
# Chosen on the val sources, with the train sources as the second check (docs/camera_model.md)
BARREL_LIMIT = -0.45
# The blurs the parity step also reads the pattern under (`parity`): SPEC blur level 3 at
# 160x120 (k = 10 taps, sd 5 px, anchored as the data sets' `service.core.blur`), whose nearly
# box-shaped kernel inverts the checker of squares under about 5 px, on the input and on a
# tile enlarged 2x (each tap spread over 2 px)
PARITY_BLUR = KERNELS[2][3]
_ANCHOR = (PARITY_BLUR[0] - 1) // 2  # cv2's filter anchor: the tap on the output pixel
PARITY_PAD = (2 * _ANCHOR, 2 * (PARITY_BLUR[0] - 1 - _ANCHOR) + 1)  # taps before / after it, 2x
STRIDES = (4, 2)  # input pixels per heat-map pixel: 40x30 maps, or 80x60 ("corners")
SQUARES = CHECKER_SQUARES  # squares of the board along its width (x) and height (y)
# |corr(image, checker)| at the aligned corners above which the board is taken as present
# whatever the presence logit says: real photos without a board stay under 0.16 (the
# corpus's train and val sources), with one mostly over 0.6
PATTERN_CORR, PATTERN_SLOPE = 0.4, 20.0
# what the networks before 3.9.0 lack, the corner offsets: zero where a checkpoint or a graph
# has none (`CornerNet._load_from_state_dict`, `onnx_weights.corner_net_from_onnx`)
ZERO_IF_ABSENT = ("offset.weight", "offset.bias")


def _parity_blurs() -> torch.Tensor:
    """The 1-D kernels of `PARITY_BLUR` on the input and on a tile enlarged 2x, [2, L] on the
    same taps: tap j is the pixel j - `PARITY_PAD`[0] away (`_parity_blur_matrices`)."""
    k, sd = PARITY_BLUR
    g = torch.tensor(gaussian_taps(k, sd), dtype=torch.float32)
    out = torch.zeros(2, PARITY_PAD[0] + PARITY_PAD[1] + 1)
    start = PARITY_PAD[0] - _ANCHOR
    out[0, start : start + k] = g
    out[1, start - _ANCHOR : start - _ANCHOR + 2 * k] = g.repeat_interleave(2) / 2
    return out


def _parity_blur_matrices(n: int) -> torch.Tensor:
    """The `_parity_blurs` along an axis of n pixels, borders replicated as the data sets'
    blur does, as matrices [2, n, n]: blurred pixel i = sum over j of M[:, i, j] x pixel j
    (one small matrix product per axis, far cheaper than a 1-channel convolution on a CPU)."""
    taps = _parity_blurs()
    offsets = torch.arange(taps.shape[1]) - PARITY_PAD[0]
    source = (torch.arange(n)[:, None] + offsets).clamp(0, n - 1)  # [n, L]: the pixel of each tap
    out = torch.zeros(2, n, n)
    return out.scatter_add_(2, source.expand(2, n, -1), taps[:, None, :].expand(2, n, -1))


class Observation(NamedTuple):
    """What one image [N, 3, H, W] says before the camera model (`CornerNet.observe`)."""

    corners: torch.Tensor  # [N, 4, 2] input px, aligned, in the heat maps' order
    parity: torch.Tensor  # [N] in [-1, 1], > 0 when that order is the object's
    present: torch.Tensor  # [N] P(present): the presence logit or'ed with `pattern`
    pattern: torch.Tensor  # [N] P(present) from the checker pattern at the corners alone
    k1: torch.Tensor  # [N] the lens's radial distortion the alignment fitted (`lens`)


def _block(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(conv_block(cin, cout), conv_block(cout, cout))


class CornerNet(NormalisedNet):
    """The network above for input `size` (W, H) = 160x120 and a board of `board_cm`
    (width, height; default: the default profile's) with the region split `z_split_cm`; the
    camera prior is the SPEC camera with its focal length times `focal_scale` and the principal
    point at the image centre; heat maps at `stride` 4 or 2 input pixels."""

    corner_order = "upper"  # `fit._corner_loss`: corner 0 is the upper end of the 0-2 diagonal
    # buffers (`__init__` says what each holds)
    grid_u: torch.Tensor  # [W / stride] px
    grid_v: torch.Tensor  # [H / stride] px
    px_to_unit: torch.Tensor  # [2]
    principal: torch.Tensor  # [2] px
    focal: torch.Tensor  # [] px
    focal_bounds: torch.Tensor  # [2] px
    self_calibrate: torch.Tensor  # [] 0 or 1
    radial_prior: torch.Tensor  # [] k1
    to_unit: torch.Tensor  # [3, 3]
    square_st: torch.Tensor  # [cells, 2]
    parity_shifts: torch.Tensor  # [9, 2]
    templates: torch.Tensor  # [2, 9, cells] (a texture)
    checker: torch.Tensor  # [cells] +-1 (the checker)
    blur_u: torch.Tensor
    blur_v: torch.Tensor
    z_split: torch.Tensor  # [] cm
    side_spread: torch.Tensor  # []
    depth_spread: torch.Tensor  # []
    parity_gain: torch.Tensor  # []

    def __init__(
        self,
        size: tuple[int, int] = SIZE,
        board_cm: tuple[float, float] | None = None,
        z_split_cm: float = Z_SPLIT_CM,
        focal_scale: float = FOCAL_PRIOR,
        self_calibrate: bool = True,
        stride: int = 4,
        pattern: Pattern | None = None,
    ) -> None:
        super().__init__()
        size = (int(size[0]), int(size[1]))
        if size != SIZE:
            raise ValueError(
                f"unsupported input size {size[0]}x{size[1]}; the network takes 160x120"
            )
        if stride not in STRIDES:
            raise ValueError(f"unsupported heat-map stride {stride}; one of {STRIDES}")
        self.size = size
        self.stride = stride
        self.batch_norm = True
        self.stem = conv_block(3, 16, 3, 2)  # 80x60
        self.down1 = _block(16, 32)  # 40x30
        self.down2 = _block(32, 64)  # 20x15
        self.down3 = _block(64, 128)  # 10x7
        self.reduce = conv_block(128, 32, 1)
        self.up2 = conv_block(32 + 64, 32)  # 20x15
        self.up1 = conv_block(32 + 32, 32)  # 40x30
        # stride 2: one more decoder step, on the stem's 80x60 features
        self.up0 = conv_block(32 + 16, 16) if stride == 2 else None
        self.heat = nn.Conv2d(16 if stride == 2 else 32, 4, 1)
        # the object's texture as the half turn and the alignment read it (default: the checker)
        texture = pattern if pattern is not None and not pattern.checker else None
        self.textured = texture is not None
        cells = texture.cells if texture is not None else SQUARES
        self.align = TextureAlign(size, SQUARES, pattern)  # no weights: geometry only
        self.presence = nn.Sequential(
            nn.Flatten(), nn.Linear(2 * 128, 64), nn.ReLU(), nn.Linear(64, 1)
        )
        # the corners' offsets from the cells (`_soft_argmax`): zero to start with, as in the
        # networks before them (`_load_from_state_dict`)
        self.offset = offset = nn.Conv2d(self.heat.in_channels, 8, 1)
        assert offset.bias is not None  # nn.Conv2d's default bias=True
        nn.init.zeros_(offset.weight)
        nn.init.zeros_(offset.bias)
        w, h = size[0] // stride, size[1] // stride
        self.register_buffer("grid_u", (torch.arange(w) * stride + (stride - 1) / 2).float())
        self.register_buffer("grid_v", (torch.arange(h) * stride + (stride - 1) / 2).float())
        self.register_buffer(
            "px_to_unit", torch.tensor([2.0 / size[0], 2.0 / size[1]]), persistent=False
        )
        self._camera_buffers(size, focal_scale, self_calibrate)
        self._pattern_buffers(board_cm, cells, texture)
        # the blurs of `blurred_checker` along the input's width and height
        self.register_buffer("blur_u", _parity_blur_matrices(size[0]), persistent=False)
        self.register_buffer("blur_v", _parity_blur_matrices(size[1]), persistent=False)
        # buffers, so that a checkpoint carries them: the region split (cm), the sd of cx, cy
        # per cm of distance and of cz per cm of cz, the parity correlation -> logit gain
        self.register_buffer("z_split", torch.tensor(float(z_split_cm)))
        self.register_buffer("side_spread", torch.tensor(0.08))
        self.register_buffer("depth_spread", torch.tensor(0.08))
        self.register_buffer("parity_gain", torch.tensor(8.0))

    def _camera_buffers(
        self, size: tuple[int, int], focal_scale: float, self_calibrate: bool
    ) -> None:
        """The prior camera's buffers: principal point at the image centre, focal length (px)
        of the SPEC camera times `focal_scale`, or (self_calibrate = 1) the estimate of
        `focal_length`, its bounds, the lens's k1 prior."""
        spec_f = float(intrinsics(size)[0, 0])
        lo, hi = FOCAL_BOUNDS
        self.register_buffer("principal", torch.tensor([(size[0] - 1) / 2, (size[1] - 1) / 2]))
        self.register_buffer("focal", torch.tensor(spec_f * focal_scale), persistent=False)
        self.register_buffer(
            "focal_bounds", torch.tensor([spec_f * lo, spec_f * hi]), persistent=False
        )
        self.register_buffer("self_calibrate", torch.tensor(float(self_calibrate)))
        self.register_buffer("radial_prior", torch.tensor(RADIAL_PRIOR), persistent=False)

    def _pattern_buffers(
        self, board_cm: tuple[float, float] | None, cells: tuple[int, int], texture: Pattern | None
    ) -> None:
        """The object's buffers: object (X, Y) cm -> unit square, the `cells` (along x, y)
        centres and their 9 shifted grids the half turn is read at, and the texture's
        templates there (`texture`) or the checker's signs (None)."""
        if board_cm is None:
            default = load_profile(DEFAULT_PROFILE)
            board_cm = (default.width_cm, default.height_cm)
        bw, bh = board_cm
        # object (X, Y) -> unit square (s, t), the inverse of X = -bw/2 + bw s, Y = -bh/2 + bh t
        self.register_buffer(
            "to_unit",
            torch.tensor([[1 / bw, 0, 0.5], [0, 1 / bh, 0.5], [0, 0, 1.0]], dtype=torch.float32),
        )
        i, j = torch.meshgrid(torch.arange(cells[0]), torch.arange(cells[1]), indexing="xy")
        self.register_buffer(
            "square_st",
            torch.stack([(i + 0.5) / cells[0], (j + 0.5) / cells[1]], -1).reshape(-1, 2),
        )
        third = torch.tensor([-1.0, 0.0, 1.0]) / 3
        shifts = torch.stack(torch.meshgrid(third / cells[0], third / cells[1], indexing="xy"), -1)
        self.register_buffer("parity_shifts", shifts.reshape(-1, 2), persistent=False)
        if texture is not None:
            # the texture at the 9 shifted grids of cell centres, in the order read and half
            # turned ((s, t) -> (1 - s, 1 - t)): [2, 9, cells]
            st = (self.square_st[None] + self.parity_shifts[:, None]).reshape(-1, 2).numpy()
            both = [texture.sample(st), texture.sample(1.0 - st)]
            templates = torch.tensor(np.stack(both), dtype=torch.float32)
            self.register_buffer("templates", templates.reshape(2, 9, -1), persistent=False)
        else:
            # +1 on white squares; the square at corner 0 (-X, -Y) is black
            self.register_buffer("checker", (((i + j) % 2) * 2 - 1).reshape(-1).float())

    def pattern_threshold(self) -> torch.Tensor | float:
        """|corr(image, texture)| at the aligned corners above which the object is taken as
        present (`observe`): `PATTERN_CORR` here; measured per object for `corners-any`."""
        return PATTERN_CORR

    # -- network -------------------------------------------------------------------------------
    def _encode(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Normalised RGB [N, 3, 120, 160] -> heat-map logits [N, 4, 30, 40] (stride 2:
        [N, 4, 60, 80]), the corners' offsets from the cells [N, 8, 30, 40] px ((u, v) of
        corner 0, ...; stride 2: [N, 8, 60, 80]), presence logit [N]."""
        s0 = self.stem(x)
        s1 = self.down1(F.max_pool2d(s0, 2))
        s2 = self.down2(F.max_pool2d(s1, 2))
        s3 = self.down3(F.max_pool2d(s2, 2))
        u = self.up2(torch.cat([F.interpolate(self.reduce(s3), size=s2.shape[2:]), s2], 1))
        u = self.up1(torch.cat([F.interpolate(u, size=s1.shape[2:]), s1], 1))
        if self.up0 is not None:
            u = self.up0(torch.cat([F.interpolate(u, size=s0.shape[2:]), s0], 1))
        pooled = torch.cat([s3.mean((2, 3)), s3.amax((2, 3))], 1)
        return self.heat(u), self.offset(u), self.presence(pooled)[:, 0]

    def _soft_argmax(self, heat: torch.Tensor, offset: torch.Tensor) -> torch.Tensor:
        """Heat-map logits [N, 4, h, w] and offsets [N, 8, h, w] px (`_encode`) -> expected
        corner positions [N, 4, 2] px (input image): the sum over the cells of P(cell) times
        the cell's centre plus its offset."""
        n, k, h, w = heat.shape
        p = F.softmax(heat.reshape(n, k, h * w), dim=2).reshape(n, k, h, w)
        offset = offset.reshape(n, k, 2, h, w)
        u = (p * (self.grid_u + offset[:, :, 0])).sum((2, 3))
        v = (p * (self.grid_v[:, None] + offset[:, :, 1])).sum((2, 3))
        return torch.stack([u, v], 2)

    # -- geometry ------------------------------------------------------------------------------
    def prior_focal(self, k1: torch.Tensor) -> torch.Tensor:
        """The lens's fitted k1 [N] (`lens`) -> the prior focal length [N] px: `focal`, shorter
        where k1 is a stronger barrel than `BARREL_LIMIT` (f0 sqrt(BARREL_LIMIT / k1))."""
        ratio = torch.where(k1 < BARREL_LIMIT, BARREL_LIMIT / k1, torch.ones_like(k1))
        return self.focal * ratio.sqrt()

    def focal_length(
        self, Hc: torch.Tensor, known: torch.Tensor | None = None, k1: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Focal length [N] px for centred object-plane homographies Hc [N, 3, 3] in square
        pixels: `known` [N] where it is > 0 (the caller's calibration, px of the input's width;
        None: unknown everywhere), else the prior `focal`, or (self_calibrate) the one that
        best makes the images of the board's x and y axes orthogonal and of equal length
        (Zhang's constraints), with the prior (`prior_focal` of the lens's fitted `k1` [N];
        None: of `radial_prior`, as `undistorted`) as one more constraint of weight
        `FOCAL_PRIOR_WEIGHT`, within `focal_bounds`.

        Unknown z = (f0 / f)^2 with f0 the prior; in pixel units of f0, with Hc scaled to unit
        norm of its first two columns, the constraints are a_i z + b_i = 0 (i = 1, 2) and the
        prior z = 1: z = (kappa - sum a_i b_i) / (kappa + sum a_i^2). A near-frontal view has
        a_i ~ 0 and keeps the prior; an oblique one decides."""
        f0 = self.prior_focal(self.radial_prior.expand_as(Hc[:, 0, 0]) if k1 is None else k1)
        Hn = torch.cat([Hc[:, :2, :] / f0[:, None, None], Hc[:, 2:, :]], 1)
        Hn = Hn / Hn[:, :, :2].flatten(1).norm(dim=1).clamp_min(1e-12)[:, None, None]
        h1, h2 = Hn[:, :, 0], Hn[:, :, 1]
        a1 = h1[:, 0] * h2[:, 0] + h1[:, 1] * h2[:, 1]
        b1 = h1[:, 2] * h2[:, 2]
        a2 = h1[:, 0] ** 2 + h1[:, 1] ** 2 - h2[:, 0] ** 2 - h2[:, 1] ** 2
        b2 = h1[:, 2] ** 2 - h2[:, 2] ** 2
        kappa = FOCAL_PRIOR_WEIGHT
        z = (kappa - (a1 * b1 + a2 * b2)) / (kappa + a1 * a1 + a2 * a2)
        f = (f0 * z.clamp_min(1e-6).rsqrt()).clamp(self.focal_bounds[0], self.focal_bounds[1])
        f = torch.where(self.self_calibrate > 0.5, f, self.focal.expand_as(f))
        return f if known is None else torch.where(known > 0, known * torch.ones_like(f), f)

    def _load_from_state_dict(
        self, state_dict: dict[str, Any], prefix: str, *args: Any, **kwargs: Any
    ) -> None:
        # checkpoints before 3.3.0 stored the focal-length prior and bounds (then from the
        # renders' focal range): the camera model is the code's, not the checkpoint's
        state_dict.pop(prefix + "focal", None)
        state_dict.pop(prefix + "focal_bounds", None)
        for key in ZERO_IF_ABSENT:
            state_dict.setdefault(prefix + key, torch.zeros_like(self.get_parameter(key)))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    @staticmethod
    def _to_square(pixel_aspect: torch.Tensor) -> torch.Tensor:
        """Pixel aspect [N] -> the (u, v) scale [N, 2] to square pixels of the input's width."""
        return torch.stack([torch.ones_like(pixel_aspect), 1 / pixel_aspect], 1)

    def lens(self, pixel_aspect: torch.Tensor, view: torch.Tensor | None = None) -> Lens:
        """The prior camera's radial lens (`radial_prior`, normalised coordinates of the prior
        focal length, square pixels) in pixels of the input: the frame's, or (`view` [N, 3],
        `answer`) those of the crop of the frame the input is."""
        centre = self.principal.expand(pixel_aspect.shape[0], 2)
        scale = self._to_square(pixel_aspect) / self.focal
        if view is not None:
            centre = (centre - view[:, :2] + 0.5) / view[:, 2:] - 0.5
            scale = scale * view[:, 2:]
        return Lens(centre, scale, self.radial_prior * torch.ones_like(pixel_aspect))

    def undistorted(
        self, q: torch.Tensor, pixel_aspect: torch.Tensor, k1: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Corners [N, 4, 2] px -> the same corners without the lens's radial distortion:
        `k1` [N] (fitted by the alignment, `observe`; None: the prior `radial_prior`), in
        normalised coordinates of the prior focal length (`lens`)."""
        lens = self.lens(pixel_aspect)
        return lens.undistort(q, (lens.k1 if k1 is None else k1)[:, None])

    def centred_homography(self, H_unit: torch.Tensor, pixel_aspect: torch.Tensor) -> torch.Tensor:
        """Unit-square homography [N, 3, 3] and pixel aspect [N] -> the object-plane (cm)
        homography [N, 3, 3] about the principal point, in square pixels of the input's
        width: what `focal_length` and `camera_centre` work on."""
        H = H_unit @ self.to_unit
        w = H[:, 2:3, :]
        centred = H[:, :2, :] - self.principal[None, :, None] * w
        return torch.cat([centred * self._to_square(pixel_aspect)[:, :, None], w], 1)

    def camera_centre(
        self,
        H_unit: torch.Tensor,
        pixel_aspect: torch.Tensor,
        focal: torch.Tensor | None = None,
        k1: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Unit-square homography [N, 3, 3] -> camera centre [N, 3] cm in the object frame
        (M = A^-1 H = lambda [r1 r2 t], c = -R^T t), with the camera of `focal_length` (its
        `known` focal length `focal` [N], its lens's fitted `k1` [N]).

        `pixel_aspect` [N] is the height over the width of an input pixel in the scene (fy /
        fx): 1 for a 4:3 photo, 0.75 W / H for a landscape W x H photo resized to 160x120
        (16:9: 4/3; `service.core.preprocess.NetworkFrame`, which turns portraits to landscape).
        The rows are brought to square pixels of the input's width first."""
        Hc = self.centred_homography(H_unit, pixel_aspect)
        f = self.focal_length(Hc, focal, k1)
        M = torch.cat([Hc[:, :2, :] / f[:, None, None], Hc[:, 2:, :]], 1)
        m1, m2, m3 = M[:, :, 0], M[:, :, 1], M[:, :, 2]
        lam = 2.0 / (m1.norm(dim=1) + m2.norm(dim=1) + 1e-9)
        lam = torch.where(m3[:, 2] < 0, -lam, lam)
        r1, r2, t = m1 * lam[:, None], m2 * lam[:, None], m3 * lam[:, None]
        r3 = torch.cross(r1, r2, dim=1)
        return -torch.stack([(r1 * t).sum(1), (r2 * t).sum(1), (r3 * t).sum(1)], 1)

    def blurred_checker(self, H_unit: torch.Tensor) -> torch.Tensor:
        """Unit-square homographies [N, 3, 3] -> the checker (+1 white, -1 black, 0 off the
        board) rendered at the input's pixel centres through them and blurred by the two
        `_parity_blurs` [N, 2, H, W]."""
        w, h = self.size
        a = H_unit  # its adjugate maps image points back to the unit square (up to scale)
        inv = torch.stack(
            [
                torch.cross(a[:, :, 1], a[:, :, 2], dim=1),
                torch.cross(a[:, :, 2], a[:, :, 0], dim=1),
                torch.cross(a[:, :, 0], a[:, :, 1], dim=1),
            ],
            1,
        )  # rows: [N, 3, 3]
        u = torch.arange(w, dtype=a.dtype, device=a.device)
        v = torch.arange(h, dtype=a.dtype, device=a.device)[:, None]
        p = [
            inv[:, i, 0, None, None] * u + inv[:, i, 1, None, None] * v + inv[:, i, 2, None, None]
            for i in range(3)
        ]
        z = torch.where(p[2].abs() < 1e-9, torch.full_like(p[2], 1e-9), p[2])
        s, t = p[0] / z * SQUARES[0], p[1] / z * SQUARES[1]
        inside = (s >= 0) & (s < SQUARES[0]) & (t >= 0) & (t < SQUARES[1])
        cells = torch.floor(s) + torch.floor(t)
        value = 2 * (cells - 2 * torch.floor(cells / 2)) - 1
        board = torch.where(inside, value, torch.zeros_like(value))[:, None]  # [N, 1, H, W]
        return self.blur_v @ (board @ self.blur_u.transpose(1, 2))

    def parity(self, x: torch.Tensor, H_unit: torch.Tensor, blurred: bool = True) -> torch.Tensor:
        """Correlation [N] in [-1, 1] of the grey image at the 70 square centres (through
        `H_unit`) with the checker pattern: > 0 when the corner order is the true one. A
        textured object (`train.network.pattern`) reads its cells instead: half the
        difference of the correlations with its template read in order and half turned
        (for the checker, whose half turn inverts it, exactly the correlation).

        The centres are also tried shifted by a third of a square along each axis (9 grids),
        and the grid with the strongest correlation answers: corners a few pixels off put
        the exact centres near square edges, where the correlation fades. Each grid is also
        correlated with the `blurred_checker`s sampled at it (a heavy blur inverts the
        pattern of small squares); the strongest of the 3 x 9 correlations answers
        (`blurred` False: of the 9 plain ones)."""
        n, k = x.shape[0], self.square_st.shape[0]
        st = (self.square_st[None] + self.parity_shifts[:, None]).reshape(-1, 2)
        st = torch.cat([st, torch.ones_like(st[:, :1])], 1)
        p = torch.einsum("nij,kj->nki", H_unit, st)  # [N, 9 * 70, 3]
        w = torch.where(p[..., 2:].abs() < 1e-6, torch.full_like(p[..., 2:], 1e-6), p[..., 2:])
        uv = p[..., :2] / w
        grid = ((uv + 0.5) * self.px_to_unit - 1.0).clamp(-2.0, 2.0).reshape(n, 1, -1, 2)
        grey = x.mean(1, keepdim=True)
        samples = F.grid_sample(grey, grid, align_corners=False).reshape(n, 1, -1, k)
        if self.textured:
            return self._textured_parity(samples)
        templates = self.checker.expand(n, 1, self.parity_shifts.shape[0], k)  # [N, 1, 9, 70]
        if blurred:
            seen = F.grid_sample(self.blurred_checker(H_unit), grid, align_corners=False)
            templates = torch.cat([templates, seen.reshape(n, 2, -1, k)], 1)  # [N, 3, 9, 70]
        centred = samples - samples.mean(3, keepdim=True)
        templates = templates - templates.mean(3, keepdim=True)
        norm = centred.pow(2).mean(3).sqrt() * templates.pow(2).mean(3).sqrt() + 1e-4
        corr = ((centred * templates).mean(3) / norm).flatten(1)  # [N, 3 * 9] (or 9)
        best = corr.abs().argmax(1, keepdim=True)
        return torch.gather(corr, 1, best)[:, 0]

    def _textured_parity(self, samples: torch.Tensor) -> torch.Tensor:
        """Image samples [N, 1, 9, K] at the shifted grids of cell centres -> half the
        difference [N] of their correlations with the template in order and half turned, of
        the grid where it is the largest."""
        centred = samples - samples.mean(3, keepdim=True)
        norm = centred.pow(2).mean(3).sqrt() + 1e-4  # the templates have unit RMS
        corr = (centred * self.templates[None]).mean(3) / norm  # [N, 2, 9]
        diff = 0.5 * (corr[:, 0] - corr[:, 1])  # [N, 9]
        best = diff.abs().argmax(1, keepdim=True)
        return torch.gather(diff, 1, best)[:, 0]

    def class_probabilities(self, c: torch.Tensor, order_ok: torch.Tensor) -> torch.Tensor:
        """Camera centres [N, 3] cm and P(corner order is the true one) [N] -> P(class 1..8
        | object present) [N, 8]."""
        dist = c.norm(dim=1).clamp_min(1.0)
        sd = self.side_spread * dist
        px = 0.5 * (1 + torch.erf(c[:, 0] / (sd * math.sqrt(2))))
        py = 0.5 * (1 + torch.erf(c[:, 1] / (sd * math.sqrt(2))))
        sz = self.depth_spread * c[:, 2].abs().clamp_min(1.0)
        near = 0.5 * (1 + torch.erf((self.z_split - c[:, 2]) / (sz * math.sqrt(2))))

        def quadrants(px: torch.Tensor, py: torch.Tensor) -> torch.Tensor:
            """P(x >= 0) [N], P(y >= 0) [N] -> P(quadrant 1..4) [N, 4] (`QUADRANT_SIGNS`)."""
            side = {1: (px, py), -1: (1 - px, 1 - py)}
            return torch.stack([side[sx][0] * side[sy][1] for sx, sy in QUADRANT_SIGNS], 1)

        q = order_ok[:, None] * quadrants(px, py) + (1 - order_ok[:, None]) * quadrants(
            1 - px, 1 - py
        )
        return torch.cat([near[:, None] * q, (1 - near[:, None]) * q], 1)

    def pose_classes(
        self,
        q: torch.Tensor,
        parity: torch.Tensor,
        pixel_aspect: torch.Tensor | None,
        focal: torch.Tensor | None = None,
        k1: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Corners [N, 4, 2] px, their parity [N], the pixel aspect [N] (None: square
        pixels), the known focal length [N] (px of the input's width, 0 or None: unknown,
        `focal_length`) and the lens's k1 [N] (None: the prior, `undistorted`) -> P(class
        1..8 | object present) [N, 8] (camera centre of the undistorted corners, mixed over
        the two half-turn readings)."""
        order_ok = torch.sigmoid(self.parity_gain * parity)
        aspect = self._aspect(parity, pixel_aspect)
        H = square_homography(self.undistorted(q, aspect, k1))
        return self.class_probabilities(self.camera_centre(H, aspect, focal, k1), order_ok)

    def _classes_if_present(
        self, x: torch.Tensor, q: torch.Tensor, pixel_aspect: torch.Tensor | None
    ) -> torch.Tensor:
        """RGB [N, 3, H, W] in [0, 1], its corners [N, 4, 2] px and pixel aspect [N] ->
        P(class 1..8 | object present) [N, 8] (`pose_classes` with the corners' parity, read
        against the plain checker only: the training step's classes train nothing and are
        only logged, and the blurred templates would cost ~15 % of a step)."""
        parity = self.parity(x, square_homography(q), blurred=False)
        return self.pose_classes(q, parity, pixel_aspect)

    @staticmethod
    def _aspect(like: torch.Tensor, pixel_aspect: torch.Tensor | None) -> torch.Tensor:
        """The pixel aspect [N] from [N], [1] (the exported graph's default) or None (1)."""
        return torch.ones_like(like) * (1.0 if pixel_aspect is None else pixel_aspect)

    def observe(
        self,
        x: torch.Tensor,
        pixel_aspect: torch.Tensor | None = None,
        view: torch.Tensor | None = None,
    ) -> Observation:
        """RGB [N, 3, H, W] in [0, 1], its pixel aspect [N] and where it lies in the frame
        (`view`, as `answer`) -> what the image says before the pose (`Observation`; corners
        in input pixels)."""
        heat, offset, presence = self._encode((x - self.mean) / self.std)
        lens = self.lens(self._aspect(x[:, 0, 0, 0], pixel_aspect), view)
        q, corr, k1 = self.align(x, self._soft_argmax(heat, offset), lens)
        parity = self.parity(x, square_homography(q))
        # the checker pattern found at the corners is evidence of the board on its own
        pattern = torch.sigmoid(PATTERN_SLOPE * (corr.abs() - self.pattern_threshold()))
        present = 1 - (1 - torch.sigmoid(presence)) * (1 - pattern)
        return Observation(q, parity, present, pattern, k1)

    def answer(
        self,
        x: torch.Tensor,
        pixel_aspect: torch.Tensor | None = None,
        view: torch.Tensor | None = None,
        focal: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """RGB [N, 3, H, W] in [0, 1], the pixel aspect [N] (`camera_centre`; None: 1), the
        camera's focal length [N] where the caller knows it (px of the frame's width in square
        pixels, 0 or None: unknown, self-calibrated; `focal_length`) and
        where the input lies in the frame the camera sees, `view` [N, 3] = (u0, v0, s): input
        pixel (u, v) is frame pixel (u0 + (u + 0.5) s - 0.5, v0 + (v + 0.5) s - 0.5), frame
        pixels as the input's (None: (0, 0, 1), the input is the frame; a crop of the frame
        enlarged 2x is (left, top, 0.5)) -> log-probabilities [N, 9] (softmax gives them
        back), the aligned corners [N, 4, 2] in frame pixels, in the object's
        `CORNER_ORDER` as the parity reads it (meaningless where the object is
        not in view), P(present) [N] from the checker pattern alone (`Observation`), and the
        corners [N, 4, 2] without the lens's radial distortion the alignment fitted (where a
        pinhole camera would see them: what the pose is computed from, `undistorted`)."""
        seen = self.observe(x, pixel_aspect, view)
        q = seen.corners
        if view is not None:
            q = view[:, None, :2] + (q + 0.5) * view[:, None, 2:] - 0.5
        pk = self.pose_classes(q, seen.parity, pixel_aspect, focal, seen.k1)
        present = seen.present[:, None]
        log_p = torch.log(torch.cat([1 - present, present * pk], 1).clamp_min(1e-7))
        pinhole = self.undistorted(q, self._aspect(seen.parity, pixel_aspect), seen.k1)
        in_order = seen.parity[:, None, None] >= 0
        corners = torch.where(in_order, q, torch.roll(q, 2, 1))
        return (
            log_p,
            corners,
            seen.pattern,
            torch.where(in_order, pinhole, torch.roll(pinhole, 2, 1)),
        )

    def logits(self, x: torch.Tensor, pixel_aspect: torch.Tensor | None = None) -> torch.Tensor:
        """RGB [N, 3, H, W] in [0, 1] (and its pixel aspect [N]) -> log-probabilities [N, 9]
        (softmax gives them back)."""
        return self.answer(x, pixel_aspect)[0]

    def corners(self, x: torch.Tensor) -> torch.Tensor:
        """RGB [N, 3, H, W] in [0, 1] -> the corners [N, 4, 2] px of `answer`."""
        return self.answer(x)[1]

    def forward(
        self, x: torch.Tensor, pixel_aspect: torch.Tensor | None = None
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """RGB [N, 3, H, W] in [0, 1] (and its pixel aspect [N]) -> log-probabilities [N, 9];
        in training mode also the corners [N, 8] ((u, v) x 4) scaled to [-1, 1], the target
        `fit._corner_loss` trains."""
        if not self.training:
            return self.logits(x, pixel_aspect)
        heat, offset, presence = self._encode((x - self.mean) / self.std)
        # under a bfloat16 training step (`FitConfig.bf16`) only the encoder runs in bfloat16:
        # the soft-argmax and the geometry need float32 (in bfloat16 a soft-argmax over
        # 80x60 positions is up to half a pixel off)
        with torch.autocast(x.device.type, enabled=False):
            heat, offset, presence = heat.float(), offset.float(), presence.float()
            q = self._soft_argmax(heat, offset)
            # the class loss trains the presence logit only; the corners learn from theirs
            with torch.no_grad():
                pk = self._classes_if_present(x, q, pixel_aspect)
            log_present = F.logsigmoid(presence)[:, None]
            log_absent = F.logsigmoid(-presence)[:, None]
            log_p = torch.cat([log_absent, log_present + torch.log(pk.clamp_min(1e-7))], 1)
        return log_p, (q * self.px_to_unit - 1.0).reshape(-1, 8)
