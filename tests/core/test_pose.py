"""The pose from four corners and the focal length from one or many views
(`service.core.pose`), on exact projections of known cameras."""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
import pytest

from service.core.frame import object_corners
from service.core.geometry import look_at, translation
from service.core.pose import (
    Camera,
    estimate_focal,
    fit_focal,
    focal_interval,
    focal_prior,
    solve_pose,
    zhang_focal,
)

OBJ = object_corners(25.0, 17.5, z=True)
SIZE = (1280, 720)
FX = 1000.0


def _view(centre: Sequence[float], fx: float = FX, noise: float = 0.0, seed: int = 0) -> np.ndarray:
    """The object's corners [4, 2] px seen from a level camera at `centre` cm looking at the
    object's centre, with Gaussian noise of `noise` px."""
    R = look_at(centre, [0.0, 0.0, 0.0])
    rvec, _ = cv2.Rodrigues(R)
    q, _ = cv2.projectPoints(OBJ, rvec, translation(R, centre), Camera(fx, SIZE).matrix, None)
    return q.reshape(4, 2) + np.random.default_rng(seed).normal(0.0, noise, (4, 2))


OBLIQUE: list[list[float]] = [
    [30, -20, 50],
    [-35, 10, 45],
    [5, 40, 55],
    [-20, -35, 60],
    [40, 30, 70],
    [0, -45, 50],
]


def test_the_pose_of_exact_corners_is_the_camera_that_saw_them() -> None:
    centre = np.array([20.0, -30.0, 55.0])
    pose = solve_pose(_view(list(centre)), OBJ, Camera(FX, SIZE))
    assert np.allclose(pose.centre, centre, atol=1e-6)
    assert pose.distance_cm == pytest.approx(np.linalg.norm(centre))
    assert pose.azimuth_deg == pytest.approx(np.degrees(np.arctan2(-30, 20)))
    assert pose.elevation_deg == pytest.approx(np.degrees(np.arcsin(55 / np.linalg.norm(centre))))
    assert pose.residual_px < 1e-6
    R, _ = cv2.Rodrigues(pose.rvec)
    assert np.allclose(-R.T @ pose.tvec, centre, atol=1e-6)  # OpenCV's pose of the same camera


def test_the_pose_is_on_the_printed_side_even_head_on() -> None:
    pose = solve_pose(_view([0.5, 0.3, 40.0]), OBJ, Camera(FX, SIZE))
    assert pose.centre[2] > 0 and pose.distance_cm == pytest.approx(40.0, rel=1e-3)


def test_corners_that_are_not_four_points_are_refused() -> None:
    with pytest.raises(ValueError, match="four finite"):
        solve_pose(np.zeros((3, 2)), OBJ, Camera(FX, SIZE))
    with pytest.raises(ValueError, match="four finite"):
        solve_pose(np.full((4, 2), np.nan), OBJ, Camera(FX, SIZE))


def test_zhang_gives_the_focal_length_of_exact_oblique_views() -> None:
    fx = zhang_focal([_view(c) for c in OBLIQUE], OBJ, SIZE)
    assert fx == pytest.approx(FX, rel=1e-6)


def test_zhang_gives_nothing_for_head_on_views() -> None:
    assert zhang_focal([_view([0, 0, 50]), _view([0, 0, 70])], OBJ, SIZE) is None


def test_more_views_narrow_the_focal_range_and_it_holds_the_truth() -> None:
    views = [_view(c, noise=1.0, seed=i) for i, c in enumerate(OBLIQUE)]
    one = focal_interval(views[:1], OBJ, SIZE, noise_px=1.0)
    all_ = focal_interval(views, OBJ, SIZE, noise_px=1.0)
    assert one[0] <= FX <= one[1] and all_[0] <= FX <= all_[1]
    assert all_[1] - all_[0] < 0.5 * (one[1] - one[0])


