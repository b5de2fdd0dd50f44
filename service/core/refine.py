"""The object's corners refined at the photo's own resolution: its texture aligned to the photo.

The corner network reads a 160 x 120 input, so its corners are good to about half an input
pixel: 4 px of a 1280 x 720 photo. Here the object's front-on texture is aligned to the photo
itself by a homography, started from those corners (OpenCV's ECC, `cv2.findTransformECC`,
coarse to fine over a pyramid):

    crop      the photo around the start corners (a margin of `MARGIN` of the object's
              extent), reduced by area to bring the object to at most `MAX_EXTENT_PX`, and
              resampled as a pinhole sees it through the lens: the camera's (`CameraLens`,
              OpenCV's coefficients) where known, else one radial coefficient
              (`RadialLens`, the corner network's division model)
    half turn the texture compared with the crop in both half-turn orders of the start
              corners (the network reads the order from a 160 x 120 input): the better
              correlation starts
    pyramid   ECC from the coarsest level (the object about `COARSE_PX` wide) to the finest,
              each level started from the one before; pixels outside the photo do not count
    features  where the alignment correlates less than `GOOD_SCORE`, again from the
              texture's SIFT features matched in the photo around the start
              (`feature_start`)
    blur      the photo's blur read from the texture blurred that correlates best; a
              blurred photo is aligned again at the finest level with the texture blurred
              alike (`_photo_blur`)
    lens      where the lens is not known, its radial coefficient fitted to the texture's
              features followed into the photo (Lucas-Kanade), then aligned through
              (`fit_radial_lens`)
    checks    kept only where ECC converged, correlates better than the start, and moved no
              corner more than `MAX_SHIFT` of the object's extent; else the start is kept

Frames and units: image pixels (u, v), origin at the top-left pixel's centre; the texture
in its own pixels, its corners in the object's order (`service.core.frame.CORNER_ORDER`:
bottom-left, bottom-right, top-right, top-left of the front-on texture).
"""

from __future__ import annotations

import math
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Literal, Protocol

import cv2
import numpy as np

from service.core.pose import Camera

#: The crop around the start corners, as a share of the object's extent on each side.
MARGIN = 0.15
#: The least share of the object's area the photo must show to align it (a board cut by the
#: frame's edge keeps the rest).
MIN_SEEN = 0.2
#: The object's extent (px) the finest level works at: larger objects are aligned on a
#: reduced crop (the texture's detail, not the photo's, then bounds the precision).
MAX_EXTENT_PX = 240
#: The object's extent (px) at the pyramid's coarsest level.
COARSE_PX = 60
#: The crop's lens map is computed every this many crop px (bilinear between).
MAP_STEP = 8
#: The radial lens fit (`fit_radial_lens`), in units of kappa (W/2)^2 (W the photo's longer
#: side; webcams and phones about -0.3 to 0.1): the range it searches and the values of
#: its grid.
LENS_RANGE, LENS_GRID = (-0.8, 0.4), 13
#: The texture features the lens fit follows into the photo (at most), the least it needs,
#: and Lucas-Kanade's window px.
TRACK_POINTS, MIN_TRACKED, TRACK_WINDOW = 80, 12, 15
#: How near px a followed feature must come back to where it started, followed back.
TRACK_RETURN_PX = 0.3
#: The least the fitted lens must lower the features' mean squared distance (px^2) from one
#: homography, below the guess's, to be worth an alignment through it: less is the features'
#: own noise (lens-free renders: 0.00-0.05; the ChArUco val frames, real webcam lenses:
#: 0.1-2.4).
LENS_MIN_FIT_GAIN_PX2 = 0.05
#: The least gain in correlation a fitted lens must bring over the start's: less is noise
#: (a head-on view of a lens-free photo gains 0.0002, the ChArUco val frames 0.01-0.05).
LENS_MIN_GAIN = 0.002
#: The refined corners' noise per coordinate, px of the photo, as the pose's focal estimate
#: and cell take it (the ChArUco val frames at 1280x720: 1.0 px median error against their
#: labels with the camera's lens known, 1.6 px with the lens fitted).
REFINED_NOISE_PX = 1.0
#: Objects smaller than this (px) are not aligned.
MIN_EXTENT_PX = 16
#: The Gaussian smoothing ECC applies to both images at each level (taps).
GAUSS_TAPS = 5
#: A refinement that moves a corner by more than this share of the extent is refused.
MAX_SHIFT = 0.25
#: A coarse level that moves a corner further than this share of the object's extent ends
#: the alignment: the finer levels refine where it went, and it would be refused (`MAX_SHIFT`)
#: (a photo without the object pays one level; at `MAX_SHIFT` itself a val book render at
#: blur 3 was lost that the finer levels bring back; docs/decisions.md).
GIVE_UP_SHIFT = 2 * MAX_SHIFT
#: ECC's iterations per level and its convergence threshold on the correlation's increment.
ITERATIONS, EPSILON = 20, 1e-4
#: ECC's iterations where the start is already close (the alignment through a fitted lens).
REALIGN_ITERATIONS = 8
#: The blurs (Gaussian sigma px at the crop's scale) a photo's blur is read among (0: sharp):
#: one, heavy. A second at 2 px aligned mildly blurred photos once more for nothing (the
#: same answers on the validation sets: docs/decisions.md) at ~4 ms a photo.
PHOTO_BLURS = (3.5,)
#: The least correlation of a refined alignment (good ones of the ChArUco val frames: 0.78-0.97,
#: alignments onto the wrong place: up to 0.3).
MIN_SCORE = 0.5
#: An alignment from the network's corners that correlates less than this is tried again from
#: the texture's features matched in the photo (`feature_start`), and the better one kept.
GOOD_SCORE = 0.7
#: How far the shifted starts of a weak start are searched (`_shifted_start`), and the
#: texture's likeness to itself measured (`Texture.self_similarity`): this share of the
#: texture's extent.
SHIFT_SEARCH = 0.2
#: A texture this self-similar (`Texture.self_similarity`) may lock onto itself shifted: a
#: weak start is also aligned from the shifted starts (the chessboard: 1.0; the ChArUco
#: board, 0.66, and the book, 0.47, are not: there it would cost 1.2-1.5x the time of a
#: 1280x720 ChArUco frame for no frame of the validation sets).
SELF_SIMILAR = 0.8
#: Feature matching: the photo's longer side is reduced to this (px), the ratio test's
#: threshold, the RANSAC reprojection threshold (px of the reduced photo), the least inliers.
FEATURE_SIDE, RATIO, RANSAC_PX, MIN_INLIERS = 640, 0.75, 4.0, 12
#: The features are searched around the network's corners (`FeatureSearch` "near"): their
#: bounding box widened by this share of their extent on each side (the whole photo took
#: twice the search's time on the book's false positives; the val answers were the same).
FEATURE_MARGIN = 0.5
#: Where `refine_corners` searches the texture's features: around the start corners, in the
#: whole photo (corners that mark no place: of an object the network missed, or of a zero-shot
#: network), or not at all.
FeatureSearch = Literal["near", "photo", "off"]


