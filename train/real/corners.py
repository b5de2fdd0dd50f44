"""Finding a planar object in a photograph: point correspondences object plane <-> image.

Two detectors, both returning object-plane points (x, y) in cm (object frame, SPEC section 2:
origin at the object centre, +x along its width, +y towards the top of its texture) and the
image pixels (u, v) where they are seen (raw pixels of the photograph, lens distortion included):

* `detect_chessboard`: the inner corners of a chessboard (`cv2.findChessboardCornersSB`, falling
  back to `cv2.findChessboardCorners` + `cv2.cornerSubPix`). The detector's own corner order is
  ambiguous; the object frame is fixed by two rules: the frame is right-handed with the camera
  in front of the board (z > 0), and the square diagonally outside the (-X, -Y) inner corner is
  black (the colour parity rule of train/assets/real/chessboard-stereo/README.md).
* `TextureMatcher`: local features (SIFT or ORB) of the photograph matched to the profile's
  front-on texture (Lowe's ratio test), then a RANSAC homography (`cv2.findHomography`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from service.core.frame import object_corners, texture_to_object
from service.core.geometry import (
    apply_homography,
    camera_centre,
    dlt_homography,
    pose_from_homography,
)

FEATURES = ("sift", "orb")


@dataclass(frozen=True)
class Correspondences:
    """Object-plane points `object_xy` (N, 2) cm seen at raw image pixels `image_uv` (N, 2)."""

    object_xy: np.ndarray
    image_uv: np.ndarray
    method: str


@dataclass(frozen=True)
class ChessboardPattern:
    """A chessboard of `inner_cols` x `inner_rows` inner corners and squares of `square_cm`.

    The inner-corner grid is centred on the object origin; columns run along +x (width).
    """

    inner_cols: int
    inner_rows: int
    square_cm: float

    def grid_xy(self) -> np.ndarray:
        """Object coordinates (rows * cols, 2) cm of the inner corners in detector order,
        row-major, before orientation is fixed: x grows with the column, y with the row."""
        cols, rows = np.meshgrid(np.arange(self.inner_cols), np.arange(self.inner_rows))
        x = (cols - (self.inner_cols - 1) / 2) * self.square_cm
        y = (rows - (self.inner_rows - 1) / 2) * self.square_cm
        return np.column_stack([x.ravel(), y.ravel()]).astype(np.float64)


def to_grey(image: np.ndarray) -> np.ndarray:
    """RGB uint8 [H, W, 3] (or grey [H, W]) -> grey uint8 [H, W]."""
    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)


def _find_grid(grey: np.ndarray, pattern: ChessboardPattern) -> np.ndarray | None:
    """Raw detector output: inner corners (rows * cols, 2) px in the detector's order, or None."""
    size = (pattern.inner_cols, pattern.inner_rows)
    found, corners = cv2.findChessboardCornersSB(grey, size, flags=cv2.CALIB_CB_EXHAUSTIVE)
    if not found:
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        found, corners = cv2.findChessboardCorners(grey, size, flags=flags)
        if not found:
            return None
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 0.01)
        corners = cv2.cornerSubPix(grey, corners, (5, 5), (-1, -1), criteria)
    return corners.reshape(-1, 2).astype(np.float64)


