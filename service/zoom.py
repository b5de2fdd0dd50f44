"""The zoom pass: a second look at parts of the network input enlarged 2x, for small boards.

The keypoint network finds a board best when it spans about a third of its 160x120 input or
more; a board 15-40 px wide (a camera 1-2 m away) is often missed or its corners are a pixel
off, which is enough to flip the x/y side. After the whole-frame pass, each image whose board
is small or missing gets a second look at half-size tiles of its frame at twice the input's
resolution, through the same graph: its `view` input places the tile in the frame, so the
pose is the frame's camera's, and its `pattern` output (the checker pattern found at the
corners) says whether the tile holds the board. Where the uploaded photo has the pixels (at
least twice the input size once turned to landscape), a tile is cut from the photo resized
to twice the input size (`detail_of`): real detail. Otherwise it is the network input's tile
enlarged 2x (bicubic): no new pixels, only a scale the network reads better.

* board found and inside a tile (`MARGIN_PX` in): that tile, the one centred nearest the
  board; its answer replaces the whole frame's if its pattern says present (>= 0.5);
* board not found (with `search`, the default): the `search_tiles` tiles (default
  `SEARCH_TILES` = 1) centred nearest the whole frame's corners, which the network gives
  even when it says absent (its best guess of where a board would be); the one with the
  strongest pattern answers if it says present. On the real val sources the search found 10
  boards the whole frame missed at blur 0; the tile nearest that guess answered all that all
  nine tiles answered (docs/service.md, "Zoom"), for 1 input instead of 9. The presence
  logit does not count in tiles: on photos without a board it fires on some tile of nine,
  the checker pattern does not.

Cost: 2 inputs for a small board, 1 + `search_tiles` for an image without one (1 without
`search`), 1 for a large board.
"""

from __future__ import annotations

import cv2
import numpy as np

from service.core.preprocess import NetworkFrame, to_network_input
from service.model import Answer, PoseModel

GRID = 3  # tiles per axis, half the input's size each, overlapping by half
MARGIN_PX = 4.0  # input pixels between the board's corners and a tile's edge
PRESENT = 0.5  # P(present) of the whole frame's answer / the tile's pattern that counts
SEARCH_TILES = 1  # tiles searched in a frame where no board was found (GRID * GRID: all)


def tile_views(size: tuple[int, int]) -> np.ndarray:
    """The tiles of an input of `size` (W, H) as views float32 [GRID * GRID, 3] = (u0, v0,
    0.5): a tile's top left corner in input pixels and its scale once enlarged 2x."""
    w, h = size
    u0 = np.linspace(0.0, w / 2, GRID)
    v0 = np.linspace(0.0, h / 2, GRID)
    uu, vv = np.meshgrid(u0, v0, indexing="xy")
    return np.stack([uu.ravel(), vv.ravel(), np.full(uu.size, 0.5)], 1).astype(np.float32)


