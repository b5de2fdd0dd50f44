"""The texture bank of the generic corner network (`corners-any`): many object pictures.

A texture is the front-on picture of a planar object, RGB uint8 [h, w, 3] (row 0 the top),
and the object's size `width_cm` x `height_cm` (its aspect is the picture's). The bank draws:

* procedural textures (`procedural_texture`): shapes, text, stripes, noise, markers (ArUco),
  checkers, and mixes of them, with random colours; seeded, so a texture is a function of its
  seed;
* photographs the project ships with a licence that allows it (`photo_sources`: the
  scikit-image samples and the real-photo crops under `train/assets/backgrounds/`, README.md
  there), as random crops of random aspect;

never the held-back test textures (`HELD_OUT_PHOTOS`, `HELD_OUT_SEEDS`, `held_out_textures`):
those photographs are not drawn as textures, and the procedural seeds of training
(`TRAIN_SEED_BASE` and up) never reach the test seeds. The objects of the shipped per-object
models (book, ChArUco) are not in the bank either: they are measured zero-shot.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from train.synth.background import BACKGROUNDS_DIR, IMAGE_SUFFIXES

#: Photographs under train/assets/backgrounds/ held back as test textures (never a texture
#: in training; still backgrounds there, as any photo may be).
HELD_OUT_PHOTOS = ("photos/astronaut.jpg", "photos/coffee.jpg", "real/right07-0.jpg")
#: Seeds of the held-back procedural test textures, and the first seed of training's.
HELD_OUT_SEEDS = (900_001, 900_002, 900_003, 900_004, 900_005)
TRAIN_SEED_BASE = 10_000_000
#: Kinds of procedural texture (`procedural_texture`).
KINDS = ("shapes", "text", "stripes", "noise", "markers", "checker", "mix")
#: Side of a procedural texture along its longer side, px.
LONG_SIDE = 320
#: Object sizes drawn: the longer side in cm, and the aspect (short / long side).
LONG_CM = (12.0, 32.0)
ASPECT = (0.45, 1.0)
_WORDS = ("PLANAR", "POSE", "Any", "object", "42", "Lorem", "ipsum", "NOTE", "x7", "ZOOM", "map")


@dataclass(frozen=True)
class Texture:
    """One object: its picture RGB uint8 [h, w, 3], its size in cm and where it came from."""

    rgb: np.ndarray
    width_cm: float
    height_cm: float
    source: str


def _colour(rng: np.random.Generator) -> tuple[int, int, int]:
    c = rng.integers(0, 256, 3)
    return int(c[0]), int(c[1]), int(c[2])


def _shapes(img: np.ndarray, rng: np.random.Generator) -> None:
    """Filled and outlined rectangles, ellipses and polygons, in place."""
    h, w = img.shape[:2]
    for _ in range(int(rng.integers(5, 30))):
        c, colour = rng.integers(0, (w, h)), _colour(rng)
        thick = -1 if rng.random() < 0.6 else int(rng.integers(1, 8))
        kind = rng.integers(3)
        if kind == 0:
            d = rng.integers(5, max(6, w // 3), 2)
            cv2.rectangle(
                img, (int(c[0]), int(c[1])), (int(c[0] + d[0]), int(c[1] + d[1])), colour, thick
            )
        elif kind == 1:
            axes = (int(rng.integers(4, w // 4)), int(rng.integers(4, h // 4)))
            cv2.ellipse(
                img,
                (int(c[0]), int(c[1])),
                axes,
                float(rng.uniform(0, 180)),
                0,
                360,
                colour,
                thick,
                cv2.LINE_AA,
            )
        else:
            pts = (c + rng.normal(0, w / 8, (int(rng.integers(3, 7)), 2))).astype(np.int32)
            if thick < 0:
                cv2.fillPoly(img, [pts], colour, cv2.LINE_AA)
            else:
                cv2.polylines(img, [pts], True, colour, thick, cv2.LINE_AA)


def _text(img: np.ndarray, rng: np.random.Generator) -> None:
    """Lines of words in random fonts, sizes and colours, in place."""
    h, w = img.shape[:2]
    colour = _colour(rng)
    scale = float(rng.uniform(0.5, 2.5))
    y = int(rng.integers(10, 40))
    while y < h:
        words = " ".join(str(rng.choice(_WORDS)) for _ in range(int(rng.integers(1, 5))))
        font = int(rng.choice([0, 1, 2, 3, 4, 6, 7]))
        cv2.putText(
            img,
            words,
            (int(rng.integers(0, w // 3)), y),
            font,
            scale,
            colour,
            int(rng.integers(1, 4)),
            cv2.LINE_AA,
        )
        y += int(30 * scale + rng.integers(0, 30))
        if rng.random() < 0.2:
            colour = _colour(rng)


def _stripes(rng: np.random.Generator, w: int, h: int) -> np.ndarray:
    """Sine or square stripes between two colours at a random angle and period, float [h, w, 3]."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    angle, period = rng.uniform(0, np.pi), rng.uniform(8, 80)
    t = np.sin(2 * np.pi * (np.cos(angle) * xx + np.sin(angle) * yy) / period)
    t = (t > 0).astype(np.float32) if rng.random() < 0.5 else 0.5 + 0.5 * t
    a, b = np.array(_colour(rng), np.float32), np.array(_colour(rng), np.float32)
    return a * (1 - t[..., None]) + b * t[..., None]


