"""Synthetic views of a profile's object (SPEC section 5): camera drawing and rendering.

* `draw_views`: camera centres from the profile's lattice for given classes, look-at targets
  (variant "C": the object centre; "noC": uniform in a 6 x 6 cm square around it; "free":
  anywhere in the central 45 % of the field of view), rolls and
  focal-length scales from the profile's ranges.
* `Renderer`: warps the texture (with a drawn white margin and frame) onto a background with
  the homography H = A [r1 r2 t] composed with texture pixel -> object plane; bilinear
  `cv2.warpPerspective` of an RGBA mip-map level whose alpha edge is anti-aliased, blended onto
  the background; then (jitter on) a hand-like occluder on the board's edge, radial lens
  distortion (the profile's k1 range), motion blur and photometric jitter (gain, contrast,
  gamma, grey, noise, JPEG), and the data set's SPEC 6 blur.
* `render_view`: one plain image in memory for a camera centre / target / roll.

Frames: object frame of SPEC section 2 (cm); images RGB uint8 [H, W, 3], size = (W, H).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache

import cv2
import numpy as np

from service.core.blur import blur_image
from service.core.frame import object_corners, texture_to_object
from service.core.geometry import (
    homography_from_pose,
    intrinsics,
    look_at,
    project_points,
    translation,
)
from service.core.profile import Profile, load_profile
from service.core.regions import pose_class
from train.synth.background import BackgroundPool

#: Look-at targets: C (object centre), noC (SPEC: a 6 x 6 cm square around it), free (the
#: object anywhere in the central part of the frame, as in hand-held calibration photos).
VARIANTS = ("C", "noC", "free")
NOC_HALF_CM = 3.0  # noC targets: uniform in [-3, 3] x [-3, 3] cm around the object centre
FREE_FRAME = 0.45  # free targets: up to this fraction of the half field of view off-centre
N_BORDER_VARIANTS = 12
P_OCCLUDE = 0.25  # share of object images with a hand-like occluder (jitter on)
P_DISTORT = 0.7  # share of images with radial lens distortion (when the profile has a range)
P_MOTION = 0.15  # share of images with linear motion blur (jitter on)
MOTION_PX_160 = (2.0, 7.0)  # motion blur length range in px at 160 px wide
_RAMP = np.linspace(0.0, 1.0, 256, dtype=np.float32)[:, None]  # grey levels / 255
PAD = 2  # transparent texels around each mip level: the anti-aliased alpha edge


def occlude_edge(image: np.ndarray, quad: np.ndarray, rng: np.random.Generator) -> None:
    """Draw (in place) a hand-like occluder over a random point of the board's outline
    `quad` (4, 2) px: an anti-aliased ellipse of skin or sleeve colour, 8-25 % of the
    outline's size, as the fingers holding the board in the real photographs."""
    if len(quad) != 4:  # no outline: a corner behind the camera (`Renderer.homography`)
        return
    i = int(rng.integers(4))
    point = quad[i] + rng.uniform(0.1, 0.9) * (quad[(i + 1) % 4] - quad[i])
    if not np.all(np.isfinite(point)):
        return
    extent = float(np.linalg.norm(np.ptp(quad, axis=0)))
    a = max(2.0, extent * rng.uniform(0.08, 0.25))
    axes = (int(round(a)), int(round(a * rng.uniform(0.3, 0.6))))
    skin = rng.random() < 0.6
    base = np.array([205, 150, 120]) if skin else rng.integers(20, 230, 3)
    colour = tuple(int(c) for c in np.clip(base * rng.uniform(0.6, 1.15), 0, 255))
    centre = (int(round(point[0])), int(round(point[1])))
    cv2.ellipse(image, centre, axes, float(rng.uniform(0, 180)), 0, 360, colour, -1, cv2.LINE_AA)


def distort_points(uv: np.ndarray, k1: float, A: np.ndarray) -> np.ndarray:
    """Ideal pixels (N, 2) -> pixels seen through radial distortion `k1` (OpenCV model
    x_d = x_u (1 + k1 r_u^2) in coordinates normalised by intrinsics A (3, 3))."""
    x = (np.asarray(uv, dtype=float) - A[:2, 2]) / np.diag(A)[:2]
    x = x * (1.0 + k1 * np.sum(x * x, axis=1, keepdims=True))
    return x * np.diag(A)[:2] + A[:2, 2]