def test_one_head_on_view_keeps_the_prior_and_says_the_range_is_wide() -> None:
    fx, (lo, hi) = estimate_focal(_view([0.0, 0.0, 60.0], noise=0.5), OBJ, SIZE)
    assert fx == pytest.approx(focal_prior(SIZE), rel=0.01) and hi / lo > 2.0
    # an object's own prior (its profile's) is the one a head-on view keeps
    longer, _ = estimate_focal(_view([0.0, 0.0, 60.0], noise=0.5), OBJ, SIZE, prior=1.0)
    assert longer == pytest.approx(focal_prior(SIZE, 1.0), rel=0.01) and longer > fx


@pytest.mark.parametrize("prior", [0.5, 0.8, 1.2])
def test_one_oblique_view_pins_its_own_focal_length_whatever_the_prior(prior: float) -> None:
    """fx 1000 px, priors of 0.82-1.98 x that: the view's fit outweighs them."""
    view = _view(OBLIQUE[0], noise=0.3, seed=1)
    fx, (lo, hi) = estimate_focal(view, OBJ, SIZE, prior=prior, noise_px=0.3)
    assert fx == pytest.approx(FX, rel=0.02) and lo <= fx <= hi


def test_an_exact_oblique_view_is_not_held_to_the_scans_steps() -> None:
    """The scan steps by 6 %: an exact view allows one step, its estimate lies between."""
    fx, (lo, hi) = estimate_focal(_view(OBLIQUE[0]), OBJ, SIZE, noise_px=0.1)
    assert fx == pytest.approx(FX, rel=0.005) and lo <= fx <= hi


def test_a_view_between_head_on_and_oblique_is_drawn_to_the_prior_as_far_as_it_allows() -> None:
    """A view that allows a range of focal lengths: its estimate moves with the prior, within
    that range."""
    view = _view([15, -10, 60], noise=0.5, seed=2)
    estimates = [estimate_focal(view, OBJ, SIZE, prior=p, noise_px=0.5) for p in (0.5, 1.2)]
    (low, (lo, hi)), (high, _) = estimates
    assert lo <= low < high <= hi and hi / lo > 1.1


def test_a_symmetric_view_ippe_fails_on_at_some_focal_lengths_still_gets_an_estimate() -> None:
    """Seen from straight below its centre line, IPPE finds no pose at one of the scan's focal
    lengths: that one fits nothing, the rest decide."""
    view = _view([0, -45, 50])
    fx, (lo, hi) = estimate_focal(view, OBJ, SIZE, noise_px=0.3)
    assert fx == pytest.approx(FX, rel=0.05) and lo <= fx <= hi
    allowed = focal_interval([view], OBJ, SIZE, noise_px=0.3)
    assert allowed[0] <= FX <= allowed[1]


def test_one_camera_is_fitted_from_noisy_views_and_an_outlier_is_dropped() -> None:
    views = [_view(c, noise=0.5, seed=i) for i, c in enumerate(OBLIQUE)]
    views.append(_view([25, 25, 60], fx=2.5 * FX))  # another lens: does not fit
    fit = fit_focal(views, OBJ, SIZE)
    assert fit.fx == pytest.approx(FX, rel=0.03)
    assert fit.used.tolist() == [True] * len(OBLIQUE) + [False]
    assert fit.interval[0] <= fit.fx <= fit.interval[1] and fit.residual_px < 1.0


def test_one_view_is_not_enough_to_fit_a_camera() -> None:
    with pytest.raises(ValueError, match="at least 2 views"):
        fit_focal([_view(OBLIQUE[0])], OBJ, SIZE)


def test_a_camera_s_matrix_puts_the_principal_point_at_the_centre_unless_given() -> None:
    assert np.allclose(
        Camera(FX, SIZE).matrix, np.array([[FX, 0, 639.5], [0, FX, 359.5], [0, 0, 1]])
    )
    K = Camera(FX, SIZE, fy=990.0, cx=600.0, cy=350.0).matrix
    assert (K[1, 1], K[0, 2], K[1, 2]) == (990.0, 600.0, 350.0)