def square_means(grey: np.ndarray, grid_uv: np.ndarray, cols: int, rows: int) -> np.ndarray:
    """Mean grey level (rows - 1, cols - 1) of each inner square, in the detector's order.

    `grid_uv` (rows * cols, 2) are the inner corners, row-major; square (j, i) spans corners
    (j, i) .. (j + 1, i + 1). Each square is sampled bilinearly at 9 points of its middle part.
    """
    g = grid_uv.reshape(rows, cols, 2)
    s = np.array([0.3, 0.5, 0.7])
    a, b = np.meshgrid(s, s)
    a, b = a.ravel()[None, None, :, None], b.ravel()[None, None, :, None]
    p00, p01 = g[:-1, :-1, None], g[:-1, 1:, None]
    p10, p11 = g[1:, :-1, None], g[1:, 1:, None]
    pts = (1 - a) * (1 - b) * p00 + a * (1 - b) * p01 + (1 - a) * b * p10 + a * b * p11
    samples = cv2.remap(
        grey.astype(np.float32),
        pts[..., 0].astype(np.float32).reshape(1, -1),
        pts[..., 1].astype(np.float32).reshape(1, -1),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    return samples.reshape(rows - 1, cols - 1, -1).mean(axis=2)


def parity_contrast(means: np.ndarray, sx: int, sy: int) -> float:
    """Mean grey of "odd" minus "even" squares when the detector's columns run along sx * x
    and its rows along sy * y; even squares have an even index sum counted from the (-X, -Y)
    corner, so the value is positive when the square at that corner is black (grey levels)."""
    m = means[:, ::sx][::sy]
    j, i = np.indices(m.shape)
    even = (i + j) % 2 == 0
    return float(m[~even].mean() - m[even].mean())


def find_grid(
    grey: np.ndarray, pattern: ChessboardPattern, max_side: int = 1600
) -> np.ndarray | None:
    """Inner corners (rows * cols, 2) raw px of `grey` in the detector's order, or None.

    Images larger than `max_side` are searched at a reduced scale, then the corners are
    refined at full resolution (`cv2.cornerSubPix`), which keeps phone photos fast.
    """
    scale = min(1.0, max_side / max(grey.shape))
    if scale == 1.0:
        return _find_grid(grey, pattern)
    small = cv2.resize(grey, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    raw = _find_grid(small, pattern)
    if raw is None:
        return None
    pts = ((raw + 0.5) / scale - 0.5).astype(np.float32).reshape(-1, 1, 2)
    spacing = np.median(
        np.linalg.norm(np.diff(raw.reshape(pattern.inner_rows, -1, 2), axis=1), axis=2)
    )
    win = int(np.clip(0.25 * spacing / scale, 3, 25))
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 0.01)
    return (
        cv2.cornerSubPix(grey, pts, (win, win), (-1, -1), criteria)
        .reshape(-1, 2)
        .astype(np.float64)
    )


def orient_grid(
    grey: np.ndarray,
    raw: np.ndarray,
    pattern: ChessboardPattern,
    undistort: Callable[[np.ndarray], np.ndarray],
    A: np.ndarray,
) -> tuple[np.ndarray, float]:
    """Object coordinates (N, 2) cm of the detected corners `raw` (N, 2) and the parity
    confidence in [0, 1].

    Of the four sign choices (sx, sy) of the detector's (column, row) axes, the two
    right-handed ones put the camera at z > 0 (tested through `undistort` and intrinsics `A`);
    of those (a half turn apart) the one with the black square diagonally outside the
    (-X, -Y) corner wins. Confidence: the parity contrast over the spread (5th-95th
    percentile) of the square means; about 1 for a clear board, near 0 when the colours
    cannot be told apart (then the half turn is a guess).
    """
    grid = pattern.grid_xy()
    R, t = pose_from_homography(dlt_homography(grid, undistort(raw)), A)
    front = camera_centre(R, t)[2] > 0
    candidates = [(1, 1), (-1, -1)] if front else [(1, -1), (-1, 1)]
    means = square_means(grey, raw, pattern.inner_cols, pattern.inner_rows)
    sx, sy = max(candidates, key=lambda s: parity_contrast(means, *s))
    spread = float(np.percentile(means, 95) - np.percentile(means, 5))
    confidence = parity_contrast(means, sx, sy) / spread if spread > 1e-6 else 0.0
    return grid * np.array([sx, sy]), float(np.clip(confidence, 0.0, 1.0))


def detect_chessboard(
    image: np.ndarray,
    pattern: ChessboardPattern,
    undistort: Callable[[np.ndarray], np.ndarray],
    A: np.ndarray,
) -> Correspondences | None:
    """Inner chessboard corners of `image` (RGB or grey) with their object coordinates, or None.

    `undistort` maps raw pixels (N, 2) to ideal pinhole pixels of intrinsics `A` (3, 3); the
    orientation rule is `orient_grid`'s.
    """
    grey = to_grey(image)
    raw = find_grid(grey, pattern)
    if raw is None:
        return None
    object_xy, _ = orient_grid(grey, raw, pattern, undistort, A)
    return Correspondences(object_xy=object_xy, image_uv=raw, method="chessboard")


@dataclass(frozen=True)
class ImageFeatures:
    """Keypoint positions (N, 2) px of an image and their descriptors (N, d) (None if N = 0)."""

    points: np.ndarray
    descriptors: np.ndarray | None


@dataclass
class MatchResult:
    """Outcome of matching one image to the texture.

    `H` (3, 3) maps object-plane cm to image pixels (None when no usable homography was
    found), `matches` the number of ratio-test survivors, `inliers` the RANSAC inliers,
    `reason` why H is None; `inlier_xy` (inliers, 2) cm and `inlier_uv` (inliers, 2) px are
    the inlier correspondences (object plane, image as given).
    """

    H: np.ndarray | None
    matches: int
    inliers: int
    reason: str = ""
    inlier_xy: np.ndarray | None = None
    inlier_uv: np.ndarray | None = None


def signed_area(quad: np.ndarray) -> float:
    """Shoelace area (px^2) of a polygon (N, 2); its sign gives the winding order."""
    x, y = quad[:, 0], quad[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def make_detector(features: str, n_features: int) -> cv2.Feature2D:
    """A SIFT or ORB detector/descriptor from OpenCV."""
    if features == "sift":
        return cv2.SIFT_create(nfeatures=n_features)  # type: ignore[attr-defined]
    if features == "orb":
        return cv2.ORB_create(  # type: ignore[attr-defined]
            nfeatures=n_features, scaleFactor=1.2, nlevels=8, fastThreshold=10
        )
    raise ValueError(f"features must be one of {', '.join(FEATURES)}, got {features!r}")


def corners_convex_and_sized(quad: np.ndarray, min_area_px: float) -> bool:
    """True if `quad` (4, 2) px, in order, is a convex, non-folded polygon of area >= min_area."""
    d = np.roll(quad, -1, axis=0) - quad
    cross = d[:, 0] * np.roll(d, -1, axis=0)[:, 1] - d[:, 1] * np.roll(d, -1, axis=0)[:, 0]
    if not (np.all(cross > 0) or np.all(cross < 0)):
        return False
    return abs(cv2.contourArea(quad.astype(np.float32))) >= min_area_px


class TextureMatcher:
    """Matches photographs to one front-on texture of a planar object (SIFT or ORB).

    texture: RGB uint8 [h, w, 3] covering the object rectangle `width_cm` x `height_cm`.
    The texture's features are computed once. `ratio` is Lowe's ratio-test threshold,
    `ransac_px` the RANSAC reprojection threshold in pixels of the image as matched
    (after `upscale`), `min_inliers` the fewest inliers accepted.
    """

    def __init__(
        self,
        texture: np.ndarray,
        width_cm: float,
        height_cm: float,
        features: str = "sift",
        ratio: float = 0.8,
        ransac_px: float = 5.0,
        min_inliers: int = 8,
        n_features: int = 2000,
    ) -> None:
        self.features = features
        self.ratio, self.ransac_px, self.min_inliers = ratio, ransac_px, min_inliers
        self.width_cm, self.height_cm = width_cm, height_cm
        self.detector = make_detector(features, n_features)
        grey = to_grey(texture)
        self.tex_to_obj = texture_to_object((grey.shape[1], grey.shape[0]), width_cm, height_cm)
        keypoints, self.descriptors = self.detector.detectAndCompute(grey, None)
        self.texture_points = np.array([k.pt for k in keypoints], dtype=np.float64).reshape(-1, 2)
        norm = cv2.NORM_L2 if features == "sift" else cv2.NORM_HAMMING
        self.matcher = cv2.BFMatcher(norm)
        if self.descriptors is None or len(self.texture_points) < 4:
            raise ValueError(f"the texture has too few {features} features to match")

    def corners_xy(self) -> np.ndarray:
        """Object-plane corners (4, 2) cm in `CORNER_ORDER`."""
        return object_corners(self.width_cm, self.height_cm)

    def image_features(self, image: np.ndarray, upscale: float = 1.0) -> ImageFeatures:
        """Keypoints and descriptors of `image` (RGB or grey), enlarged by `upscale` (cubic)
        before detection, which helps small images; points in the original image's pixels."""
        grey = to_grey(image)
        if upscale != 1.0:
            grey = cv2.resize(grey, None, fx=upscale, fy=upscale, interpolation=cv2.INTER_CUBIC)
        keypoints, descriptors = self.detector.detectAndCompute(grey, None)
        pts = np.array([k.pt for k in keypoints], dtype=np.float64).reshape(-1, 2)
        # Pixel centres at integers: original u = (u' + 0.5) / upscale - 0.5.
        return ImageFeatures((pts + 0.5) / upscale - 0.5, descriptors)

    def match_features(
        self, feats: ImageFeatures, ratio: float | None = None, ransac_px: float | None = None
    ) -> MatchResult:
        """Homography object plane (cm) -> image pixels from precomputed image features, or why
        there is none. `ratio` and `ransac_px` (original image pixels) default to the
        matcher's own."""
        ratio = self.ratio if ratio is None else ratio
        ransac_px = self.ransac_px if ransac_px is None else ransac_px
        if feats.descriptors is None or len(feats.points) < 4:
            return MatchResult(None, 0, 0, "too few features in the image")
        pairs = self.matcher.knnMatch(feats.descriptors, self.descriptors, k=2)
        good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < ratio * p[1].distance]
        if len(good) < max(4, self.min_inliers):
            return MatchResult(None, len(good), 0, "too few matches")
        img_pts = feats.points[[m.queryIdx for m in good]]
        tex_pts = self.texture_points[[m.trainIdx for m in good]]
        H_tex, mask = cv2.findHomography(tex_pts, img_pts, cv2.RANSAC, ransac_px)
        inliers = int(mask.sum()) if mask is not None else 0
        if H_tex is None or inliers < self.min_inliers:
            return MatchResult(None, len(good), inliers, "too few RANSAC inliers")
        H = H_tex @ np.linalg.inv(self.tex_to_obj)
        quad = apply_homography(H, self.corners_xy())
        if not np.all(np.isfinite(quad)) or not corners_convex_and_sized(quad, 4.0):
            return MatchResult(None, len(good), inliers, "degenerate homography")
        # Seen from the front, the corners (counter-clockwise in the object plane) run
        # clockwise on screen (image v points down), i.e. with a negative shoelace area.
        if signed_area(quad) >= 0:
            return MatchResult(None, len(good), inliers, "mirrored homography")
        keep = mask.ravel().astype(bool)
        inlier_xy = cv2.perspectiveTransform(tex_pts[keep].reshape(-1, 1, 2), self.tex_to_obj)
        return MatchResult(
            H / H[2, 2], len(good), inliers, "", inlier_xy.reshape(-1, 2), img_pts[keep]
        )

    def match(self, image: np.ndarray, upscale: float = 1.0) -> MatchResult:
        """`match_features` of `image_features(image, upscale)`."""
        return self.match_features(self.image_features(image, upscale))
