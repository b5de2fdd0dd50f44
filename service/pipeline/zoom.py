"""The zoom pass: a second look at the board, enlarged, for boards that are not large.

The keypoint network finds a board's corners best when it spans most of its 160x120 input; a
board 15-100 px wide (a camera 1-2 m away, a hand-held board in a webcam's frame) is often
missed or its corners are pixels off, which is enough to flip the x/y side. After the
whole-frame pass, each image whose board is not large or was missed gets a second look at a
crop of its frame, enlarged, through the same graph: its `view` input places the crop in the
frame, so the pose is the frame's camera's, and its `pattern` output (the object's pattern
found at the corners) says whether the crop holds the board. Where the uploaded photo has the
pixels (at least twice the input size once turned to landscape), the crop is cut from the
photo's frame at twice the input size (`detail_of`): real detail. Otherwise it is the network
input's crop enlarged (bicubic): no new pixels, only a scale the network reads better.

* board found, spanning less than `LARGE` of the input: the crop centred on its corners that
  it fills to `FILL` of the crop's width or height (`closer_view`; at most `MAX_ZOOM` x,
  kept inside the frame); its answer replaces the whole frame's if its pattern says present
  (>= 0.5) and at least as strongly as the whole frame's (a blurred board enlarged can read
  worse than the frame);
* board not found (with `search`, the default): the `search_tiles` half-size tiles of a 3x3
  grid (default `SEARCH_TILES` = 1) centred nearest the whole frame's corners, which the
  network gives even when it says absent (its best guess of where a board would be); the one
  with the strongest pattern answers if it says present. On the real val sources the search
  found 10 boards the whole frame missed at blur 0; the tile nearest that guess answered all
  that all nine tiles answered (docs/service.md, "Zoom"), for 1 input instead of 9. The
  presence logit does not count in tiles: on photos without a board it fires on some tile of
  nine, the checker pattern does not.

Cost: 2 inputs for a board that is not large, 1 + `search_tiles` for an image without one (1
without `search`), 1 for a large board.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

from service.core.preprocess import NetworkFrame, to_network_input
from service.pipeline.model import Answer, PoseModel

GRID = 3  # search tiles per axis, half the input's size each, overlapping by half
FILL = 0.85  # a found board's extent over its crop's width or height (the larger)
LARGE = 0.8  # a board spanning this much of the input or more gets no second look
MAX_ZOOM = 2  # the crop is at least 1 / MAX_ZOOM of the input's size (4: within noise, val)
PRESENT = 0.5  # P(present) of the whole frame's answer / the crop's pattern that counts
SEARCH_TILES = 1  # tiles searched in a frame where no board was found (GRID * GRID: all)


def tile_views(size: tuple[int, int]) -> np.ndarray:
    """The tiles of an input of `size` (W, H) as views float32 [GRID * GRID, 3] = (u0, v0,
    0.5): a tile's top left corner in input pixels and its scale once enlarged 2x."""
    w, h = size
    u0 = np.linspace(0.0, w / 2, GRID)
    v0 = np.linspace(0.0, h / 2, GRID)
    uu, vv = np.meshgrid(u0, v0, indexing="xy")
    return np.stack([uu.ravel(), vv.ravel(), np.full(uu.size, 0.5)], 1).astype(np.float32)


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


def view_input(image: np.ndarray, view: np.ndarray, detail: np.ndarray | None) -> np.ndarray:
    """The second look's input at a view (u0, v0, s) of the frame, float32 [3, H, W]: the
    frame's pixels [u0, u0 + s W) x [v0, v0 + s H) resized to the input's size, cut from
    `detail` (the frame at twice the input size, `detail_of`) where there is one, else from
    the input `image` [3, H, W] (area where it shrinks, bicubic where it enlarges). Input
    pixel (u, v) is frame pixel (u0 + (u + 0.5) s - 0.5, v0 + (v + 0.5) s - 0.5) either way;
    u0, v0, s W and s H are whole input pixels (`closer_view`, `tile_views`)."""
    _, h, w = image.shape
    source, k = (image, 1) if detail is None else (detail, 2)
    x0, y0 = k * int(round(view[0])), k * int(round(view[1]))
    cw, ch = k * int(round(view[2] * w)), k * int(round(view[2] * h))
    crop = source[:, y0 : y0 + ch, x0 : x0 + cw]
    if (cw, ch) == (w, h):
        return np.ascontiguousarray(crop)
    shrink = cw > w
    out = cv2.resize(
        np.ascontiguousarray(crop.transpose(1, 2, 0)),
        (w, h),
        interpolation=cv2.INTER_AREA if shrink else cv2.INTER_CUBIC,
    )
    return np.ascontiguousarray(np.clip(out, 0.0, 1.0).transpose(2, 0, 1))


