"""One camera learned from several views of the object: its focal length and, where the views
pin it, its radial lens. One policy for `POST /v1/cameras` (photos), a `same_camera` request
and a stream that learns its camera.

    fit_camera   views (pinhole corners [4, 2] px of one image size each, and the radial
                 lens each view's refinement fitted, `service.core.refine.RadialLens`) ->
                 `CameraFit`: fx by `service.core.pose.fit_focal` (views that do not fit
                 dropped), the range the views allow, and OpenCV's k1, k2 of the views'
                 median lens with its uncertainty, where enough views fitted one; where
                 `MIN_FEATURE_VIEWS` or more views carry the texture's features followed
                 into them (`service.core.refine.Features`), the camera calibrated from
                 those instead (`calibrate_features`: fx, the principal point, k1, k2)

Units: px of the images (landscape: a portrait is the camera turned, its corners turned
back first), kappa in px^-2 about the image centre, k1 and k2 of OpenCV's normalised
coordinates at the fitted fx.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import cv2
import numpy as np

from service.core.pose import fit_focal
from service.core.refine import Features

#: The widest range of focal lengths (hi - lo) / fx a learned camera may leave: wider, the
#: views do not pin it (too close to head-on, or too few), and it is not taken.
MAX_FX_SPREAD = 0.5
#: The views whose refinement fitted a lens that a learned lens needs, at least.
MIN_LENS_VIEWS = 3
#: The largest standard error of the learned k1 (OpenCV's): beyond, fx alone is learned.
MAX_K1_SE = 0.05
#: The views with followed texture features a camera is calibrated from, at least (fewer: its
#: corners alone), and the least features one of them brings.
MIN_FEATURE_VIEWS, MIN_FEATURES = 3, 12
#: The range a calibrated fx allows: this many standard errors either side.
FX_SIGMAS = 3.0
#: The farthest a calibrated principal point may lie from the image centre, a share of the
#: image's width and height (farther: the views do not pin it, and the centre is kept).
MAX_CENTRE_SHIFT = 0.1


@dataclass(frozen=True)
class CameraFit:
    """A camera learned from views: fx px, the range (lo, hi) px they allow, the RMS
    reprojection error px of the views used, which views were used [V] bool, OpenCV's
    (k1, k2) of the lens with k1's standard error (None: the views do not pin a lens), and
    the principal point (cx, cy) px (None: the image centre)."""

    fx: float
    fx_range: tuple[float, float]
    residual_px: float
    used: np.ndarray
    radial: tuple[float, float] | None = None
    k1_se: float | None = None
    centre: tuple[float, float] | None = None

    @property
    def pinned(self) -> bool:
        """Whether the views pin the focal length (`MAX_FX_SPREAD`)."""
        return (self.fx_range[1] - self.fx_range[0]) / self.fx <= MAX_FX_SPREAD

    @property
    def dist(self) -> tuple[float, ...] | None:
        """OpenCV's 5 distortion coefficients of the learned lens, or None."""
        return None if self.radial is None else (*self.radial, 0.0, 0.0, 0.0)


def radial_of_kappa(kappa: float, fx: float, size: tuple[int, int]) -> tuple[float, float]:
    """The division model's kappa px^-2 (x_u = x_d / (1 + kappa r_d^2) about the image
    centre) -> OpenCV's (k1, k2) at focal length `fx` px (x_d = x_u (1 + k1 r^2 + k2 r^4),
    r = |x_u| / fx), least squares over the radii of an image of `size` (W, H)."""
    r_d = np.linspace(0.0, 0.5 * math.hypot(*size), 64)[1:]
    r_u = r_d / (1.0 + kappa * r_d**2)
    ok = r_u > 0
    r = r_u[ok] / fx
    A = np.column_stack([r**2, r**4])
    (k1, k2), *_ = np.linalg.lstsq(A, r_d[ok] / r_u[ok] - 1.0, rcond=None)
    return float(k1), float(k2)


