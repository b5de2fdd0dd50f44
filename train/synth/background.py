"""Backgrounds for the renders (SPEC section 5): shipped photographs and procedural textures.

Sources, all RGB uint8:

* `train/assets/backgrounds/photos/`: scikit-image sample photographs (CC0 / public domain);
* `train/assets/backgrounds/real/`: crops of the real chessboard photos that do not contain the
  board (made by `real_photo_crops`, see train/assets/backgrounds/README.md);
* the real corpus's *train* sources (`corpus_backgrounds`): its photos without the board and
  the parts of its board photos outside the board; the val and test sources never;
* procedural textures (value noise, gradients, stripes, blobs, clutter), drawn from a fixed
  seed so every data set sees the same pool.

A `BackgroundPool` keeps them at a working resolution for one output size and returns random
crops (position, scale, mirror) through a single affine warp.
"""

from __future__ import annotations

import csv
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from service.core.dataset import corpus_sources, read_splits
from service.core.frame import object_corners
from service.core.geometry import apply_homography, dlt_homography
from service.core.paths import ASSETS_DIR
from service.core.profile import DEFAULT_PROFILE, load_profile

BACKGROUNDS_DIR = ASSETS_DIR / "backgrounds"
CORPUS_DIR = ASSETS_DIR / "real" / "corpus"
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")
N_PROCEDURAL = 48


def shipped_backgrounds(folder: Path = BACKGROUNDS_DIR) -> list[np.ndarray]:
    """Every image under `folder` (recursively, sorted by path) as RGB uint8 [h, w, 3]."""
    images = []
    for path in sorted(p for p in folder.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES):
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise ValueError(f"cannot read background image {path}")
        images.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
    return images


def shipped_names(folder: Path = BACKGROUNDS_DIR) -> list[str]:
    """The paths under `folder` of `shipped_backgrounds`'s images, in its order."""
    paths = sorted(p for p in folder.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES)
    return [p.relative_to(folder).as_posix() for p in paths]


#: `shows_texture`: ORB features per image, Lowe's ratio, RANSAC reprojection threshold (px of
#: images brought to `MATCH_SIDE` px along the longer side) and the inliers that say "shown"
MATCH_FEATURES, MATCH_RATIO, MATCH_RANSAC_PX, MATCH_INLIERS, MATCH_SIDE = 1000, 0.75, 4.0, 25, 400
#: ... and the share of the texture's area the inliers' convex hull covers at least
MATCH_SPREAD = 0.04


def _grey_for_matching(rgb: np.ndarray) -> np.ndarray:
    """RGB uint8 [h, w, 3] -> grey uint8, the longer side brought to `MATCH_SIDE` px."""
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    f = MATCH_SIDE / max(grey.shape)
    return cv2.resize(
        grey, None, fx=f, fy=f, interpolation=cv2.INTER_AREA if f < 1 else cv2.INTER_LINEAR
    )


