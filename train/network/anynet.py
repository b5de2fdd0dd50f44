"""The generic corner network (architecture `corners-any`): it reads the object's picture.

`CornerNet` finds the corners of the one object it was trained on. `AnyCornerNet` is the same
network (U-Net encoder, heat maps at stride 2, offsets, presence, then the texture's
alignment, half turn, pose and classes unchanged) with the object's front-on picture as a
second input, so that one set of weights serves any object:

    texture     the picture resized to `TEXTURE_SIZE` (RGB [T, 3, 64, 64] in [0, 1], its
                aspect height / width in cm [T] beside it) -> a small encoder (4 conv blocks,
                64 x 64 -> 4 x 4) -> 16 local keys [T, 32, 16] and a global embedding [T, 64]
    match       the image's 20 x 15 features (`down2`) projected to 32 channels, cosine
                similarity with each local key -> 16 maps [N, 16, 15, 20], and their maximum
    condition   the maps (and their max) added to the first decoder step through a 1x1
                convolution; the embedding scales and shifts (FiLM) the bottleneck and the
                40 x 30 decoder features; presence adds a head on the embedding and the
                pooled maps to the image-only presence logit

Every new layer starts at zero (its output adds nothing), so the network starts as the
`CornerNet` whose weights it is given (`grown_from`). The object's picture is a buffer
(`texture_input`, `texture_aspect`), set from its profile: the exported graph is an ordinary
corner graph per object (`service/core/onnx_contract.py` unchanged). Training on many
textures feeds them per image instead (`encode_with`, `train.network.anyfit`).

The presence threshold on the texture's alignment score (`pattern_threshold`) and a bias of
the presence logit are buffers measured per object (`train.network.zeroshot.presence_threshold`),
not the chessboard's 0.4 and none.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from service.core.pose import FOCAL_PRIOR
from service.core.regions import Z_SPLIT_CM
from train.network.align import square_homography
from train.network.base import conv_block
from train.network.corners import PATTERN_CORR, PATTERN_SLOPE, SIZE, CornerNet, Observation
from train.network.pattern import Pattern

#: The picture's size at the network's input (W, H) px.
TEXTURE_SIZE = (64, 64)
KEYS, KEY_DIM, EMBED = 16, 32, 64


def texture_tensor(rgb: np.ndarray) -> torch.Tensor:
    """RGB uint8 [h, w, 3] -> the network's texture input float32 [3, 64, 64] in [0, 1]."""
    small = cv2.resize(rgb, TEXTURE_SIZE, interpolation=cv2.INTER_AREA)
    return torch.from_numpy(small).permute(2, 0, 1).float() / 255.0


def _zero(layer: nn.Linear | nn.Conv2d) -> nn.Linear | nn.Conv2d:
    nn.init.zeros_(layer.weight)
    if layer.bias is not None:
        nn.init.zeros_(layer.bias)
    return layer