def _noise(rng: np.random.Generator, w: int, h: int) -> np.ndarray:
    """Multi-octave value noise in random colours, float [h, w, 3]."""
    out = np.zeros((h, w, 3), np.float32)
    for octave in range(int(rng.integers(1, 3)), 7):
        cells = 2**octave
        small = rng.random((cells, cells, 3), dtype=np.float32)
        out += cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC) / octave
    out = (out - out.min()) / max(float(np.ptp(out)), 1e-6)
    return out * rng.uniform(120, 255) + rng.uniform(0, 100)


def _markers(img: np.ndarray, rng: np.random.Generator) -> None:
    """A grid of ArUco markers (some cells empty), in place."""
    h, w = img.shape[:2]
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_250)
    n = int(rng.integers(1, 5))
    side = min(w, h) // (n + 1)
    for i in range(int(np.ceil(w / side))):
        for j in range(int(np.ceil(h / side))):
            if rng.random() < 0.3:
                continue
            marker = cv2.aruco.generateImageMarker(
                dictionary, int(rng.integers(250)), side * 3 // 4
            )
            x, y = i * side + side // 8, j * side + side // 8
            patch = img[y : y + marker.shape[0], x : x + marker.shape[1]]
            patch[:] = marker[: patch.shape[0], : patch.shape[1], None]


