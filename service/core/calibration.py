"""One camera learned from several views of the object: its focal length and, where the views
pin it, its radial lens. One policy for `POST /v1/cameras` (photos), a `same_camera` request
and a stream that learns its camera.

    fit_camera   views (pinhole corners [4, 2] px of one image size each, and the radial
                 lens each view's refinement fitted, `service.core.refine.RadialLens`) ->
                 `CameraFit`: fx by `service.core.pose.fit_focal` (views that do not fit
                 dropped), the range the views allow, and OpenCV's k1, k2 of the views'
                 median lens with its uncertainty, where enough views fitted one

Units: px of the images (landscape: a portrait is the camera turned, its corners turned
back first), kappa in px^-2 about the image centre, k1 and k2 of OpenCV's normalised
coordinates at the fitted fx.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from service.core.pose import fit_focal

#: The widest range of focal lengths (hi - lo) / fx a learned camera may leave: wider, the
#: views do not pin it (too close to head-on, or too few), and it is not taken.
MAX_FX_SPREAD = 0.5
#: The views whose refinement fitted a lens that a learned lens needs, at least.
MIN_LENS_VIEWS = 3
#: The largest standard error of the learned k1 (OpenCV's): beyond, fx alone is learned.
MAX_K1_SE = 0.05


@dataclass(frozen=True)
class CameraFit:
    """A camera learned from views: fx px, the range (lo, hi) px they allow, the RMS
    reprojection error px of the views used, which views were used [V] bool, and OpenCV's
    (k1, k2) of the lens with k1's standard error (None: the views do not pin a lens)."""

    fx: float
    fx_range: tuple[float, float]
    residual_px: float
    used: np.ndarray
    radial: tuple[float, float] | None = None
    k1_se: float | None = None

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


def fit_camera(
    views: Sequence[np.ndarray],
    kappas: Sequence[float | None],
    object_points: np.ndarray,
    size: tuple[int, int],
) -> CameraFit:
    """Views of the object by one camera (pinhole corners [4, 2] px of images of `size`
    (W, H)) and the radial lens each one's refinement fitted (kappa px^-2, None: none) ->
    the camera (`CameraFit`). The lens is the median kappa of the views used that fitted
    one, turned into OpenCV's k1, k2 at the fitted fx, where `MIN_LENS_VIEWS` or more did
    and k1's standard error (1.4826 MAD / sqrt(n)) is within `MAX_K1_SE`. ValueError for
    fewer than 2 views, or fewer than 2 that agree (`fit_focal`)."""
    fit = fit_focal(views, object_points, size)
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