class TextureMatcher:
    """Whether background images show an object's texture (RGB uint8 [h, w, 3]), by matching,
    not by name: ORB features of the texture (computed once) matched to the image's with
    Lowe's ratio test, and a homography fitted with RANSAC that keeps at least
    `MATCH_INLIERS` of them. A background that is the texture, a crop of it or a view of it
    passes; an unrelated photo keeps a few chance matches (tests/train/synth/test_textures.py
    pins both)."""

    def __init__(self, texture: np.ndarray) -> None:
        self.orb = cv2.ORB.create(MATCH_FEATURES)
        grey = _grey_for_matching(texture)
        self.keys, self.descriptors = self.orb.detectAndCompute(grey, None)
        self.matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
        self.area = float(grey.shape[0] * grey.shape[1])

    def inliers(self, background: np.ndarray, name: str | None = None) -> int:
        """The matches [0, ...] of the texture in `background` (RGB uint8) that one
        homography explains; `name`: a source whose features are kept for the process
        (`_source_features`: its pixels never change)."""
        kb, db = _source_features(name, background) if name else self._features(background)
        if db is None or self.descriptors is None or len(kb) < 4 or len(self.keys) < 4:
            return 0
        pairs = self.matcher.knnMatch(self.descriptors, db, k=2)
        good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < MATCH_RATIO * p[1].distance]
        if len(good) < MATCH_INLIERS:
            return len(good)
        src = np.array([self.keys[m.queryIdx].pt for m in good], np.float32)
        dst = np.array([kb[m.trainIdx].pt for m in good], np.float32)
        _, mask = cv2.findHomography(src, dst, cv2.RANSAC, MATCH_RANSAC_PX)
        if mask is None:
            return 0
        kept = mask.ravel() > 0
        inside = src[kept]
        # a view of the texture spreads over it and over distinct image features; chance
        # matches bunch (many texture features onto a few of a plain image's)
        spread = cv2.contourArea(cv2.convexHull(inside)) if len(inside) >= 3 else 0.0
        distinct = len({m.trainIdx for m, k in zip(good, kept, strict=True) if k})
        return distinct if spread >= MATCH_SPREAD * self.area else 0

    def shown_in(self, background: np.ndarray, name: str | None = None) -> bool:
        """Whether `background` shows the texture (`MATCH_INLIERS` or more inliers)."""
        return self.inliers(background, name) >= MATCH_INLIERS

    def _features(self, rgb: np.ndarray) -> tuple[Any, np.ndarray | None]:
        return self.orb.detectAndCompute(_grey_for_matching(rgb), None)


#: ORB keypoints and descriptors of the named background sources (shipped photographs,
#: corpus crops), computed once per process: every object's pool matches the same ones.
_SOURCE_FEATURES: dict[str, tuple[Any, np.ndarray | None]] = {}


def _source_features(name: str, rgb: np.ndarray) -> tuple[Any, np.ndarray | None]:
    if name not in _SOURCE_FEATURES:
        orb = cv2.ORB.create(MATCH_FEATURES)
        _SOURCE_FEATURES[name] = orb.detectAndCompute(_grey_for_matching(rgb), None)
    return _SOURCE_FEATURES[name]


def shows_texture(background: np.ndarray, texture: np.ndarray) -> bool:
    """Whether a background image shows the texture (`TextureMatcher`), both RGB uint8."""
    return TextureMatcher(texture).shown_in(background)


def _value_noise(rng: np.random.Generator, size: tuple[int, int]) -> np.ndarray:
    """Multi-octave value noise, float32 [h, w, 3] in [0, 1]."""
    w, h = size
    out = np.zeros((h, w, 3), np.float32)
    for octave in range(1, 6):
        cells = 2**octave
        small = rng.random((cells, cells, 3), dtype=np.float32)
        out += cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC) / octave
    out -= out.min()
    return out / max(float(out.max()), 1e-6)


