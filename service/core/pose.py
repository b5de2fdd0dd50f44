"""The camera pose from the object's four corners, and the focal length from one or many views.

Frames and units as `service.core.geometry`: the object frame in cm (origin at the object's
centre, the object in z = 0, +z out of its printed face), OpenCV's camera frame (x right, y
down, z forward), image pixels with the origin at the top-left pixel's centre. A camera here
is a pinhole with square pixels, its principal point at the image centre unless given, and
(optionally) OpenCV's distortion coefficients.

    solve_pose       corners [4, 2] px + camera -> `CameraPose` (IPPE PnP, the face seen)
    focal_interval   views -> the focal lengths they allow: where the corners fit within
                     their noise (a head-on view allows a wide range, an oblique one a narrow)
    estimate_focal   one view -> the focal length its pose takes: the most probable given
                     the view's fit and the network's prior (an oblique view pins its own,
                     a head-on one keeps the prior)
    zhang_focal      views -> fx of Zhang's constraints on their homographies, closed form
    fit_focal        views -> one camera's fx: the focal length the views agree on (views that
                     do not dropped), Zhang refined by `cv2.calibrateCamera` (fx = fy,
                     principal point fixed, no distortion)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TypeGuard

import cv2
import numpy as np

from service.core.inputs import spec_fx

#: The corner network's focal-length prior and bounds, x the SPEC camera's fx at the image's
#: width: where the view says little, the estimate is drawn to the prior (the graph's
#: `train.network.corners.CornerNet.focal_length` and the service's `estimate_focal`).
FOCAL_PRIOR, FOCAL_BOUNDS = 0.8, (0.4, 1.2)
#: The focal lengths a camera learned from several views may have, x the same: a fisheye-like
#: webcam to a short telephoto.
CAMERA_BOUNDS = (0.3, 3.0)
#: The corner network's corner noise per coordinate, px of its 160-px-wide input: what "the
#: corners fit" means in `focal_interval` and `fit_focal`. The robust spread (1.4826 x the
#: median absolute error) of the default model's corners against the labels on the corpus's
#: val sources is 0.46 px (median 0.31, 68th percentile 0.68; a few gross misses beyond).
CORNER_NOISE_INPUT_PX = 0.5
#: Focal lengths tried across the bounds (log-spaced; 6 % apart over the `CAMERA_BOUNDS`).
FOCAL_STEPS = 41
#: The spread of focal lengths around the prior, in ln(fx) (a factor of 1.28 either way): the
#: prior's weight in `estimate_focal` against the view's own fit. Chosen on the val sets
#: (0.25 and 0.4 tried) where it replaced a switch (the best fit where the view allowed a
#: range narrower than a factor of 2, else the prior): docs/decisions.md.
FOCAL_PRIOR_SD = 0.25


@dataclass(frozen=True)
class Camera:
    """A pinhole camera for images of `size` (W, H) px: fx, fy (None: fx) px, principal point
    (None: the image centre) and OpenCV's distortion coefficients (None: none)."""

    fx: float
    size: tuple[int, int]
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    dist: tuple[float, ...] | None = None

    @property
    def matrix(self) -> np.ndarray:
        """K (3, 3)."""
        w, h = self.size
        cx = (w - 1) / 2.0 if self.cx is None else self.cx
        cy = (h - 1) / 2.0 if self.cy is None else self.cy
        fy = self.fx if self.fy is None else self.fy
        return np.array([[self.fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])

    @property
    def coefficients(self) -> np.ndarray | None:
        return None if self.dist is None else np.asarray(self.dist, np.float64)


@dataclass(frozen=True)
class CameraPose:
    """A camera's pose relative to the object: OpenCV's rvec (3,) and tvec (3,) cm (object ->
    camera), the camera centre (3,) cm in the object frame, and the corners' RMS reprojection
    error px."""

    rvec: np.ndarray
    tvec: np.ndarray
    centre: np.ndarray
    residual_px: float

    @property
    def distance_cm(self) -> float:
        return float(np.linalg.norm(self.centre))

    @property
    def azimuth_deg(self) -> float:
        """atan2(c_y, c_x): 0 = seen from the object's +x side, 90 = from its top (+y)."""
        return math.degrees(math.atan2(self.centre[1], self.centre[0]))

    @property
    def elevation_deg(self) -> float:
        """asin(c_z / |c|): 90 = straight on, 0 = grazing."""
        return math.degrees(math.asin(max(-1.0, min(1.0, self.centre[2] / self.distance_cm))))


def corner_noise_px(size: tuple[int, int]) -> float:
    """The corner network's corner noise in px of an image of `size` (W, H): its input is the
    image's longer side brought to 160 px."""
    return CORNER_NOISE_INPUT_PX * max(size) / 160.0


def focal_bounds(
    size: tuple[int, int], factors: tuple[float, float] = FOCAL_BOUNDS
) -> tuple[float, float]:
    """The focal lengths (px) an estimate keeps within for an image of `size` (W, H): the
    `factors` (the network's bounds) x the SPEC camera's fx at the image's longer side."""
    f = spec_fx(max(size))
    return factors[0] * f, factors[1] * f


def focal_prior(size: tuple[int, int], scale: float = FOCAL_PRIOR) -> float:
    """The prior focal length (px) for an image of `size` (W, H): `scale` (the model's object
    profile's, `service.core.profile`) x the SPEC camera's fx at the image's longer side."""
    return scale * spec_fx(max(size))


def is_focal_prior(value: object) -> TypeGuard[float]:
    """Whether `value` can be a model's focal-length prior: a number (x the SPEC camera's fx)
    within the `FOCAL_BOUNDS` its estimate keeps to."""
    lo, hi = FOCAL_BOUNDS
    return isinstance(value, int | float) and not isinstance(value, bool) and lo <= value <= hi


def _as_points(corners: np.ndarray) -> np.ndarray:
    q = np.asarray(corners, np.float64).reshape(-1, 2)
    if q.shape != (4, 2) or not np.isfinite(q).all():
        raise ValueError(f"corners: four finite (x, y) points, got shape {q.shape}")
    return q


def _ippe(
    obj: np.ndarray, q: np.ndarray, K: np.ndarray, dist: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Object points [4, 3] cm, their image [4, 2] px, K (3, 3) and distortion -> (rvec (3,),
    tvec (3,) cm, camera centre (3,) cm, RMS error px) of IPPE's two solutions, the one with
    the camera on the printed side (c_z > 0) and the smaller reprojection error."""
    _, rvecs, tvecs, errors = cv2.solvePnPGeneric(obj, q, K, dist, flags=cv2.SOLVEPNP_IPPE)
    best: tuple[np.ndarray, np.ndarray, np.ndarray, float] | None = None
    for rvec, tvec, error in zip(rvecs, tvecs, np.ravel(errors), strict=True):
        centre = -cv2.Rodrigues(rvec)[0].T @ tvec.ravel()
        if best is None or (centre[2] <= 0, error) < (best[2][2] <= 0, best[3]):
            best = (rvec.ravel(), tvec.ravel(), centre, float(error))
    if best is None:
        raise ValueError("corners: no pose fits them")
    return best


def solve_pose(corners: np.ndarray, object_points: np.ndarray, camera: Camera) -> CameraPose:
    """Corners [4, 2] px (in the order of `object_points` [4, 3] cm) seen by `camera` -> the
    pose (`_ippe`: the camera on the printed side, the smaller reprojection error)."""
    obj = np.asarray(object_points, np.float64).reshape(4, 3)
    return CameraPose(*_ippe(obj, _as_points(corners), camera.matrix, camera.coefficients))


def _residuals(
    views: Sequence[np.ndarray], object_points: np.ndarray, size: tuple[int, int], fx: float
) -> np.ndarray:
    """The RMS reprojection error px [V] of each view's pose with focal length `fx` (the
    focal scans call it a few thousand times a second: no validation, no objects)."""
    K = Camera(fx, size).matrix
    obj = np.asarray(object_points, np.float64).reshape(4, 3)
    return np.array([_ippe(obj, q, K, None)[3] for q in views])


def _costs(
    views: Sequence[np.ndarray], object_points: np.ndarray, size: tuple[int, int], fs: np.ndarray
) -> np.ndarray:
    """Each view's sum of squared reprojection errors px^2 over its 4 corners [V, F] at each
    focal length `fs` [F] (solvePnP's error is the RMS distance: 4 rms^2 per view); inf
    where no pose was found (IPPE gives NaN for some exactly symmetric views)."""
    costs = np.stack([4.0 * _residuals(views, object_points, size, f) ** 2 for f in fs], 1)
    return np.where(np.isfinite(costs), costs, np.inf)


def _allowed(fs: np.ndarray, cost: np.ndarray, noise: float) -> tuple[float, float]:
    """The focal lengths (lo, hi) of `fs` [F] whose summed cost [F] px^2 is within 4 noise^2
    of the least (chi-square, 2 sigma, noise px per coordinate)."""
    allowed = fs[cost <= cost.min() + 4.0 * noise**2]
    return float(allowed.min()), float(allowed.max())


def focal_interval(
    views: Sequence[np.ndarray],
    object_points: np.ndarray,
    size: tuple[int, int],
    noise_px: float | None = None,
    factors: tuple[float, float] = FOCAL_BOUNDS,
) -> tuple[float, float]:
    """Views (corners [4, 2] px each, one camera, images of `size` (W, H)) -> the focal
    lengths (lo, hi) px within `focal_bounds` (of `factors`) they allow: those whose sum of
    squared reprojection errors over all corners is within 4 noise^2 of the best one's
    (chi-square, 2 sigma; `noise_px` per coordinate, default `corner_noise_px`). More views
    narrow it; head-on views leave it wide."""
    fs = np.geomspace(*focal_bounds(size, factors), FOCAL_STEPS)
    noise = corner_noise_px(size) if noise_px is None else noise_px
    qs = [_as_points(q) for q in views]
    return _allowed(fs, _costs(qs, object_points, size, fs).sum(0), noise)


def zhang_focal(
    views: Sequence[np.ndarray], object_points: np.ndarray, size: tuple[int, int]
) -> float | None:
    """Views (corners [4, 2] px each) -> the focal length px that best makes the images of the
    object's x and y axes orthogonal and of equal length in all of them (Zhang's two
    constraints per homography, principal point at the image centre, square pixels; least
    squares in z = 1 / f^2), or None when they do not give a positive z (head-on views)."""
    w, h = size
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    f0 = focal_prior(size)  # pixel units of the prior keep the system well scaled
    obj = np.asarray(object_points, np.float64).reshape(4, 3)[:, :2]
    a, b = [], []
    for q in views:
        H = cv2.getPerspectiveTransform(
            obj.astype(np.float32), (_as_points(q) - centre).astype(np.float32)
        )
        Hn = np.vstack([H[:2] / f0, H[2:]])
        Hn /= np.linalg.norm(Hn[:, :2])
        h1, h2 = Hn[:, 0], Hn[:, 1]
        a += [h1[0] * h2[0] + h1[1] * h2[1], h1[0] ** 2 + h1[1] ** 2 - h2[0] ** 2 - h2[1] ** 2]
        b += [h1[2] * h2[2], h1[2] ** 2 - h2[2] ** 2]
    av, bv = np.array(a), np.array(b)
    denominator = float(av @ av)
    z = -float(av @ bv) / denominator if denominator > 0 else 0.0
    return f0 / math.sqrt(z) if z > 0 else None


@dataclass(frozen=True)
class FocalFit:
    """`fit_focal`'s answer: fx px, the RMS reprojection error px of the views used, which
    views were used [V] bool, and the focal lengths (lo, hi) px those views allow."""

    fx: float
    residual_px: float
    used: np.ndarray
    interval: tuple[float, float]


def fit_focal(
    views: Sequence[np.ndarray],
    object_points: np.ndarray,
    size: tuple[int, int],
    noise_px: float | None = None,
) -> FocalFit:
    """Views of the object by one camera (corners [4, 2] px each, images of `size` (W, H)) ->
    its focal length.

    Each view's error curve over the `CAMERA_BOUNDS` is measured against its own best; the
    focal length where the sum of those excesses, each capped at 4 noise^2 (`noise_px` per
    coordinate, default `corner_noise_px`), is least is where the views agree, and a view
    whose excess there is above the cap is dropped (a wrong detection, another lens: one
    strong outlier cannot pull the fit). The views kept are fitted by `zhang_focal`
    refined by `cv2.calibrateCamera` (fx = fy, principal point at the centre, no
    distortion). ValueError for fewer than 2 views, or fewer than 2 that agree."""
    if len(views) < 2:
        raise ValueError(f"need at least 2 views, got {len(views)}")
    qs = [_as_points(q) for q in views]
    obj = np.asarray(object_points, np.float64).reshape(4, 3)
    noise = corner_noise_px(size) if noise_px is None else noise_px
    fs = np.geomspace(*focal_bounds(size, CAMERA_BOUNDS), FOCAL_STEPS)
    costs = _costs(qs, obj, size, fs)  # [V, F]
    excess = costs - costs.min(1, keepdims=True)
    cap = 4.0 * noise**2
    agreed = int(np.argmin(np.minimum(excess, cap).sum(0)))
    used = excess[:, agreed] <= cap
    if used.sum() < 2:
        raise ValueError("the views do not agree on one focal length")
    kept = [q for q, u in zip(qs, used, strict=True) if u]
    guess = zhang_focal(kept, obj, size)
    if guess is None or abs(guess / fs[agreed] - 1.0) > 0.25:  # another basin: start at the scan's
        guess = float(fs[agreed])
    fx, residual = _calibrated(kept, obj, size, guess)
    return FocalFit(fx, residual, used, _allowed(fs, costs[used].sum(0), noise))


def estimate_focal(
    corners: np.ndarray,
    object_points: np.ndarray,
    size: tuple[int, int],
    prior: float = FOCAL_PRIOR,
    noise_px: float | None = None,
) -> tuple[float, tuple[float, float]]:
    """One view's corners [4, 2] px (`noise_px` per coordinate, None: `corner_noise_px`) ->
    the focal length px the pose takes and the range (lo, hi) px the view allows (the
    focal lengths within the `CAMERA_BOUNDS` whose pose fits the corners within their
    noise, as `focal_interval`). The focal length is the most probable one given the view
    and the prior: the least of the corners' squared error over 2 noise^2 plus
    (ln f - ln prior)^2 / (2 `FOCAL_PRIOR_SD`^2) (a parabola's vertex in ln f between the
    scan's steps), the prior being the model's (`focal_prior` of `prior`, x the SPEC
    camera's). An oblique view pins its own focal length; a head-on one keeps the prior. The
    range is the scan's, widened to the estimate where that lies between its steps (a sharply
    pinned view allows a single step, 6 % wide)."""
    q = _as_points(corners)
    fs = np.geomspace(*focal_bounds(size, CAMERA_BOUNDS), FOCAL_STEPS)
    cost = _costs([q], object_points, size, fs)[0]
    noise = corner_noise_px(size) if noise_px is None else noise_px
    lo, hi = _allowed(fs, cost, noise)
    log_fs = np.log(fs)
    off_prior = (log_fs - math.log(focal_prior(size, prior))) / FOCAL_PRIOR_SD
    score = cost / (2.0 * noise**2) + 0.5 * off_prior**2
    i = int(np.clip(np.argmin(score), 1, len(fs) - 2))
    c0, c1, c2 = score[i - 1 : i + 2]
    curve = c0 - 2 * c1 + c2
    shift = 0.5 * (c0 - c2) / curve if curve > 0 else 0.0
    best = float(np.exp(log_fs[i] + (log_fs[1] - log_fs[0]) * np.clip(shift, -1.0, 1.0)))
    return best, (min(lo, best), max(hi, best))


#: `cv2.calibrateCamera` with one unknown: fx = fy from the guess, nothing else.
_FX_ONLY = (
    cv2.CALIB_USE_INTRINSIC_GUESS
    | cv2.CALIB_FIX_PRINCIPAL_POINT
    | cv2.CALIB_FIX_ASPECT_RATIO
    | cv2.CALIB_ZERO_TANGENT_DIST
    | cv2.CALIB_FIX_K1
    | cv2.CALIB_FIX_K2
    | cv2.CALIB_FIX_K3
)


def _calibrated(
    views: Sequence[np.ndarray], obj: np.ndarray, size: tuple[int, int], guess: float | None
) -> tuple[float, float]:
    """fx px and the RMS reprojection error px of `cv2.calibrateCamera` from `guess` (None:
    the prior), kept within the `CAMERA_BOUNDS`."""
    lo, hi = focal_bounds(size, CAMERA_BOUNDS)
    start = float(np.clip(focal_prior(size) if guess is None else guess, lo, hi))
    K = Camera(start, size).matrix
    rms, K, *_ = cv2.calibrateCamera(
        [obj.astype(np.float32)] * len(views),
        [q.reshape(4, 1, 2).astype(np.float32) for q in views],
        size,
        K,
        None,
        flags=_FX_ONLY,
    )
    fx = float(K[0, 0])
    if not (math.isfinite(fx) and lo <= fx <= hi):
        fx = start
        rms = float(np.sqrt(np.mean(_residuals(views, obj, size, fx) ** 2)))
    return fx, float(rms)