def _checker(rng: np.random.Generator, w: int, h: int) -> np.ndarray:
    """A checker of random square counts and colours, float [h, w, 3]."""
    nx, ny = int(rng.integers(2, 13)), int(rng.integers(2, 13))
    yy, xx = np.mgrid[0:h, 0:w]
    t = ((xx * nx // w + yy * ny // h) % 2).astype(np.float32)[..., None]
    return np.array(_colour(rng), np.float32) * (1 - t) + np.array(_colour(rng), np.float32) * t


def procedural_texture(seed: int) -> Texture:
    """The procedural texture of `seed` (module doc): its kind, size and content all drawn
    from the seed."""
    rng = np.random.default_rng(seed)
    long_cm, aspect = rng.uniform(*LONG_CM), rng.uniform(*ASPECT)
    wide = rng.random() < 0.5
    w_cm, h_cm = (long_cm, long_cm * aspect) if wide else (long_cm * aspect, long_cm)
    w, h = int(round(LONG_SIDE * w_cm / long_cm)), int(round(LONG_SIDE * h_cm / long_cm))
    kind = KINDS[int(rng.integers(len(KINDS)))]
    base = {
        "stripes": _stripes,
        "noise": _noise,
        "checker": _checker,
    }.get(kind)
    img = (
        np.clip(base(rng, w, h), 0, 255).astype(np.uint8)
        if base is not None
        else np.full((h, w, 3), _colour(rng), np.uint8)
    )
    if kind in ("shapes", "mix"):
        _shapes(img, rng)
    if kind in ("text", "mix") or (kind != "markers" and rng.random() < 0.25):
        _text(img, rng)
    if kind == "markers":
        img[:] = 255 if rng.random() < 0.7 else _colour(rng)
        _markers(img, rng)
    return Texture(img, float(w_cm), float(h_cm), f"procedural:{kind}:{seed}")


def photo_sources(held_out: bool = False) -> dict[str, np.ndarray]:
    """The shipped photographs usable as textures, {path under train/assets/backgrounds/:
    RGB uint8}: all but the `HELD_OUT_PHOTOS` (`held_out`: only those)."""
    out = {}
    for path in sorted(p for p in BACKGROUNDS_DIR.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES):
        name = path.relative_to(BACKGROUNDS_DIR).as_posix()
        if (name in HELD_OUT_PHOTOS) != held_out:
            continue
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise ValueError(f"cannot read {path}")
        out[name] = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    return out


def photo_texture(name: str, photo: np.ndarray, rng: np.random.Generator) -> Texture:
    """A random crop (30-100 % of each side) of a photograph as an object picture, its size
    in cm drawn as `procedural_texture`'s, the aspect the crop's."""
    h, w = photo.shape[:2]
    cw, ch = int(w * rng.uniform(0.3, 1.0)), int(h * rng.uniform(0.3, 1.0))
    ratio = ch / cw
    if not ASPECT[0] <= min(ratio, 1 / ratio):  # too elongated: shorten the longer side
        cw, ch = (int(ch / ASPECT[0]), ch) if ratio < 1 else (cw, int(cw / ASPECT[0]))
    x0, y0 = int(rng.integers(w - cw + 1)), int(rng.integers(h - ch + 1))
    crop = photo[y0 : y0 + ch, x0 : x0 + cw]
    f = min(1.0, LONG_SIDE / max(cw, ch))
    crop = cv2.resize(
        crop, (max(8, int(cw * f)), max(8, int(ch * f))), interpolation=cv2.INTER_AREA
    )
    long_cm = float(rng.uniform(*LONG_CM))
    scale = long_cm / max(cw, ch)
    return Texture(np.ascontiguousarray(crop), cw * scale, ch * scale, f"photo:{name}")


class TextureBank:
    """Training textures (module doc): procedural with probability `p_procedural`, else a crop
    of a shipped photograph that is not held back."""

    def __init__(self, p_procedural: float = 0.7) -> None:
        self.p_procedural = p_procedural
        self.photos = photo_sources()

    def draw(self, rng: np.random.Generator) -> Texture:
        """One training texture drawn with `rng`."""
        if not self.photos or rng.random() < self.p_procedural:
            return procedural_texture(TRAIN_SEED_BASE + int(rng.integers(2**40)))
        names = sorted(self.photos)
        name = names[int(rng.integers(len(names)))]
        return photo_texture(name, self.photos[name], rng)


def held_out_textures() -> list[Texture]:
    """The fixed test textures no network is trained on: the procedural `HELD_OUT_SEEDS` and
    the whole `HELD_OUT_PHOTOS` (long side `LONG_SIDE` px, 20 cm)."""
    out = [procedural_texture(seed) for seed in HELD_OUT_SEEDS]
    for name, photo in photo_sources(held_out=True).items():
        h, w = photo.shape[:2]
        f = LONG_SIDE / max(h, w)
        rgb = cv2.resize(photo, (int(w * f), int(h * f)), interpolation=cv2.INTER_AREA)
        out.append(Texture(rgb, 20.0 * w / max(h, w), 20.0 * h / max(h, w), f"photo:{name}"))
    return out


def save_texture(texture: Texture, path: Path) -> None:
    """Write the texture's picture as a PNG (RGB -> BGR on disk)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), cv2.cvtColor(texture.rgb, cv2.COLOR_RGB2BGR)):
        raise OSError(f"cannot write {path}")