#: Sizes of a texture kept resized (`Texture.at_extent`), and the lock of all their caches.
RESIZED_KEPT = 16
_RESIZED_LOCK = threading.Lock()


@dataclass(frozen=True)
class Texture:
    """An object's front-on texture for alignment: grey float32 [h, w] in [0, 1]."""

    grey: np.ndarray

    @classmethod
    def of_rgb(cls, rgb: np.ndarray) -> Texture:
        """RGB uint8 [h, w, 3] -> the texture."""
        grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32) / np.float32(255.0)
        return cls(grey)

    @property
    def corners(self) -> np.ndarray:
        """The texture's corners [4, 2] in its pixels, in the object's corner order."""
        h, w = self.grey.shape
        return np.array([[-0.5, h - 0.5], [w - 0.5, h - 0.5], [w - 0.5, -0.5], [-0.5, -0.5]])

    @cached_property
    def features(self) -> tuple[np.ndarray, np.ndarray] | None:
        """SIFT keypoints (x, y) [K, 2] px and descriptors float32 [K, 128] of the texture at
        `FEATURE_SIDE` (computed once), or None where it has too few of them."""
        image = self.at_extent(FEATURE_SIDE)
        points, descriptors = _sift(np.clip(image * 255.0 + 0.5, 0, 255).astype(np.uint8))
        if descriptors is None or len(points) < MIN_INLIERS:
            return None
        scale = max(self.grey.shape) / max(image.shape)
        return (points + 0.5) * scale - 0.5, descriptors

    @cached_property
    def self_similarity(self) -> float:
        """How well the texture correlates with itself shifted (by `SHIFT_SEARCH` of its
        extent at most, `SHIFT_SEARCH` / 4 at least) or half turned and shifted: its inner
        part (a `SHIFT_SEARCH` / 2 margin off) matched (`cv2.matchTemplate`) in it, at an
        extent of `COARSE_PX` x 2 (computed once). A chessboard: 1 (half turned and a square
        off, its inside is the same); a ChArUco board 0.66; a book cover 0.47."""
        t = self.at_extent(2 * COARSE_PX)
        h, w = t.shape
        m = max(1, round(SHIFT_SEARCH * max(w, h)))
        inner = t[m // 2 : h - m // 2, m // 2 : w - m // 2]
        best = -1.0
        for other in (t, t[::-1, ::-1]):
            padded = cv2.copyMakeBorder(other, m, m, m, m, cv2.BORDER_REPLICATE)
            scores = cv2.matchTemplate(padded, inner, cv2.TM_CCOEFF_NORMED)
            if other is t:  # the texture on itself: not within a quarter of the search
                ys, xs = np.indices(scores.shape)
                c = (np.array(scores.shape) - 1) / 2
                scores[np.hypot(ys - c[0], xs - c[1]) < m / 4] = -1.0
            best = max(best, float(scores.max()))
        return best

    @cached_property
    def _resized(self) -> OrderedDict[tuple[int, int], np.ndarray]:
        return OrderedDict()

    def at_extent(self, extent_px: float) -> np.ndarray:
        """The texture resized so that its longer side is `extent_px` (area average down,
        bilinear up); read-only, the last `RESIZED_KEPT` sizes kept (a large picture takes
        ~0.7 ms to resize, and most photos ask for the same sizes: `MAX_EXTENT_PX` and its
        pyramid)."""
        h, w = self.grey.shape
        f = extent_px / max(w, h)
        size = (max(8, round(w * f)), max(8, round(h * f)))
        found = self._resized.get(size)
        if found is None:
            interpolation = cv2.INTER_AREA if f < 1 else cv2.INTER_LINEAR
            found = cv2.resize(self.grey, size, interpolation=interpolation)
            found.setflags(write=False)
            with _RESIZED_LOCK:
                self._resized[size] = found
                while len(self._resized) > RESIZED_KEPT:
                    self._resized.popitem(last=False)
        return found


@dataclass(frozen=True)
class Features:
    """Points of the texture and where the photo shows them: `uv` [K, 2] in units of the
    texture's width and height from its top-left edge (x right, y down), `seen` [K, 2] px of
    the photo (its lens not undone)."""

    uv: np.ndarray
    seen: np.ndarray


@dataclass(frozen=True)
class Refinement:
    """A refinement's answer: the corners [4, 2] px of the photo as seen and as a pinhole
    camera sees them (the same where no lens is known; the start's, unchanged, where not
    refined), the alignment's correlation at the start and at the end (-1..1; the start's
    where not refined), whether the start's order was half turned, and why it was not
    refined (None where it was); the lens the pinhole corners undo: the one given, or
    (`fit_lens`) the radial lens the alignment fitted; and (`fit_lens`) the texture's
    features it followed into the photo (`Features`), which calibrate a camera."""

    corners: np.ndarray
    pinhole: np.ndarray
    start_score: float
    score: float
    turned: bool
    reason: str | None
    elapsed_ms: float
    lens: Lens | None = None
    features: Features | None = None

    @property
    def refined(self) -> bool:
        """Whether the corners are the alignment's (else the start's)."""
        return self.reason is None


def extent(corners: np.ndarray) -> float:
    """The object's extent in px: the longest side or diagonal of its corners [4, 2]."""
    q = np.asarray(corners, np.float64)
    return float(max(np.linalg.norm(q[i] - q[j]) for i in range(4) for j in range(i + 1, 4)))


def image_centre(size: tuple[int, int]) -> tuple[float, float]:
    """The centre (x, y) px of an image of `size` (W, H), pixel centres at integers."""
    return ((size[0] - 1) / 2.0, (size[1] - 1) / 2.0)


def scaled_camera(camera: Camera, factor: float) -> Camera:
    """`camera` for its image reduced by `factor` (pixel (u, v) of the reduced image is
    ((u + 0.5) f - 0.5, (v + 0.5) f - 0.5) of the full one): focal lengths / f, the principal
    point moved alike, the distortion (of normalised coordinates) the same."""
    if factor == 1:
        return camera
    K = camera.matrix
    w, h = camera.size
    size = (max(1, math.ceil(w / factor)), max(1, math.ceil(h / factor)))
    cx, cy = ((K[0, 2] + 0.5) / factor - 0.5, (K[1, 2] + 0.5) / factor - 0.5)
    return Camera(K[0, 0] / factor, size, K[1, 1] / factor, cx, cy, camera.dist)


class Lens(Protocol):
    """A lens's distortion in px of its image: where a pinhole would see points, and back."""

    def undistort(self, points: np.ndarray) -> np.ndarray:
        """Points [N, 2] px as the image shows them -> where a pinhole sees them."""
        ...

    def distort(self, points: np.ndarray) -> np.ndarray:
        """Points [N, 2] px where a pinhole sees them -> where the image shows them."""
        ...

    def reduced(self, factor: float) -> Lens:
        """The lens in px of its image reduced by `factor` (pixel centres kept)."""
        ...


@dataclass(frozen=True)
class CameraLens:
    """A calibrated camera's lens: OpenCV's distortion coefficients (`camera.dist`)."""

    camera: Camera

    def undistort(self, points: np.ndarray) -> np.ndarray:
        q = np.asarray(points, np.float64).reshape(-1, 1, 2)
        K = self.camera.matrix
        return cv2.undistortPoints(q, K, self.camera.coefficients, P=K).reshape(-1, 2)

    def distort(self, points: np.ndarray) -> np.ndarray:
        q = np.asarray(points, np.float64).reshape(-1, 2)
        K = self.camera.matrix
        rays = np.column_stack([(q - K[:2, 2]) / [K[0, 0], K[1, 1]], np.ones(len(q))])
        zero = np.zeros(3)
        seen, _ = cv2.projectPoints(rays, zero, zero, K, self.camera.coefficients)
        return seen.reshape(-1, 2)

    def reduced(self, factor: float) -> CameraLens:
        return CameraLens(scaled_camera(self.camera, factor))


@dataclass(frozen=True)
class RadialLens:
    """One radial coefficient about `centre` (x, y) px, the division model the corner network
    fits: x_u = c + (x_d - c) / (1 + kappa |x_d - c|^2), kappa in px^-2 (< 0: barrel)."""

    centre: tuple[float, float]
    kappa: float

    @classmethod
    def fitted(
        cls, seen: np.ndarray, pinhole: np.ndarray, centre: tuple[float, float]
    ) -> RadialLens:
        """The kappa that maps the points `seen` [N, 2] px to `pinhole` [N, 2] px best
        (least squares of x_d - x_u = kappa r_d^2 (x_u - c))."""
        c = np.asarray(centre, np.float64)
        d, u = np.asarray(seen, np.float64) - c, np.asarray(pinhole, np.float64) - c
        basis = (d * d).sum(1, keepdims=True) * u
        denominator = float((basis * basis).sum())
        kappa = float(((d - u) * basis).sum()) / denominator if denominator > 0 else 0.0
        return cls(centre, kappa if math.isfinite(kappa) else 0.0)

    def undistort(self, points: np.ndarray) -> np.ndarray:
        c = np.asarray(self.centre, np.float64)
        d = np.asarray(points, np.float64).reshape(-1, 2) - c
        out: np.ndarray = c + d / (1.0 + self.kappa * (d * d).sum(1, keepdims=True))
        return out

    def distort(self, points: np.ndarray) -> np.ndarray:
        """The division model's exact inverse, r_d = 2 r_u / (1 + sqrt(1 - 4 kappa r_u^2))
        (clamped where a pincushion has no inverse), as the network's `Lens.distort_uv`."""
        c = np.asarray(self.centre, np.float64)
        u = np.asarray(points, np.float64).reshape(-1, 2) - c
        root = np.sqrt(np.maximum(1.0 - 4.0 * self.kappa * (u * u).sum(1, keepdims=True), 0.0))
        out: np.ndarray = c + u * 2.0 / (1.0 + root)
        return out

    def reduced(self, factor: float) -> RadialLens:
        cx, cy = ((v + 0.5) / factor - 0.5 for v in self.centre)
        return RadialLens((cx, cy), self.kappa * factor * factor)


@dataclass(frozen=True)
class _Crop:
    """A region of the pinhole image at `scale` crop px per image px: crop pixel (x, y) is
    pinhole image pixel origin + (x, y) / scale; `grey` float32 [h, w] in [0, 1] and the mask
    of the pixels the photo has, uint8 [h, w]."""

    grey: np.ndarray
    mask: np.ndarray
    origin: np.ndarray
    scale: float

    def to_crop(self, points: np.ndarray) -> np.ndarray:
        return (np.asarray(points, np.float64) - self.origin) * self.scale

    def to_image(self, points: np.ndarray) -> np.ndarray:
        return np.asarray(points, np.float64) / self.scale + self.origin


def _crop(grey: np.ndarray, pinhole: np.ndarray, lens: Lens | None, scale: float) -> _Crop:
    """The crop around the pinhole corners [4, 2] px of the photo `grey` uint8 [H, W] (a
    `MARGIN` of their extent around them) as a pinhole sees it (`lens` undone; None: the
    photo is a pinhole's), at `scale`: the photo's region reduced by the scale first (area
    average: no aliasing), then resampled through the lens (computed
    every `MAP_STEP` crop px, bilinear between: a lens is smooth). ValueError where the
    photo shows less than `MIN_SEEN` of the object's area."""
    margin = MARGIN * extent(pinhole)
    origin = pinhole.min(0) - margin
    w, h = (np.ceil((pinhole.max(0) + margin - origin) * scale)).astype(int)
    gw, gh = w // MAP_STEP + 2, h // MAP_STEP + 2
    xs, ys = np.meshgrid(np.arange(gw) * MAP_STEP, np.arange(gh) * MAP_STEP)
    flat = np.column_stack([xs.ravel(), ys.ravel()]) / scale + origin
    seen = (flat if lens is None else lens.distort(flat)).reshape(gh, gw, 2)
    H, W = grey.shape
    lo = np.maximum(np.floor(seen.reshape(-1, 2).min(0)) - 1, 0).astype(int)
    hi = np.minimum(np.ceil(seen.reshape(-1, 2).max(0)) + 2, [W, H]).astype(int)
    if np.any(hi - lo < 8):
        raise ValueError("the object lies outside the photo")
    region = grey[lo[1] : hi[1], lo[0] : hi[0]]
    f = np.ones(2)  # region px per photo px, along x and y
    if scale < 1:
        full = np.array([region.shape[1], region.shape[0]])
        reduced = np.maximum(np.round(full * scale), 1).astype(int)
        region = cv2.resize(region, tuple(reduced), interpolation=cv2.INTER_AREA)
        f = reduced / full
    coarse = ((seen - lo + 0.5) * f - 0.5).astype(np.float32)
    up = np.array([[1.0 / MAP_STEP, 0.0, 0.0], [0.0, 1.0 / MAP_STEP, 0.0]])
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    maps = cv2.warpAffine(coarse, up, (w, h), flags=flags, borderMode=cv2.BORDER_REPLICATE)
    crop = cv2.remap(region, maps, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    rh, rw = region.shape
    mx, my = maps[..., 0], maps[..., 1]
    inside = (mx >= 0) & (mx <= rw - 1) & (my >= 0) & (my <= rh - 1)
    quad = np.zeros((h, w), np.uint8)  # the object in the crop, the margin left out
    cv2.fillPoly(quad, [np.round((pinhole - origin) * scale).astype(np.int32)], 1)
    area = max(int(np.count_nonzero(quad)), 1)
    if np.count_nonzero(inside & (quad > 0)) < MIN_SEEN * area:
        raise ValueError("the object lies outside the photo")
    return _Crop(_unit(crop), inside.astype(np.uint8) * 255, origin, scale)


def _unit(grey: np.ndarray) -> np.ndarray:
    """uint8 [h, w] -> float32 [h, w] in [0, 1]."""
    return grey.astype(np.float32) / np.float32(255.0)


def _level(points: np.ndarray, factor: float) -> np.ndarray:
    """Pixels [N, 2] -> pixels of the image reduced by `factor` (pixel centres kept)."""
    return (np.asarray(points, np.float64) + 0.5) / factor - 0.5


def _homography(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    return cv2.getPerspectiveTransform(src.astype(np.float32), dst.astype(np.float32))


def _score(template: np.ndarray, crop: _Crop, H: np.ndarray) -> float:
    """The correlation of `template` with the crop warped onto it by H (template px -> crop
    px), over the pixels the photo has; -1 where too few of them are left."""
    h, w = template.shape
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    warped = cv2.warpPerspective(crop.grey, H, (w, h), flags=flags)
    valid = cv2.warpPerspective(
        crop.mask, H, (w, h), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP
    )
    if np.count_nonzero(valid) < MIN_SEEN * valid.size:
        return -1.0
    try:
        return float(cv2.computeECC(template, warped, valid))
    except cv2.error:  # a plain region: no correlation to speak of
        return -1.0


class _OverBudget(Exception):
    """The refinement's time budget ran out."""


def _align(
    texture: Texture,
    crop: _Crop,
    start: np.ndarray,
    extent_px: float,
    deadline: float,
    finest_only: bool = False,
    iterations: int = ITERATIONS,
    blur_px: float = 0.0,
) -> tuple[np.ndarray, float]:
    """ECC from the corners [4, 2] px of the crop `start`, coarse to fine (`finest_only`:
    the crop's own level alone with at most `iterations`, for a start already close) -> the
    refined corners [4, 2] px of the crop and the final correlation. A coarse level where
    ECC fails is skipped (the next starts where it would have); one that moves a corner
    further than `GIVE_UP_SHIFT` of `extent_px` ends the alignment there (the caller
    refuses it); cv2.error where the finest fails, _OverBudget where `deadline`
    (`time.perf_counter()`) passes between two levels."""
    levels = (
        1 if finest_only else max(1, min(5, 1 + int(math.log2(max(extent_px / COARSE_PX, 1.0)))))
    )
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, iterations, EPSILON)
    corners, score = start, -1.0
    for level in reversed(range(levels)):
        if time.perf_counter() > deadline:
            raise _OverBudget
        factor = 2.0**level
        template = _blurred(texture.at_extent(extent_px / factor), blur_px / factor)
        size = (
            max(8, round(crop.grey.shape[1] / factor)),
            max(8, round(crop.grey.shape[0] / factor)),
        )
        image = cv2.resize(crop.grey, size, interpolation=cv2.INTER_AREA) if level else crop.grey
        mask = cv2.resize(crop.mask, size, interpolation=cv2.INTER_NEAREST) if level else crop.mask
        tex = Texture(template).corners
        H0 = _homography(tex, _level(corners, factor)).astype(np.float32)
        try:
            score, H = cv2.findTransformECC(
                template, image, H0, cv2.MOTION_HOMOGRAPHY, criteria, mask, GAUSS_TAPS
            )
        except cv2.error:
            if level == 0:
                raise
            continue  # a coarse level that loses the detail (a chessboard's squares): skipped
        moved = cv2.perspectiveTransform(tex.reshape(-1, 1, 2), np.asarray(H, np.float64))
        corners = (moved.reshape(4, 2) + 0.5) * factor - 0.5
        if level and np.linalg.norm(corners - start, axis=1).max() > GIVE_UP_SHIFT * extent_px:
            break
    return corners, float(score)


def _blurred(grey: np.ndarray, sigma_px: float) -> np.ndarray:
    """float32 [h, w] blurred by a Gaussian of `sigma_px` (the same below 0.3 px)."""
    if sigma_px < 0.3:
        return grey
    return cv2.GaussianBlur(grey, (0, 0), sigma_px, borderType=cv2.BORDER_REPLICATE)


def _photo_blur(texture: Texture, crop: _Crop, corners: np.ndarray) -> float:
    """The Gaussian sigma px (of `PHOTO_BLURS`, tried in turn while the correlation grows)
    of the texture blurred that correlates best with the crop at the aligned corners [4, 2]
    px of the crop: the photo's own blur."""
    template = texture.at_extent(extent(corners))
    H = _homography(Texture(template).corners, corners)
    best, best_score = 0.0, _score(template, crop, H)
    for sigma in PHOTO_BLURS:
        score = _score(_blurred(template, sigma), crop, H)
        if score <= best_score:
            break
        best, best_score = sigma, score
    return best


def _sift(grey: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """uint8 [H, W] -> SIFT keypoints (x, y) [K, 2] px and descriptors [K, 128] (or None)."""
    sift = cv2.SIFT_create(nfeatures=2000)  # type: ignore[attr-defined]
    keypoints, descriptors = sift.detectAndCompute(grey, None)
    return np.array([k.pt for k in keypoints], np.float64).reshape(-1, 2), descriptors


def feature_start(
    grey: np.ndarray, texture: Texture, near: np.ndarray | None = None
) -> np.ndarray | None:
    """The object's corners [4, 2] px of the photo `grey` uint8 [H, W] from the texture's
    SIFT features matched in it (ratio test, RANSAC homography), or None where fewer than
    `MIN_INLIERS` agree: a start where the network's corners are far off. With `near`
    (corners [4, 2] px, at least `MIN_EXTENT_PX` apart: else they mark no region), only the
    region around them (`FEATURE_MARGIN`) is searched, at the whole photo's resolution."""
    ours = texture.features
    if ours is None:
        return None
    f = min(1.0, FEATURE_SIDE / max(grey.shape))
    origin = np.zeros(2)
    if near is not None and np.isfinite(near).all() and extent(near) >= MIN_EXTENT_PX:
        margin = FEATURE_MARGIN * extent(near)
        lo = np.maximum(np.floor(near.min(0) - margin), 0).astype(int)
        hi = np.minimum(np.ceil(near.max(0) + margin) + 1, [grey.shape[1], grey.shape[0]])
        grey, origin = grey[lo[1] : int(hi[1]), lo[0] : int(hi[0])], lo.astype(np.float64)
    if min(grey.shape) * f < 8:
        return None
    small = grey if f == 1.0 else cv2.resize(grey, None, fx=f, fy=f, interpolation=cv2.INTER_AREA)
    points, descriptors = _sift(small)
    if descriptors is None or len(points) < MIN_INLIERS:
        return None
    pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(ours[1], descriptors, k=2)
    good = [m[0] for m in pairs if len(m) == 2 and m[0].distance < RATIO * m[1].distance]
    if len(good) < MIN_INLIERS:
        return None
    src = ours[0][[m.queryIdx for m in good]]
    dst = points[[m.trainIdx for m in good]]
    H, inliers = cv2.findHomography(src, dst, cv2.RANSAC, RANSAC_PX)
    if H is None or int(inliers.sum()) < MIN_INLIERS:
        return None
    small_corners = cv2.perspectiveTransform(texture.corners.reshape(-1, 1, 2), H).reshape(4, 2)
    scale = np.array([small.shape[1] / grey.shape[1], small.shape[0] / grey.shape[0]])
    corners: np.ndarray = (small_corners + 0.5) / scale - 0.5 + origin
    return corners if np.isfinite(corners).all() else None


@dataclass(frozen=True)
class _Aligned:
    """One alignment's pinhole corners [4, 2] px of the photo, its correlation, the start's,
    whether the start was half turned, why it is refused (None: it holds) and the crop it
    aligned in."""

    pinhole: np.ndarray
    score: float
    start_score: float
    turned: bool
    refused: str | None
    crop: _Crop | None = None


def _aligned_from(
    grey: np.ndarray, start: np.ndarray, texture: Texture, lens: Lens | None, deadline: float
) -> _Aligned:
    """The texture aligned to the photo `grey` uint8 [H, W] from the pinhole corners [4, 2]
    px `start`, in the half-turn order that correlates better; where that start correlates
    less than `GOOD_SCORE` and the texture is self-similar (`Texture.self_similarity` >=
    `SELF_SIMILAR`), also from each order's best shifted start (`_shifted_start`), and the
    best alignment kept. A chessboard's half turn inverts its colours, as does a shift by
    one square: a start about a square off correlates weakly in both orders, and the wrong
    one aligns onto the squares one square off."""
    size, nan = extent(start), float("nan")
    if not np.isfinite(start).all() or size < MIN_EXTENT_PX:
        return _Aligned(start, nan, nan, False, "the object is too small to align")
    scale = min(1.0, MAX_EXTENT_PX / size)
    try:
        crop = _crop(grey, start, lens, scale)
    except ValueError as exc:
        return _Aligned(start, nan, nan, False, str(exc))
    full = texture.at_extent(size * scale)
    tex = Texture(full).corners
    orders = [crop.to_crop(start), crop.to_crop(np.roll(start, 2, 0))]
    starts = [_score(full, crop, _homography(tex, q)) for q in orders]
    turned = starts[1] > starts[0]
    start_score = starts[int(turned)]
    first = _aligned_once(texture, crop, orders[int(turned)], size, start_score, deadline)
    held = [] if isinstance(first, str) else [(first[1], first[0], turned)]
    if start_score < GOOD_SCORE and texture.self_similarity >= SELF_SIMILAR:
        for turn in (turned, not turned):  # each order from its best shifted start too
            begin = _shifted_start(full, crop, orders[int(turn)])
            if turn == turned and np.allclose(begin, orders[int(turned)]):
                continue  # no shift: the first alignment again
            found = _aligned_once(texture, crop, begin, size, start_score, deadline)
            if not isinstance(found, str):
                held.append((found[1], found[0], turn))
    if not held:  # the first start's reason: why the network's corners stand
        return _Aligned(start, start_score, start_score, turned, str(first))
    score, corners, turn = max(held, key=lambda h: h[0])
    return _Aligned(crop.to_image(corners), score, start_score, turn, None, crop)


def _shifted_start(template: np.ndarray, crop: _Crop, start: np.ndarray) -> np.ndarray:
    """The corners [4, 2] px of the crop `start` shifted along the texture's axes by the
    shift, up to `SHIFT_SEARCH` of the texture's extent, at which `template` correlates
    best with the crop (`cv2.matchTemplate` over the crop warped onto the texture's frame
    widened by that much) -> those corners [4, 2] px of the crop."""
    h, w = template.shape
    m = max(1, round(SHIFT_SEARCH * max(w, h)))
    tex = Texture(template).corners
    widened = _homography(tex, start) @ np.array([[1.0, 0, -m], [0, 1.0, -m], [0, 0, 1.0]])
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    seen = cv2.warpPerspective(
        crop.grey, widened, (w + 2 * m, h + 2 * m), flags=flags, borderMode=cv2.BORDER_REPLICATE
    )
    scores = cv2.matchTemplate(seen, template, cv2.TM_CCOEFF_NORMED)
    dy, dx = np.unravel_index(int(np.argmax(scores)), scores.shape)
    moved = (tex + [dx, dy]).reshape(-1, 1, 2)  # in the widened frame: dx - m, dy - m shifted
    return cv2.perspectiveTransform(moved, widened).reshape(4, 2)


def _aligned_once(
    texture: Texture,
    crop: _Crop,
    begin: np.ndarray,
    size: float,
    start_score: float,
    deadline: float,
) -> tuple[np.ndarray, float] | str:
    """One alignment in `crop` from its corners [4, 2] px `begin` (the object `size` px in
    the photo; its better start correlating `start_score`) -> (the corners [4, 2] px of the
    crop, their correlation), or why it is refused."""
    try:
        moved, score = _align(texture, crop, begin, size * crop.scale, deadline)
    except cv2.error:
        return "the alignment did not converge"
    except _OverBudget:
        return "the alignment ran out of its time budget"
    shift = float(np.linalg.norm(moved - begin, axis=1).max()) / crop.scale
    if not np.isfinite(moved).all() or shift > MAX_SHIFT * size:
        return "the alignment moved the corners too far"
    if score < max(start_score, MIN_SCORE):
        return "the alignment correlates too little"
    blur = _photo_blur(texture, crop, moved)
    if blur > 0:  # a blurred photo: aligned again at its level with the texture blurred alike
        try:
            again, s = _align(
                texture, crop, moved, size * crop.scale, deadline, True, ITERATIONS, blur
            )
            if s > score:
                moved, score = again, s
        except (cv2.error, _OverBudget):
            pass
    return moved, score


def _realigned(
    grey: np.ndarray, start: np.ndarray, lens: RadialLens, texture: Texture, deadline: float
) -> _Aligned:
    """The alignment through `lens` from the pinhole corners [4, 2] px `start` (already
    close: the crop's own level, `REALIGN_ITERATIONS`)."""
    size, nan = extent(start), float("nan")
    scale = min(1.0, MAX_EXTENT_PX / size)
    try:
        crop = _crop(grey, start, lens, scale)
        at = crop.to_crop(start)
        moved, score = _align(texture, crop, at, size * scale, deadline, True, REALIGN_ITERATIONS)
    except (ValueError, cv2.error):
        return _Aligned(start, nan, nan, False, "the alignment did not converge")
    except _OverBudget:
        return _Aligned(start, nan, nan, False, "the alignment ran out of its time budget")
    return _Aligned(crop.to_image(moved), score, nan, False, None, crop)


def _tracked_points(aligned: _Aligned, lens: RadialLens, texture: Texture) -> Features | None:
    """Where the texture's own corner features lie in the photo, around an alignment
    (pinhole corners under `lens`, in its crop): the crop warped onto the texture by the
    alignment's homography, its brightness and contrast matched to the texture's, and the
    texture's `TRACK_POINTS` strongest features (Shi-Tomasi) followed into it (Lucas-Kanade,
    kept where they follow back to within `TRACK_RETURN_PX`) -> `Features`, or None where
    fewer than `MIN_TRACKED` are followed."""
    crop = aligned.crop
    if crop is None:
        return None
    template = texture.at_extent(extent(aligned.pinhole) * crop.scale)
    h, w = template.shape
    H = _homography(Texture(template).corners, crop.to_crop(aligned.pinhole))
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    warped = cv2.warpPerspective(crop.grey, H, (w, h), flags=flags)
    seen = cv2.warpPerspective(crop.mask, H, (w, h), flags=cv2.INTER_NEAREST | flags) > 0
    if np.count_nonzero(seen) < MIN_SEEN * seen.size:
        return None
    # Lucas-Kanade is not invariant to brightness and contrast as the correlation is
    gain = template[seen].std() / max(float(warped[seen].std()), 1e-6)
    matched = (warped - warped[seen].mean()) * gain + template[seen].mean()
    ours, theirs = (np.clip(a * 255.0 + 0.5, 0, 255).astype(np.uint8) for a in (template, matched))
    found = cv2.goodFeaturesToTrack(ours, TRACK_POINTS, 0.02, max(w, h) / 15.0)
    if found is None or len(found) < MIN_TRACKED:
        return None
    window = (TRACK_WINDOW, TRACK_WINDOW)
    moved, status, _ = cv2.calcOpticalFlowPyrLK(ours, theirs, found, None, winSize=window)
    back, again, _ = cv2.calcOpticalFlowPyrLK(theirs, ours, moved, None, winSize=window)
    src, dst = found.reshape(-1, 2), moved.reshape(-1, 2)
    inside = np.all((dst >= 0) & (dst <= [w - 1, h - 1]), axis=1)
    at = np.clip(dst.round().astype(int), 0, [w - 1, h - 1])
    keep = (
        (status.ravel() == 1)
        & (again.ravel() == 1)
        & (np.linalg.norm(back.reshape(-1, 2) - src, axis=1) < TRACK_RETURN_PX)
        & inside
        & seen[at[:, 1], at[:, 0]]
    )
    if np.count_nonzero(keep) < MIN_TRACKED:
        return None
    in_crop = cv2.perspectiveTransform(dst[keep].reshape(-1, 1, 2), H).reshape(-1, 2)
    return Features((src[keep] + 0.5) / [w, h], lens.distort(crop.to_image(in_crop)))


def _homography_fit(features: Features, lens: RadialLens) -> tuple[np.ndarray, float]:
    """The least-squares homography of the features' texture points (`uv`) onto where the
    photo shows them undone by `lens`, and their mean squared distance px^2 from it."""
    pinhole = lens.undistort(features.seen)
    H, _ = cv2.findHomography(features.uv, pinhole, 0)
    if H is None:
        return np.eye(3), math.inf
    fit = cv2.perspectiveTransform(features.uv.reshape(-1, 1, 2), H).reshape(-1, 2)
    return H, float(((fit - pinhole) ** 2).sum(1).mean())


def _normalised(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points [..., N, 2] moved to their centroid and scaled to a mean distance of sqrt(2)
    (Hartley) -> (those points, the scale [...] px per unit)."""
    centred = points - points.mean(-2, keepdims=True)
    spread = np.sqrt((centred**2).sum(-1).mean(-1)) / np.sqrt(2.0)
    return centred / spread[..., None, None], spread


def homography_costs(uv: np.ndarray, pinholes: np.ndarray) -> np.ndarray:
    """The mean squared distance px^2 of each of `pinholes` [K, N, 2] px from the
    least-squares homography (normalised DLT) of `uv` [N, 2] onto it -> [K]: the K fits at
    once (the lens fit's grid)."""
    src, _ = _normalised(np.asarray(uv, np.float64))
    dst, spread = _normalised(np.asarray(pinholes, np.float64))
    k, n = dst.shape[:2]
    x, y = (np.broadcast_to(c, (k, n)) for c in src.T)
    u, v = dst[..., 0], dst[..., 1]
    one, zero = np.ones((k, n)), np.zeros((k, n))
    rows_u = np.stack([x, y, one, zero, zero, zero, -u * x, -u * y, -u], -1)
    rows_v = np.stack([zero, zero, zero, x, y, one, -v * x, -v * y, -v], -1)
    a = np.concatenate([rows_u, rows_v], 1)  # [K, 2N, 9]
    _, vectors = np.linalg.eigh(np.swapaxes(a, 1, 2) @ a)  # ascending eigenvalues
    h = vectors[..., 0].reshape(k, 3, 3)  # the least one's: A h ~ 0
    mapped = h @ np.stack([x[0], y[0], one[0]])  # [K, 3, N]
    fit = np.swapaxes(mapped[:, :2] / mapped[:, 2:], 1, 2)  # [K, N, 2]
    return np.asarray(((fit - dst) ** 2).sum(-1).mean(-1) * spread**2)


def fit_radial_lens(
    grey: np.ndarray,
    aligned: _Aligned,
    lens: RadialLens,
    texture: Texture,
    deadline: float,
    points: Features | None,
) -> tuple[_Aligned, RadialLens]:
    """The radial lens about `lens.centre` under which the texture's features `points`,
    followed into the photo `grey` uint8 [H, W] (`_tracked_points`), lie on one homography
    best: kappa
    (W/2)^2 (W the photo's longer side) on a grid of `LENS_GRID` values over `LENS_RANGE`,
    then the vertex of the parabola through the best and its neighbours; where it fits the
    features better than `lens` by `LENS_MIN_FIT_GAIN_PX2`, the alignment is repeated through
    it from that homography's corners, and kept where it correlates better than `aligned` by
    `LENS_MIN_GAIN` -> (alignment, lens). Where too few features are followed, or time runs
    out, `aligned` and `lens` stay."""
    if points is None or time.perf_counter() > deadline:
        return aligned, lens
    unit = (0.5 * max(grey.shape)) ** 2
    grid = np.linspace(*LENS_RANGE, LENS_GRID)
    pinholes = [RadialLens(lens.centre, k / unit).undistort(points.seen) for k in grid]
    costs = homography_costs(points.uv, np.stack(pinholes))
    best = int(np.clip(np.argmin(costs), 1, LENS_GRID - 2))
    c0, c1, c2 = costs[best - 1 : best + 2]
    curve = c0 - 2 * c1 + c2
    step = grid[1] - grid[0]
    offset = 0.5 * (c0 - c2) / curve if curve > 0 else 0.0
    fitted = RadialLens(lens.centre, (grid[best] + step * float(np.clip(offset, -1, 1))) / unit)
    H, cost = _homography_fit(points, fitted)
    if _homography_fit(points, lens)[1] - cost < LENS_MIN_FIT_GAIN_PX2:
        return aligned, lens  # the guess fits the features as well: nothing to align again
    h, w = texture.grey.shape
    edges = (texture.corners + 0.5) / [w, h]  # the texture's corners in units of uv
    start = cv2.perspectiveTransform(edges.reshape(-1, 1, 2), H)
    found = _realigned(grey, start.reshape(4, 2), fitted, texture, deadline)
    if found.refused is not None or found.score < aligned.score + LENS_MIN_GAIN:
        return aligned, lens
    return replace(found, start_score=aligned.start_score, turned=aligned.turned), fitted


def refine_corners(
    grey: np.ndarray,
    corners: np.ndarray,
    texture: Texture,
    lens: Lens | None = None,
    budget_ms: float = 1000.0,
    fit_lens: bool = False,
    features: FeatureSearch = "near",
) -> Refinement:
    """The photo `grey` uint8 [H, W], the object's corners [4, 2] px as seen (the
    network's), its texture and the lens of the photo (None: a pinhole's) -> the corners
    aligned to the photo (`Refinement`; the start's where no alignment holds).

    The alignment starts from the network's corners; where it correlates less than
    `GOOD_SCORE` and time is left of `budget_ms`, also from the texture's features matched in
    the photo (`feature_start`: around the network's corners with `features` "near", in the
    whole photo with "photo", not with "off"), and the better of the two is kept. With
    `fit_lens` (a lens not known: `lens` a `RadialLens` guess, or None), the radial lens is
    fitted too (`fit_radial_lens`)."""
    t0 = time.perf_counter()
    deadline = t0 + budget_ms / 1000.0
    points: Features | None = None
    seen = np.asarray(corners, np.float64).reshape(4, 2)
    pinhole = seen if lens is None else lens.undistort(seen)
    best = _aligned_from(grey, pinhole, texture, lens, deadline)
    weak = best.refused is not None or best.score < GOOD_SCORE
    if features != "off" and weak and time.perf_counter() < deadline:
        found = feature_start(grey, texture, seen if features == "near" else None)
        if found is not None:
            start = found if lens is None else lens.undistort(found)
            other = _aligned_from(grey, start, texture, lens, deadline)
            if other.refused is None and (best.refused is not None or other.score > best.score):
                best = other
    if fit_lens and best.refused is None:
        centre = image_centre((grey.shape[1], grey.shape[0]))
        guess = lens if isinstance(lens, RadialLens) else RadialLens(centre, 0.0)
        if lens is None:  # the alignment's corners under the guess: the same, kappa 0
            best = replace(best, pinhole=guess.undistort(best.pinhole))
        points = _tracked_points(best, guess, texture)
        best, lens = fit_radial_lens(grey, best, guess, texture, deadline, points)
    ms = 1000.0 * (time.perf_counter() - t0)
    if best.refused is not None:
        start_score = best.start_score
        return Refinement(
            seen, pinhole, start_score, start_score, best.turned, best.refused, ms, lens
        )
    out = best.pinhole if lens is None else lens.distort(best.pinhole)
    return Refinement(
        out, best.pinhole, best.start_score, best.score, best.turned, None, ms, lens, points
    )