class AnyCornerNet(CornerNet):
    """`CornerNet` (stride 2) conditioned on the object's picture (module doc); `texture` RGB
    uint8 [h, w, 3] of the object (None: mid grey, the generic network's placeholder)."""

    corner_order = "top"  # `fit._corner_loss`: the quarter turn is read from the texture
    texture_input: torch.Tensor  # [1, 3, 64, 64] in [0, 1]
    texture_aspect: torch.Tensor  # [1] height / width (cm)
    presence_corr: torch.Tensor  # [] the object's threshold on |corr| (`pattern_threshold`)
    presence_bias: torch.Tensor  # [] added to the presence logit in `observe`, per object

    def __init__(
        self,
        size: tuple[int, int] = SIZE,
        board_cm: tuple[float, float] | None = None,
        z_split_cm: float = Z_SPLIT_CM,
        focal_scale: float = FOCAL_PRIOR,
        pattern: Pattern | None = None,
        texture: np.ndarray | None = None,
    ) -> None:
        super().__init__(size, board_cm, z_split_cm, focal_scale, stride=2, pattern=pattern)
        self.tex_stem = conv_block(3, 16, 3, 2)  # 32 x 32
        self.tex_blocks = nn.Sequential(
            conv_block(16, 32), nn.MaxPool2d(2), conv_block(32, 64), nn.MaxPool2d(2),
            conv_block(64, 64), nn.MaxPool2d(2),
        )  # fmt: skip  # 4 x 4
        self.tex_keys = nn.Conv2d(64, KEY_DIM, 1)
        self.tex_embed = nn.Sequential(nn.Linear(2 * 64 + 1, EMBED), nn.ReLU())
        self.img_keys = nn.Conv2d(64, KEY_DIM, 1)
        self.inject = _zero(nn.Conv2d(KEYS + 1, 32, 1))
        self.film_bottleneck = _zero(nn.Linear(EMBED, 2 * 32))
        self.film_decoder = _zero(nn.Linear(EMBED, 2 * 32))
        self.presence_any = nn.Sequential(
            nn.Linear(EMBED + 2 * KEYS, 64), nn.ReLU(), _zero(nn.Linear(64, 1))
        )
        if board_cm is None:
            board_cm = (float(1 / self.to_unit[0, 0]), float(1 / self.to_unit[1, 1]))
        grey = np.full((8, 8, 3), 127, np.uint8)
        self.register_buffer(
            "texture_input", texture_tensor(grey if texture is None else texture)[None]
        )
        self.register_buffer("texture_aspect", torch.tensor([board_cm[1] / board_cm[0]]))
        self.register_buffer("presence_corr", torch.tensor(PATTERN_CORR))
        self.register_buffer("presence_bias", torch.tensor(0.0))

    def _load_from_state_dict(
        self, state_dict: dict[str, Any], prefix: str, *args: Any, **kwargs: Any
    ) -> None:
        # checkpoints of the first generic runs have no per-object presence bias: none
        state_dict.setdefault(prefix + "presence_bias", torch.tensor(0.0))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def pattern_threshold(self) -> torch.Tensor:
        """The object's own threshold on the alignment score (module doc)."""
        return self.presence_corr

    def texture_features(
        self, texture: torch.Tensor, aspect: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Pictures [T, 3, 64, 64] in [0, 1] and aspects [T] -> unit local keys [T, 32, 16]
        and the embedding [T, 64]."""
        f = self.tex_blocks(self.tex_stem((texture - self.mean) / self.std))  # [T, 64, 4, 4]
        keys = F.normalize(self.tex_keys(f).flatten(2), dim=1)
        pooled = torch.cat([f.mean((2, 3)), f.amax((2, 3)), aspect.log()[:, None]], 1)
        return keys, self.tex_embed(pooled)

    @staticmethod
    def _film(u: torch.Tensor, film: torch.Tensor) -> torch.Tensor:
        """Features [N, C, h, w] scaled and shifted by FiLM parameters [N | 1, 2C]."""
        gamma, beta = film.chunk(2, dim=1)
        return u * (1 + gamma[:, :, None, None]) + beta[:, :, None, None]

    def encode_with(
        self, x: torch.Tensor, texture: torch.Tensor, aspect: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Normalised RGB [N, 3, 120, 160] and the object's picture [N | 1, 3, 64, 64] in [0, 1]
        with its aspect [N | 1] -> heat-map logits [N, 4, 60, 80], offsets [N, 8, 60, 80] px,
        presence logit [N] (`CornerNet._encode`, conditioned as the module doc says)."""
        keys, embed = self.texture_features(texture, aspect)
        s0 = self.stem(x)
        s1 = self.down1(F.max_pool2d(s0, 2))
        s2 = self.down2(F.max_pool2d(s1, 2))
        s3 = self.down3(F.max_pool2d(s2, 2))
        image_keys = F.normalize(self.img_keys(s2), dim=1)  # [N, 32, 15, 20]
        sim = torch.einsum("nchw,nck->nkhw", image_keys, keys.expand(x.shape[0], -1, -1))
        sim = torch.cat([sim, sim.amax(1, keepdim=True)], 1)  # [N, 17, 15, 20]
        r = self._film(self.reduce(s3), self.film_bottleneck(embed))
        u = self.up2(torch.cat([F.interpolate(r, size=s2.shape[2:]), s2], 1)) + self.inject(sim)
        u = self.up1(torch.cat([F.interpolate(u, size=s1.shape[2:]), s1], 1))
        u = self._film(u, self.film_decoder(embed))
        assert self.up0 is not None  # stride 2
        u = self.up0(torch.cat([F.interpolate(u, size=s0.shape[2:]), s0], 1))
        pooled = torch.cat([s3.mean((2, 3)), s3.amax((2, 3))], 1)
        matched = torch.cat([sim[:, :KEYS].amax((2, 3)), sim[:, :KEYS].mean((2, 3))], 1)
        conditioned = torch.cat([embed.expand(x.shape[0], -1), matched], 1)
        presence = self.presence(pooled)[:, 0] + self.presence_any(conditioned)[:, 0]
        return self.heat(u), self.offset(u), presence

    def observe(
        self,
        x: torch.Tensor,
        pixel_aspect: torch.Tensor | None = None,
        view: torch.Tensor | None = None,
    ) -> Observation:
        """`CornerNet.observe` with the quarter turn read from the texture: the heat maps give
        the corners in the "top" cyclic order (`corner_order`), which may be the object's
        order turned by a quarter; the texture is aligned in that order and turned by a quarter
        (each also half turned, `TextureAlign`) and the better correlation kept."""
        heat, offset, presence = self._encode((x - self.mean) / self.std)
        lens = self.lens(self._aspect(x[:, 0, 0, 0], pixel_aspect), view)
        q0 = self._soft_argmax(heat, offset)
        a, b = self.align(x, q0, lens), self.align(x, torch.roll(q0, 1, 1), lens)
        pick = b[1].abs() > a[1].abs()  # the sign says the half turn, read by the parity
        q = torch.where(pick[:, None, None], b[0], a[0])
        corr, k1 = torch.where(pick, b[1], a[1]), torch.where(pick, b[2], a[2])
        parity = self.parity(x, square_homography(q))
        pattern = torch.sigmoid(PATTERN_SLOPE * (corr.abs() - self.pattern_threshold()))
        present = 1 - (1 - torch.sigmoid(presence + self.presence_bias)) * (1 - pattern)
        return Observation(q, parity, present, pattern, k1)

    def _encode(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """`encode_with` the object's own picture (the buffers)."""
        return self.encode_with(x, self.texture_input, self.texture_aspect)


def grown_from(parent: CornerNet, net: AnyCornerNet) -> AnyCornerNet:
    """`net` with every parameter and buffer of `parent` (a trained `CornerNet`, stride 2)
    of the same name and shape, except the object's own buffers: it starts as `parent`."""
    own = net.state_dict()
    keep = {"texture_input", "texture_aspect", "presence_corr", "presence_bias", "to_unit"}
    state = {
        k: v
        for k, v in parent.state_dict().items()
        if k in own and own[k].shape == v.shape and k not in keep
    }
    net.load_state_dict(state, strict=False)
    return net
