"""A camera learned from views (service/core/calibration.py): calibrated from the texture's
features where enough views bring them, else fx from the corners."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from service.core.calibration import MIN_FEATURES, calibrate_features, fit_camera
from service.core.frame import object_corners
from service.core.refine import Features

SIZE = (1280, 720)
W_CM, H_CM = 26.0, 18.0
#: The camera the views are made with: fx = fy, principal point off the centre, a barrel lens.
K = np.array([[700.0, 0.0, 655.0], [0.0, 700.0, 340.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.2, 0.05, 0.0, 0.0, 0.0])
#: Poses (rvec, tvec cm) of the object seen from several sides, 40-70 cm away.
POSES = [
    ((0.5, 0.1, 0.0), (2.0, -1.0, 55.0)),
    ((-0.4, 0.3, 0.2), (-6.0, 3.0, 60.0)),
    ((0.2, -0.5, -0.1), (5.0, 4.0, 45.0)),
    ((-0.3, -0.4, 0.3), (-3.0, -4.0, 70.0)),
    ((0.6, 0.4, 0.1), (0.0, 2.0, 50.0)),
    ((0.1, 0.6, -0.2), (8.0, -2.0, 65.0)),
]


def view(rvec: tuple, tvec: tuple, rng: np.random.Generator) -> tuple[np.ndarray, Features]:
    """The object's corners [4, 2] px as a pinhole sees them and 40 of its texture's points
    as the lens shows them (0.2 px of noise)."""
    uv = rng.uniform(0.03, 0.97, (40, 2))
    plane = np.column_stack([(uv[:, 0] - 0.5) * W_CM, (0.5 - uv[:, 1]) * H_CM, np.zeros(40)])
    r, t = np.array(rvec, float), np.array(tvec, float)
    seen, _ = cv2.projectPoints(plane, r, t, K, DIST)
    corners, _ = cv2.projectPoints(object_corners(W_CM, H_CM, z=True), r, t, K, None)
    noisy = seen.reshape(-1, 2) + rng.normal(0, 0.2, (40, 2))
    return corners.reshape(4, 2), Features(uv, noisy)


def test_the_features_of_a_few_views_calibrate_the_camera() -> None:
    rng = np.random.default_rng(0)
    views = [view(r, t, rng)[1] for r, t in POSES]
    fit = calibrate_features(views, object_corners(W_CM, H_CM, z=True), SIZE, 800.0)
    assert fit is not None and fit.pinned
    assert fit.fx == pytest.approx(700.0, rel=0.01)
    assert fit.fx_range[0] < 700.0 < fit.fx_range[1]
    assert fit.centre == pytest.approx((655.0, 340.0), abs=6.0)
    assert fit.radial is not None and fit.radial[0] == pytest.approx(-0.2, abs=0.03)
    assert fit.residual_px < 0.5


def test_the_camera_comes_from_features_where_enough_views_bring_them() -> None:
    rng = np.random.default_rng(1)
    made = [view(r, t, rng) for r, t in POSES]
    corners = [c for c, _ in made]
    objects = object_corners(W_CM, H_CM, z=True)
    calibrated = fit_camera(corners, [None] * 6, objects, SIZE, [f for _, f in made])
    assert calibrated.centre is not None and calibrated.fx == pytest.approx(700.0, rel=0.01)
    few = [f if i < 2 else None for i, (_, f) in enumerate(made)]  # 2 views: corners alone
    scant = [Features(f.uv[: MIN_FEATURES - 1], f.seen[: MIN_FEATURES - 1]) for _, f in made]
    for features in (few, scant, None):
        fit = fit_camera(corners, [None] * 6, objects, SIZE, features)
        assert fit.centre is None and fit.radial is None  # fx from the pinhole corners
        assert fit.fx == pytest.approx(700.0, rel=0.05)