def enlarged(image: np.ndarray, view: np.ndarray) -> np.ndarray:
    """float32 [3, H, W] in [0, 1] and a tile's view (u0, v0, 0.5) -> the tile enlarged 2x,
    float32 [3, H, W] in [0, 1] (bicubic, pixel centres kept)."""
    _, h, w = image.shape
    u0, v0 = int(round(view[0])), int(round(view[1]))
    tile = np.ascontiguousarray(image[:, v0 : v0 + h // 2, u0 : u0 + w // 2].transpose(1, 2, 0))
    big = cv2.resize(tile, (w, h), interpolation=cv2.INTER_CUBIC)
    return np.ascontiguousarray(np.clip(big, 0.0, 1.0).transpose(2, 0, 1))


def detail_decode_size(size: tuple[int, int]) -> tuple[int, int]:
    """The least size (W, H) to decode an upload at for an input of `size` (W, H): both sides
    at least twice the input height, so that a photo of 4:3 or wider, once turned to
    landscape, keeps the pixels of `detail_of` (libjpeg's reduced decoding keeps them)."""
    return (2 * size[1], 2 * size[1])


def detail_of(rgb: np.ndarray, size: tuple[int, int]) -> np.ndarray | None:
    """An uploaded RGB uint8 [H0, W0, 3] -> its frame at twice the input `size` (W, H),
    float32 [3, 2H, 2W] in [0, 1] (`to_network_input` at that size: turned, resized), or None
    when it has fewer pixels than that."""
    w, h = NetworkFrame((rgb.shape[1], rgb.shape[0]), size).upright_size
    if w < 2 * size[0] or h < 2 * size[1]:
        return None
    return to_network_input(rgb, (2 * size[0], 2 * size[1]))


def tile_input(image: np.ndarray, view: np.ndarray, detail: np.ndarray | None) -> np.ndarray:
    """The second look's input at a tile's view (u0, v0, 0.5), float32 [3, H, W]: cut from
    `detail` (the frame at twice the input size, `detail_of`) where there is one, else the
    input `image` [3, H, W]'s tile `enlarged`. Both put a pixel's centre at the same place of
    the frame."""
    if detail is None:
        return enlarged(image, view)
    _, h, w = image.shape
    u0, v0 = 2 * int(round(view[0])), 2 * int(round(view[1]))
    return np.ascontiguousarray(detail[:, v0 : v0 + h, u0 : u0 + w])


def holding_tile(corners: np.ndarray, views: np.ndarray, size: tuple[int, int]) -> int | None:
    """Corners [4, 2] in input pixels -> the index of the tile that holds them all
    `MARGIN_PX` in, centred nearest them (None: the board is larger than a tile)."""
    w, h = size
    lo, hi = corners.min(0), corners.max(0)
    inside = (
        (lo[0] >= views[:, 0] + MARGIN_PX)
        & (lo[1] >= views[:, 1] + MARGIN_PX)
        & (hi[0] <= views[:, 0] + w / 2 - 1 - MARGIN_PX)
        & (hi[1] <= views[:, 1] + h / 2 - 1 - MARGIN_PX)
    )
    if not inside.any():
        return None
    centres = views[:, :2] + np.array([w, h]) / 4
    distance = np.linalg.norm(centres - corners.mean(0), axis=1)
    return int(np.argmin(np.where(inside, distance, np.inf)))


def search_order(corners: np.ndarray, views: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Corners [4, 2] in input pixels (a frame's guess, board found or not) -> the tile
    indices, the tile centred nearest the corners' mean first."""
    centres = views[:, :2] + np.array(size, np.float64) / 4
    order: np.ndarray = np.argsort(np.linalg.norm(centres - corners.mean(0), axis=1), kind="stable")
    return order


def zoomed(
    model: PoseModel,
    batch: np.ndarray,
    pixel_aspect: np.ndarray | None,
    search: bool = True,
    focal: np.ndarray | None = None,
    detail: list[np.ndarray | None] | None = None,
    search_tiles: int = SEARCH_TILES,
) -> Answer:
    """The whole-frame answer of `model` on float32 [N, 3, H, W] in [0, 1] (and its pixel
    aspect [N] and the known focal lengths [N], `PoseModel.run`), with the zoom pass where
    it applies (module doc; `search`: also in the `search_tiles` tiles nearest the corners'
    guess of the images where no board was found, 1 to `GRID` * `GRID`; `detail`: per image
    its frame at twice the input size, or None, `detail_of`) -> `Answer` (probabilities
    [N, 9], corners [N, 4, 2] in input pixels, pattern [N]). A model without `view` and
    `pattern` (`PoseModel.zooms`) gives its whole-frame answer."""
    if not 1 <= search_tiles <= GRID * GRID:
        raise ValueError(f"search_tiles: 1 to {GRID * GRID}, got {search_tiles}")
    whole = model.run(batch, pixel_aspect, focal=focal)
    if not model.zooms or whole.corners is None or whole.pattern is None:
        return whole
    views = tile_views(model.input_size)
    owners, looks = [], []
    for i, (p_absent, corners) in enumerate(
        zip(whole.probabilities[:, 0], whole.corners, strict=True)
    ):
        if p_absent < PRESENT:
            tile = holding_tile(corners, views, model.input_size)
            chosen = [] if tile is None else [tile]
        elif search:
            chosen = search_order(corners, views, model.input_size)[:search_tiles].tolist()
        else:
            chosen = []
        owners += [i] * len(chosen)
        looks += chosen
    if not looks:
        return whole
    aspect, fx = (
        None if a is None else np.asarray(a, np.float32)[owners] for a in (pixel_aspect, focal)
    )
    sharp = detail or [None] * len(batch)
    tiles = np.stack(
        [tile_input(batch[i], views[t], sharp[i]) for i, t in zip(owners, looks, strict=True)]
    )
    second = model.run(tiles, aspect, views[looks], fx)
    assert second.corners is not None and second.pattern is not None  # model.zooms
    probs, corners, pattern = (
        a.copy() for a in (whole.probabilities, whole.corners, whole.pattern)
    )
    flat = None if whole.undistorted is None else whole.undistorted.copy()
    owner = np.asarray(owners)
    for i in np.unique(owner):
        rows = np.flatnonzero(owner == i)
        best = rows[np.argmax(second.pattern[rows])]
        if second.pattern[best] >= PRESENT:
            probs[i], corners[i], pattern[i] = (
                second.probabilities[best],
                second.corners[best],
                second.pattern[best],
            )
            if flat is not None and second.undistorted is not None:
                flat[i] = second.undistorted[best]
    return Answer(probs, corners, pattern, flat)
