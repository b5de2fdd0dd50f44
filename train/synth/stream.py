"""Renders of many objects, drawn on the fly: the training data of the generic corner network.

Each image of a `TextureStream.batch` shows its own object: a texture of the bank
(`train.synth.textures.TextureBank`) with its own size, rendered as `train.synth.render`
renders a profile (the base profile's camera, lens, roll, border, occluders, jitter and
backgrounds; `free` look-at targets), with probability `p_absent` not at all (class 0). With
probability `p_distractor` another object of the bank is drawn into the background first: the
network has to find the object whose picture it is given, not any rectangle. A photograph used
as the texture is never the image's background.

Frames: images RGB uint8 [H, W, 3] of `size` (W, H); corners in pixels of the image in
`service.core.frame.CORNER_ORDER` (nan where absent).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from service.core.profile import Profile, load_profile
from train.synth.background import BackgroundPool, shipped_names
from train.synth.render import BoardImage, Renderer, draw_views
from train.synth.textures import Texture, TextureBank

#: The profile whose camera, lens, border and regions the generic renders use (its size and
#: picture are each image's own).
BASE_PROFILE = "book"


@dataclass
class Batch:
    """A batch of renders, one object each."""

    images: np.ndarray  # uint8 [N, H, W, 3]
    corners: np.ndarray  # float32 [N, 8] px, nan where absent
    classes: np.ndarray  # int64 [N], 0 where absent
    textures: list[Texture]  # the object of each image (also of the absent ones)


class TextureStream:
    """On-the-fly renders of the texture bank at `size` (W, H) (module doc)."""

    def __init__(
        self,
        size: tuple[int, int] = (160, 120),
        bank: TextureBank | None = None,
        backgrounds: BackgroundPool | None = None,
        p_absent: float = 1 / 9,
        p_distractor: float = 0.15,
        base: str = BASE_PROFILE,
    ) -> None:
        self.size = size
        self.bank = bank if bank is not None else TextureBank()
        self.pool = backgrounds if backgrounds is not None else BackgroundPool.default(size)
        self.base: Profile = load_profile(base)
        # the pool's first sources are the shipped photographs, in `shipped_names` order
        self.photo_index = {name: i for i, name in enumerate(shipped_names())}
        grey = np.full((8, 8, 3), 127, np.uint8)
        self.renderer = Renderer(self.base, size, True, self.pool, texture=grey, borders=1)
        self.p_absent, self.p_distractor = p_absent, p_distractor

    def _board(self, texture: Texture, rng: np.random.Generator) -> tuple[Profile, BoardImage]:
        """The texture as an object (the base profile at its size) and its framed board."""
        profile = replace(self.base, width_cm=texture.width_cm, height_cm=texture.height_cm)
        border = profile.border
        board = BoardImage(
            profile,
            texture.rgb,
            float(rng.uniform(*border.margin_cm)),
            float(rng.uniform(*border.frame_cm)),
            int(rng.integers(border.frame_grey[0], border.frame_grey[1] + 1)),
        )
        return profile, board

    def _show(
        self,
        texture: Texture,
        k: int,
        rng: np.random.Generator,
        background: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """One render of `texture` in class `k` (0: not shown) on `background` (None: drawn
        from the pool, not the texture's own photograph) -> (RGB uint8 [H, W, 3], corners
        (8,) px, nan for class 0)."""
        profile, board = self._board(texture, rng)
        self.renderer.profile, self.renderer.boards = profile, [board]
        view = draw_views(profile, np.array([k]), "free", rng)[0] if k else None
        own = self.photo_index.get(texture.source.removeprefix("photo:"))
        avoid = frozenset() if own is None else frozenset({own})
        image = self.renderer.render(view, 0, rng, avoid, background)
        if view is None:
            return image, np.full(8, np.nan, np.float32)
        return image, view.object_corners(profile, self.size).ravel().astype(np.float32)

    def distractor(self, texture: Texture, rng: np.random.Generator) -> np.ndarray:
        """A background (RGB uint8 [H, W, 3]) with another object of the bank in it, drawn
        without jitter (the image's own jitter comes after)."""
        other = self.bank.draw(rng)
        profile, board = self._board(other, rng)
        view = draw_views(profile, rng.integers(1, 9, 1), "free", rng)[0]
        own = self.photo_index.get(texture.source.removeprefix("photo:"))
        avoid = frozenset() if own is None else frozenset({own})
        return self.renderer.draw_object(self.pool.sample(rng, avoid), view, board)

    def batch(self, n: int, rng: np.random.Generator) -> Batch:
        """`n` renders, each of its own texture (module doc)."""
        images = np.empty((n, self.size[1], self.size[0], 3), np.uint8)
        corners = np.full((n, 8), np.nan, np.float32)
        classes = np.where(rng.random(n) < self.p_absent, 0, rng.integers(1, 9, n))
        textures = []
        for i in range(n):
            texture = self.bank.draw(rng)
            background = self.distractor(texture, rng) if rng.random() < self.p_distractor else None
            images[i], corners[i] = self._show(texture, int(classes[i]), rng, background)
            textures.append(texture)
        return Batch(images, corners, classes.astype(np.int64), textures)