def lens_distort(image: np.ndarray, k1: float, A: np.ndarray) -> np.ndarray:
    """The pinhole image `image` (RGB uint8 [H, W, 3], intrinsics A (3, 3)) as a lens with
    radial distortion `k1` sees it (the model of `distort_points`).

    Each output pixel samples the ideal image at x_u, solved from x_d by fixed-point
    iteration; where that falls outside (barrel distortion, corners) the image is mirrored.
    """
    h, w = image.shape[:2]
    (fx, fy), (cx, cy) = np.diag(A)[:2], A[:2, 2]
    u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    xd, yd = (u - cx) / fx, (v - cy) / fy
    xu, yu = xd, yd
    for _ in range(3):
        factor = 1.0 + k1 * (xu * xu + yu * yu)
        xu, yu = xd / factor, yd / factor
    map_x = (xu * fx + cx).astype(np.float32)
    map_y = (yu * fy + cy).astype(np.float32)
    return cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101)


def motion_blur(image: np.ndarray, length_px: float, angle_deg: float) -> np.ndarray:
    """Linear motion blur of `length_px` pixels along `angle_deg` (normalised line kernel)."""
    k = max(3, int(math.ceil(length_px)) | 1)
    kernel = np.zeros((k, k), np.float32)
    c = (k - 1) / 2
    dx, dy = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    half = length_px / 2
    p0 = (round((c - dx * half) * 16), round((c - dy * half) * 16))
    p1 = (round((c + dx * half) * 16), round((c + dy * half) * 16))
    cv2.line(kernel, p0, p1, 1.0, 1, cv2.LINE_AA, shift=4)
    return cv2.filter2D(image, -1, kernel / max(float(kernel.sum()), 1e-6))


@dataclass(frozen=True)
class View:
    """A camera for one render: centre and look-at target (3,) cm, roll (deg), focal scale
    and radial lens distortion k1 (0: pinhole)."""

    centre: np.ndarray
    target: np.ndarray
    roll_deg: float = 0.0
    focal_scale: float = 1.0
    k1: float = 0.0

    def object_corners(self, profile: Profile, size: tuple[int, int]) -> np.ndarray:
        """Pixels (4, 2) of the object corners in `CORNER_ORDER` in an
        image of `size` (W, H), lens distortion included."""
        A = intrinsics(size, self.focal_scale)
        R = look_at(self.centre, self.target, np.radians(self.roll_deg))
        corners = object_corners(profile.width_cm, profile.height_cm, z=True)
        uv = project_points(A, R, translation(R, self.centre), corners)
        return distort_points(uv, self.k1, A) if self.k1 else uv


def draw_views(
    profile: Profile, classes: np.ndarray, variant: str, rng: np.random.Generator
) -> list[View]:
    """One view per entry of `classes` (N,) in 1..8: a lattice point of that class (uniform),
    its target per `variant`, roll, focal scale and (with probability P_DISTORT) lens
    distortion k1 uniform in the profile's ranges."""
    if variant not in VARIANTS:
        raise ValueError(f"variant must be one of {', '.join(VARIANTS)}, got {variant!r}")
    lattice = profile.lattice()
    lattice_classes = pose_class(lattice, profile.geometry.z_split_cm)
    by_class = {k: lattice[lattice_classes == k] for k in range(1, 9)}
    views = []
    for k in np.asarray(classes, dtype=int):
        points = by_class[int(k)]
        if len(points) == 0:
            raise ValueError(f"profile {profile.name!r} has no lattice point in class {k}")
        centre = points[rng.integers(len(points))]
        target = np.zeros(3)
        focal_scale = float(rng.uniform(*profile.focal_scale))
        if variant == "noC":
            target[:2] = rng.uniform(-NOC_HALF_CM, NOC_HALF_CM, 2)
        elif variant == "free":
            # Half the field of view at the object's distance (SPEC camera: tan = 0.388 / scale
            # horizontally, 3/4 of it vertically), an approximation for oblique views.
            half = float(np.linalg.norm(centre)) * 0.388 / focal_scale * FREE_FRAME
            target[:2] = rng.uniform(-1, 1, 2) * half * np.array([1.0, 0.75])
        roll = float(rng.uniform(*profile.roll_deg))
        k1 = 0.0
        if profile.distortion_k1 != (0.0, 0.0) and rng.random() < P_DISTORT:
            k1 = float(rng.uniform(*profile.distortion_k1))
        views.append(View(centre.copy(), target, roll, focal_scale, k1))
    return views