def closer_view(corners: np.ndarray, size: tuple[int, int]) -> np.ndarray | None:
    """Corners [4, 2] in input pixels of an input of `size` (W, H) -> the view (u0, v0, s),
    float32 [3], of the crop the board fills to `FILL` of its width or height, centred on it
    and kept inside the input, at most `MAX_ZOOM` x enlarged; s is a multiple of 1 / gcd(W, H)
    and (u0, v0) whole pixels, so that the crop is whole pixels of the input and of the detail
    (`view_input`). None: the board spans `LARGE` or more (or its corners are not finite)."""
    w, h = size
    lo, hi = corners.min(0), corners.max(0)
    span = float(max((hi[0] - lo[0]) / w, (hi[1] - lo[1]) / h))
    if not np.all(np.isfinite(corners)) or span >= LARGE:
        return None
    step = math.gcd(w, h)
    s = min(max(math.ceil(span / FILL * step), math.ceil(step / MAX_ZOOM)), step) / step
    centre = (lo + hi) / 2
    u0 = float(np.clip(round(centre[0] - s * w / 2), 0, w - s * w))
    v0 = float(np.clip(round(centre[1] - s * h / 2), 0, h - s * h))
    return np.array([u0, v0, s], np.float32)


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
    search: bool | Sequence[bool] = True,
    focal: np.ndarray | None = None,
    detail: list[np.ndarray | None] | None = None,
    search_tiles: int = SEARCH_TILES,
) -> Answer:
    """The whole-frame answer of `model` on float32 [N, 3, H, W] in [0, 1] (and its pixel
    aspect [N] and the known focal lengths [N], `PoseModel.run`), with the zoom pass where
    it applies (module doc; `search`, for all images or per image: also in the
    `search_tiles` tiles nearest the corners' guess of the images where no board was found,
    1 to `GRID` * `GRID`; `detail`: per image
    its frame at twice the input size, or None, `detail_of`) -> `Answer` (probabilities
    [N, 9], corners [N, 4, 2] in input pixels, pattern [N]). A model without `view` and
    `pattern` (`PoseModel.zooms`) gives its whole-frame answer."""
    if not 1 <= search_tiles <= GRID * GRID:
        raise ValueError(f"search_tiles: 1 to {GRID * GRID}, got {search_tiles}")
    whole = model.run(batch, pixel_aspect, focal=focal)
    if not model.zooms or whole.corners is None or whole.pattern is None:
        return whole
    tiles = tile_views(model.input_size)
    owners: list[int] = []
    looks: list[np.ndarray] = []
    for i, (p_absent, corners) in enumerate(
        zip(whole.probabilities[:, 0], whole.corners, strict=True)
    ):
        if p_absent < PRESENT:
            view = closer_view(corners, model.input_size)
            chosen = [] if view is None else [view]
        elif search if isinstance(search, bool) else search[i]:
            chosen = list(tiles[search_order(corners, tiles, model.input_size)[:search_tiles]])
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
    views = np.stack(looks)
    crops = np.stack(
        [view_input(batch[i], v, sharp[i]) for i, v in zip(owners, views, strict=True)]
    )
    second = model.run(crops, aspect, views, fx)
    assert second.corners is not None and second.pattern is not None  # model.zooms
    probs, corners, pattern = (
        a.copy() for a in (whole.probabilities, whole.corners, whole.pattern)
    )
    flat = None if whole.undistorted is None else whole.undistorted.copy()
    owner = np.asarray(owners)
    for i in np.unique(owner):
        rows = np.flatnonzero(owner == i)
        best = rows[np.argmax(second.pattern[rows])]
        if second.pattern[best] >= max(PRESENT, whole.pattern[i]):
            probs[i], corners[i], pattern[i] = (
                second.probabilities[best],
                second.corners[best],
                second.pattern[best],
            )
            if flat is not None and second.undistorted is not None:
                flat[i] = second.undistorted[best]
    return Answer(probs, corners, pattern, flat)