def procedural_background(rng: np.random.Generator, size: tuple[int, int]) -> np.ndarray:
    """One procedural texture RGB uint8 [h, w, 3] of `size` (W, H): noise, gradient, stripes,
    blobs or clutter, with random colours."""
    w, h = size
    kind = rng.integers(5)
    colours = rng.integers(0, 256, (2, 3)).astype(np.float32)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    if kind == 0:  # value noise between two colours
        t = _value_noise(rng, size)
    elif kind == 1:  # linear gradient at a random angle
        a = rng.uniform(0, 2 * np.pi)
        t = (np.cos(a) * xx + np.sin(a) * yy)[..., None]
        t = np.repeat((t - t.min()) / max(float(np.ptp(t)), 1e-6), 3, axis=2)
    elif kind == 2:  # stripes (sine), random angle and period
        a, period = rng.uniform(0, np.pi), rng.uniform(6, 60)
        t = 0.5 + 0.5 * np.sin(2 * np.pi * (np.cos(a) * xx + np.sin(a) * yy) / period)
        t = np.repeat(t[..., None], 3, axis=2)
    else:
        t = None
    if t is not None:
        img = colours[0] * (1 - t) + colours[1] * t
        return np.clip(img, 0, 255).astype(np.uint8)
    img = np.empty((h, w, 3), np.uint8)
    img[:] = colours[0].astype(np.uint8)
    for _ in range(int(rng.integers(8, 40))):
        colour = tuple(int(c) for c in rng.integers(0, 256, 3))
        centre = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        if kind == 3:  # blobs: filled ellipses
            axes = (int(rng.integers(4, w // 4)), int(rng.integers(4, h // 4)))
            angle = float(rng.uniform(0, 180))
            cv2.ellipse(img, centre, axes, angle, 0, 360, colour, -1, cv2.LINE_AA)
        else:  # clutter: rectangles and lines, like an office scene
            other = (int(rng.integers(0, w)), int(rng.integers(0, h)))
            if rng.random() < 0.5:
                cv2.rectangle(img, centre, other, colour, -1)
            else:
                cv2.line(img, centre, other, colour, int(rng.integers(1, 6)), cv2.LINE_AA)
    return cv2.GaussianBlur(img, (0, 0), float(rng.uniform(0.5, 2.0)))


def procedural_backgrounds(n: int, size: tuple[int, int], seed: int = 0) -> list[np.ndarray]:
    """`n` procedural textures (see `procedural_background`) from a fixed seed."""
    rng = np.random.default_rng(seed)
    return [procedural_background(rng, size) for _ in range(n)]


def board_polygon(
    corners_px: np.ndarray, inner_cm: tuple[float, float], grow_cm: float
) -> np.ndarray:
    """Image polygon (4, 2) px of the board grown by `grow_cm` around its inner-corner grid.

    `corners_px` (4, 2): the inner-grid rectangle corners in `CORNER_ORDER` as
    in train/assets/real/*/labels.csv; `inner_cm` = (width, height) of that grid.
    """
    w, h = inner_cm
    H = dlt_homography(object_corners(w, h), corners_px)
    return apply_homography(H, object_corners(w + 2 * grow_cm, h + 2 * grow_cm))


def free_strips(
    shape: tuple[int, int], polygon: np.ndarray, min_side: int
) -> Iterator[tuple[int, int, int, int]]:
    """Rectangles (x0, y0, x1, y1) px of an image of `shape` (H, W) left, right, above and
    below the polygon's bounding box, with both sides >= `min_side`."""
    h, w = shape
    x0, y0 = np.floor(polygon.min(axis=0)).astype(int)
    x1, y1 = np.ceil(polygon.max(axis=0)).astype(int)
    for rect in ((0, 0, x0, h), (x1, 0, w, h), (0, 0, w, y0), (0, y1, w, h)):
        a, b, c, d = max(rect[0], 0), max(rect[1], 0), min(rect[2], w), min(rect[3], h)
        if c - a >= min_side and d - b >= min_side:
            yield a, b, c, d


def real_photo_crops(
    folder: Path,
    inner_cm: tuple[float, float] = (20.0, 12.5),
    grow_cm: float = 6.0,
    min_side: int = 120,
) -> list[tuple[str, np.ndarray]]:
    """Crops (name, RGB uint8) of the photos of a real set that do not show the board.

    The board is the inner-corner rectangle of labels.csv (corner_x0..corner_y3) grown by
    `grow_cm` (board squares, margin, frame and lens distortion); the crops are the strips
    outside its bounding box whose sides are all >= `min_side` px.
    """
    with (folder / "labels.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    crops = []
    for row in rows:
        corners = np.array([[float(row[f"corner_{a}{i}"]) for a in "xy"] for i in range(4)])
        bgr = cv2.imread(str(folder / row["file"]), cv2.IMREAD_COLOR)
        if bgr is None:
            raise ValueError(f"cannot read {folder / row['file']}")
        polygon = board_polygon(corners, inner_cm, grow_cm)
        for k, (x0, y0, x1, y1) in enumerate(free_strips(bgr.shape[:2], polygon, min_side)):
            name = f"{Path(row['file']).stem}-{k}.png"
            crops.append((name, cv2.cvtColor(bgr[y0:y1, x0:x1], cv2.COLOR_BGR2RGB)))
    return crops


def corpus_backgrounds(corpus: Path = CORPUS_DIR) -> list[np.ndarray]:
    """Backgrounds from the corpus's train sources (splits.toml): every class-0 photo, and
    the strips of the board photos outside the board (their corners are the board's outer
    corners, those of the default profile). Empty when there is no corpus."""
    if not (corpus / "splits.toml").is_file():
        return []
    splits = read_splits(corpus / "splits.toml")
    board = load_profile(DEFAULT_PROFILE)
    board_cm = (board.width_cm, board.height_cm)
    images: list[np.ndarray] = []
    for src in corpus_sources(corpus):
        if splits.get(src.name) != "train":
            continue
        if src.parent.name == "negatives":
            images += shipped_backgrounds(src / "images")
        else:
            images += [crop for _, crop in real_photo_crops(src, board_cm, 3.0, 100)]
    return images


class BackgroundPool:
    """Background sources scaled for output images of `size` (W, H).

    Each source is used at `scales` times the smallest size that covers the output (so a crop
    shows 1/scale of the source's extent), scaled when first drawn and kept; `sample` takes a
    random integer crop of one of them, mirrored half of the time: no resampling per image.
    """

    def __init__(
        self,
        size: tuple[int, int],
        sources: list[np.ndarray],
        scales: tuple[float, ...] = (1.0, 1.3, 1.6, 2.0),
        excluded: tuple[str, ...] = (),
    ) -> None:
        if not sources:
            raise ValueError("no background images")
        self.size = size
        self.sources, self.scales = sources, scales
        self.per_source = len(scales)  # images per source: image i is source i // this
        self.count = len(sources) * len(scales)
        #: names of the sources left out because they show the object (`default`'s `texture`)
        self.excluded = excluded
        self._scaled: dict[int, np.ndarray] = {}

    def image(self, i: int) -> np.ndarray:
        """Image i: source i // `per_source` at scale i % `per_source`, RGB uint8 (scaled
        once, when first drawn)."""
        if i not in self._scaled:
            img, w, h = self.sources[i // self.per_source], *self.size
            f = max(w / img.shape[1], h / img.shape[0]) * self.scales[i % self.per_source]
            out = (max(w, int(round(img.shape[1] * f))), max(h, int(round(img.shape[0] * f))))
            interp = cv2.INTER_AREA if f < 1 else cv2.INTER_LINEAR
            self._scaled[i] = cv2.resize(img, out, interpolation=interp)
        return self._scaled[i]

    @classmethod
    def default(cls, size: tuple[int, int], texture: np.ndarray | None = None) -> BackgroundPool:
        """The shipped photographs and real-photo crops, the corpus's train sources and the
        procedural textures; with the object's `texture` (RGB uint8), without the sources that
        show it (`shows_texture`; their names in `excluded`)."""
        w, h = size
        named = list(zip(shipped_names(), shipped_backgrounds(), strict=True))
        named += [(f"corpus #{i}", im) for i, im in enumerate(corpus_backgrounds())]
        procedural = procedural_backgrounds(N_PROCEDURAL, (2 * w, 2 * h))
        named += [(f"procedural #{i}", im) for i, im in enumerate(procedural)]
        if texture is None:
            return cls(size, [im for _, im in named])
        matcher = TextureMatcher(texture)
        # the procedural textures are drawn per size: not kept by name
        shown = [
            matcher.shown_in(im, None if name.startswith("procedural") else name)
            for name, im in named
        ]
        kept = [im for (_, im), s in zip(named, shown, strict=True) if not s]
        excluded = tuple(name for (name, _), s in zip(named, shown, strict=True) if s)
        return cls(size, kept, excluded=excluded)

    def sample(self, rng: np.random.Generator, avoid: frozenset[int] = frozenset()) -> np.ndarray:
        """A random crop of the output size from a random scaled source (not one of the
        source indices `avoid`), 50 % mirrored: RGB uint8 [H, W, 3]."""
        i = int(rng.integers(self.count))
        while avoid and i // self.per_source in avoid and len(avoid) < self.count:
            i = int(rng.integers(self.count))
        src = self.image(i)
        w, h = self.size
        y0 = int(rng.integers(src.shape[0] - h + 1))
        x0 = int(rng.integers(src.shape[1] - w + 1))
        crop = src[y0 : y0 + h, x0 : x0 + w]
        return cv2.flip(crop, 1) if rng.random() < 0.5 else crop.copy()