def _rounded_alpha(shape: tuple[int, int], radius: float) -> np.ndarray:
    """uint8 [h, w] alpha of a rectangle with anti-aliased rounded corners of `radius` px."""
    h, w = shape
    alpha = np.zeros((h, w), np.uint8)
    r = int(round(radius))
    if r < 1:
        alpha[:] = 255
        return alpha
    cv2.rectangle(alpha, (r, 0), (w - 1 - r, h - 1), 255, -1)
    cv2.rectangle(alpha, (0, r), (w - 1, h - 1 - r), 255, -1)
    for cx, cy in ((r, r), (w - 1 - r, r), (r, h - 1 - r), (w - 1 - r, h - 1 - r)):
        cv2.circle(alpha, (cx, cy), r, 255, -1, cv2.LINE_AA)
    return alpha


@dataclass(frozen=True)
class _Level:
    """One mip level: padded RGBA uint8 and the map padded pixel -> object plane (3, 3)."""

    rgba: np.ndarray
    to_object: np.ndarray


class BoardImage:
    """The texture framed by a white margin and an outer frame, as an RGBA mip-map.

    `margin_cm`, `frame_cm`: widths; `frame_grey`: frame grey level. Level 0 has the
    texture's own resolution; each next level halves it (area average).
    """

    def __init__(
        self,
        profile: Profile,
        texture: np.ndarray,
        margin_cm: float,
        frame_cm: float,
        frame_grey: int,
        min_side: int = 8,
    ) -> None:
        th, tw = texture.shape[:2]
        ppc = tw / profile.width_cm  # texels per cm
        m, f = int(round(margin_cm * ppc)), int(round(frame_cm * ppc))
        b = m + f
        board = np.empty((th + 2 * b, tw + 2 * b, 4), np.uint8)
        board[..., 3] = _rounded_alpha(board.shape[:2], 1.5 * f)
        board[..., :3] = frame_grey
        board[f : f + th + 2 * m, f : f + tw + 2 * m, :3] = profile.border.margin_rgb
        board[b : b + th, b : b + tw, :3] = texture
        tex_to_obj = texture_to_object((tw, th), profile.width_cm, profile.height_cm)
        board_to_tex = np.array([[1.0, 0, -b], [0, 1.0, -b], [0, 0, 1.0]])
        self.levels: list[_Level] = []
        level = board
        while True:
            lh, lw = level.shape[:2]
            sx, sy = board.shape[1] / lw, board.shape[0] / lh
            # padded level pixel (p, q) -> level-0 board pixel: ((p - PAD + 0.5) s - 0.5).
            to_board = np.array(
                [[sx, 0, (0.5 - PAD) * sx - 0.5], [0, sy, (0.5 - PAD) * sy - 0.5], [0, 0, 1.0]]
            )
            padded = cv2.copyMakeBorder(level, PAD, PAD, PAD, PAD, cv2.BORDER_REPLICATE)
            padded[:PAD, :, 3] = padded[-PAD:, :, 3] = 0
            padded[:, :PAD, 3] = padded[:, -PAD:, 3] = 0
            self.levels.append(_Level(padded, tex_to_obj @ board_to_tex @ to_board))
            if min(lh, lw) // 2 < min_side:
                break
            level = cv2.resize(level, (lw // 2, lh // 2), interpolation=cv2.INTER_AREA)
        w = profile.width_cm + 2 * b / ppc
        h = profile.height_cm + 2 * b * profile.height_cm / th
        #: The board's outline (4, 3) cm in the object plane, margin and frame included.
        self.outline_cm = object_corners(w, h, z=True)
        self.texels = float(board.shape[0] * board.shape[1])  # at level 0

    def level_for(self, texels_per_px: float) -> _Level:
        """The mip level with at most ~1.4 texels per output pixel (the finest if magnified)."""
        index = max(0, math.floor(math.log2(max(texels_per_px, 1.0) / 1.4) + 1))
        return self.levels[min(index, len(self.levels) - 1)]


class Renderer:
    """Renders views of one profile at one image `size` (W, H).

    `jitter` switches the photometric jitter; `backgrounds` defaults to the shipped pool.
    Border variants (`borders` of them: margin / frame widths and grey) are drawn from the
    profile's ranges with `seed`, so a renderer is deterministic given its seed and the
    per-image rng.
    """

    def __init__(
        self,
        profile: Profile,
        size: tuple[int, int],
        jitter: bool = True,
        backgrounds: BackgroundPool | None = None,
        seed: int = 0,
        texture: np.ndarray | None = None,
        borders: int = N_BORDER_VARIANTS,
    ) -> None:
        self.profile, self.size, self.jitter = profile, (int(size[0]), int(size[1])), jitter
        self.backgrounds = backgrounds if backgrounds is not None else BackgroundPool.default(size)
        # `texture` (RGB uint8, covering the profile's width x height): the object's picture
        # where it is not the profile's file (the texture bank of `train.synth.stream`)
        texture = profile.texture_rgb() if texture is None else texture
        rng = np.random.default_rng(seed)
        border = profile.border
        self.boards = [
            BoardImage(
                profile,
                texture,
                float(rng.uniform(*border.margin_cm)),
                float(rng.uniform(*border.frame_cm)),
                int(rng.integers(border.frame_grey[0], border.frame_grey[1] + 1)),
            )
            for _ in range(borders)
        ]
        self.noise = np.clip(rng.normal(128, 16, (2 * size[1], 2 * size[0], 3)), 0, 255).astype(
            np.uint8
        )

    def homography(self, view: View, board: BoardImage) -> tuple[np.ndarray, _Level, np.ndarray]:
        """Image-from-texel homography (3, 3) for `view`, the mip level it samples and the
        board's outline in the image (4, 2) px (camera in front of the object plane)."""
        A = intrinsics(self.size, view.focal_scale)
        R = look_at(view.centre, view.target, np.radians(view.roll_deg))
        t = translation(R, view.centre)
        H_obj = homography_from_pose(A, R, t)
        quad = project_points(A, R, t, board.outline_cm)
        if np.min(board.outline_cm @ R[2] + t[2]) <= 1e-6:  # a corner behind the camera
            quad = np.array([[0.0, 0.0], [self.size[0], self.size[1]]])
        area_px = abs(cv2.contourArea(quad.astype(np.float32)))
        level = board.level_for(math.sqrt(board.texels / max(area_px, 1e-9)))
        return H_obj @ level.to_object, level, quad

    def draw_object(self, background: np.ndarray, view: View, board: BoardImage) -> np.ndarray:
        """`background` RGB uint8 [H, W, 3] with the object of `board` seen from `view`."""
        return self._composite(background, view, board)[0]

    def _composite(
        self, background: np.ndarray, view: View, board: BoardImage
    ) -> tuple[np.ndarray, np.ndarray]:
        """(image, board outline (4, 2) px); only the outline's bounding box is warped."""
        H, level, quad = self.homography(view, board)
        w, h = self.size
        (qx0, qy0), (qx1, qy1) = quad.min(axis=0).tolist(), quad.max(axis=0).tolist()
        x0, y0 = max(0, min(w, math.floor(qx0) - 1)), max(0, min(h, math.floor(qy0) - 1))
        x1, y1 = max(0, min(w, math.ceil(qx1) + 2)), max(0, min(h, math.ceil(qy1) + 2))
        if x1 <= x0 or y1 <= y0:
            return background, quad
        shift = np.array([[1.0, 0, -x0], [0, 1.0, -y0], [0, 0, 1.0]])
        warped = cv2.warpPerspective(
            level.rgba,
            shift @ H,
            (x1 - x0, y1 - y0),
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REPLICATE,
        )
        alpha = cv2.extractChannel(warped, 3).astype(np.float32) * np.float32(1 / 255)
        rgb = cv2.cvtColor(warped, cv2.COLOR_RGBA2RGB)
        out = background.copy()
        out[y0:y1, x0:x1] = cv2.blendLinear(rgb, out[y0:y1, x0:x1], alpha, 1.0 - alpha)
        return out, quad

    def render(
        self,
        view: View | None,
        blur: int,
        rng: np.random.Generator,
        avoid: frozenset[int] = frozenset(),
        background: np.ndarray | None = None,
    ) -> np.ndarray:
        """One data set image: background (`background`, else drawn from the pool, not
        from its sources `avoid`, `BackgroundPool.sample`), + the object unless `view` is None
        (class 0), photometric jitter if enabled, then SPEC blur `blur` -> RGB uint8
        [H, W, 3]."""
        image = self.backgrounds.sample(rng, avoid) if background is None else background
        if view is not None:
            board = self.boards[int(rng.integers(len(self.boards)))]
            image, quad = self._composite(image, view, board)
            if self.jitter and rng.random() < P_OCCLUDE:
                occlude_edge(image, quad, rng)
        if view is not None and view.k1:
            image = lens_distort(image, view.k1, intrinsics(self.size, view.focal_scale))
        if self.jitter and rng.random() < P_MOTION:
            length = rng.uniform(*MOTION_PX_160) * self.size[0] / 160
            image = motion_blur(image, length, float(rng.uniform(0, 180)))
        if self.jitter:
            image = self.photometric(image, rng)
        return blur_image(image, blur, self.size)

    def photometric(self, image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Gain / contrast / gamma / brightness (one LUT), grey (30 %), Gaussian noise
        (sigma 0-8 grey levels), JPEG (quality 35-95, 25 %) of an RGB uint8 image."""
        u = rng.random(6)
        gamma = math.exp(math.log(0.6) + u[0] * math.log(1.6 / 0.6))  # 0.6 .. 1.6
        gain = (0.9 + 0.2 * u[1:4]).astype(np.float32)  # per channel
        contrast, brightness = 0.6 + 0.7 * u[4], -45 + 90 * u[5]
        y = (255 * _RAMP**gamma - 128) * contrast + 128 + brightness
        lut = np.clip(y * gain, 0, 255).astype(np.uint8).reshape(1, 256, 3)
        image = cv2.LUT(image, lut)
        if rng.random() < 0.3:
            image = cv2.cvtColor(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY), cv2.COLOR_GRAY2RGB)
        w, h = self.size
        sigma = rng.uniform(0, 8) / 16
        y0, x0 = rng.integers(h), rng.integers(w)
        noise = self.noise[y0 : y0 + h, x0 : x0 + w]
        image = cv2.addWeighted(image, 1.0, noise, sigma, -128 * sigma)
        if rng.random() < 0.25:
            quality = int(rng.integers(35, 96))
            ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
            decoded = cv2.imdecode(buf, cv2.IMREAD_COLOR)  # channel order is kept as given
            assert ok and decoded is not None  # a JPEG OpenCV has just encoded
            image = decoded
        return image


@cache
def _plain_renderer(profile_path: str, size: tuple[int, int]) -> Renderer:
    profile = load_profile(profile_path)
    grey = np.full((size[1], size[0], 3), 127, np.uint8)
    return Renderer(profile, size, jitter=False, backgrounds=BackgroundPool(size, [grey]))


def render_view(
    profile: Profile,
    size: tuple[int, int],
    centre: np.ndarray,
    target: np.ndarray | None = None,
    roll_deg: float = 0.0,
    focal_scale: float = 1.0,
    background: np.ndarray | None = None,
) -> np.ndarray:
    """Render the object seen from `centre` (3,) cm looking at `target` (default the object
    centre) with `roll_deg`, on `background` (RGB uint8 [H, W, 3], default mid grey), without
    jitter or blur, with the first border variant -> RGB uint8 [H, W, 3] of `size` (W, H)."""
    renderer = _plain_renderer(str(profile.path), tuple(size))
    view = View(
        np.asarray(centre, dtype=float),
        np.zeros(3) if target is None else np.asarray(target, dtype=float),
        roll_deg,
        focal_scale,
    )
    if background is None:
        background = np.full((size[1], size[0], 3), 127, np.uint8)
    return renderer.draw_object(background, view, renderer.boards[0])