def calibrate_features(
    views: Sequence[Features], object_points: np.ndarray, size: tuple[int, int], fx: float
) -> CameraFit | None:
    """Views of the texture's features (in px of images of `size`, the lens not undone) of
    the object whose corners are `object_points` [4, 3] cm -> the camera by OpenCV's
    calibration (`cv2.calibrateCameraExtended`, Zhang's method): fx = fy, the principal
    point (the centre kept where it lands farther than `MAX_CENTRE_SHIFT`), k1, k2 where k1's
    standard error is within `MAX_K1_SE` (no tangential terms, no k3), started from `fx` and
    the image centre; its range `FX_SIGMAS` standard errors either side. None where OpenCV
    fails."""
    lo, hi = object_points[:, :2].min(0), object_points[:, :2].max(0)
    # uv from the texture's top-left edge -> the object frame, cm: x right, y up, z = 0
    planes = [
        np.column_stack([lo[0] + v.uv[:, 0] * (hi - lo)[0], hi[1] - v.uv[:, 1] * (hi - lo)[1],
                         np.zeros(len(v.uv))]).astype(np.float32)
        for v in views
    ]  # fmt: skip
    seen = [v.seen.astype(np.float32) for v in views]
    centre = np.array([(size[0] - 1) / 2, (size[1] - 1) / 2])
    flags = (cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_ASPECT_RATIO
             | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3)  # fmt: skip
    for fixed in (0, cv2.CALIB_FIX_PRINCIPAL_POINT):  # the centre where the views drift off
        K = np.array([[fx, 0, centre[0]], [0, fx, centre[1]], [0, 0, 1]])
        try:
            rms, K, dist, _, _, sigma, _, _ = cv2.calibrateCameraExtended(
                planes, seen, size, K, np.zeros(5), flags=flags | fixed
            )
        except cv2.error:
            return None
        if np.all(np.abs(K[:2, 2] - centre) <= MAX_CENTRE_SHIFT * np.array(size)):
            break
    sd = np.asarray(sigma, np.float64).ravel()  # fx, fy, cx, cy, k1, k2, ...
    # with fy / fx fixed, OpenCV reports the focal length's error under fy (fx: 0)
    f, se, k1_se = float(K[0, 0]), float(max(sd[0], sd[1])), float(sd[4])
    if not (math.isfinite(f) and f > 0 and math.isfinite(se) and math.isfinite(k1_se)):
        return None
    k = np.asarray(dist, np.float64).ravel()
    radial = (float(k[0]), float(k[1])) if k1_se <= MAX_K1_SE else None
    return CameraFit(
        f,
        (f - FX_SIGMAS * se, f + FX_SIGMAS * se),
        float(rms),
        np.ones(len(views), bool),
        radial,
        k1_se,
        (float(K[0, 2]), float(K[1, 2])),
    )


def fit_camera(
    views: Sequence[np.ndarray],
    kappas: Sequence[float | None],
    object_points: np.ndarray,
    size: tuple[int, int],
    features: Sequence[Features | None] | None = None,
) -> CameraFit:
    """Views of the object by one camera (pinhole corners [4, 2] px of images of `size`
    (W, H)), the radial lens each one's refinement fitted (kappa px^-2, None: none) and the
    texture's features it followed (in px of `size`; None: none) -> the camera
    (`CameraFit`). Calibrated from the features where `MIN_FEATURE_VIEWS` or more of the
    views the corners fit bring `MIN_FEATURES` each (`calibrate_features`). Else fx from the
    corners, and the lens the median kappa of the views used that fitted one, turned into
    OpenCV's k1, k2 at the fitted fx, where `MIN_LENS_VIEWS` or more did and k1's standard
    error (1.4826 MAD / sqrt(n)) is within `MAX_K1_SE`. ValueError for fewer than 2 views,
    or fewer than 2 that agree (`fit_focal`)."""
    fit = fit_focal(views, object_points, size)
    rich = [
        f if f is not None and used and len(f.uv) >= MIN_FEATURES else None
        for f, used in zip(features or [None] * len(views), fit.used, strict=True)
    ]
    chosen = [f for f in rich if f is not None]
    if len(chosen) >= MIN_FEATURE_VIEWS:
        calibrated = calibrate_features(chosen, object_points, size, fit.fx)
        if calibrated is not None:
            return replace(calibrated, used=np.array([f is not None for f in rich]))
    lenses = np.array(
        [k for k, u in zip(kappas, fit.used, strict=True) if u and k is not None], np.float64
    )
    radial, se = None, None
    if len(lenses) >= MIN_LENS_VIEWS:
        kappa = float(np.median(lenses))
        spread = 1.4826 * float(np.median(np.abs(lenses - kappa))) / math.sqrt(len(lenses))
        se = spread * fit.fx**2  # k1 ~ kappa fx^2 to first order
        if se <= MAX_K1_SE:
            radial = radial_of_kappa(kappa, fit.fx, size)
    return CameraFit(fit.fx, fit.interval, fit.residual_px, fit.used, radial, se)
