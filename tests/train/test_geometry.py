"""Property tests of service.core.geometry: look-at, homographies, DLT, pose recovery, regions."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from service.core.geometry import (
    apply_homography,
    camera_centre,
    camera_lattice,
    dlt_homography,
    fibonacci_hemisphere,
    homography_from_pose,
    intrinsics,
    look_at,
    pose_from_homography,
    project_points,
    translation,
)
from service.core.regions import RegionGeometry, pose_class

GEOM = RegionGeometry()
coord = st.floats(-36.86, 36.86, allow_nan=False)
height = st.floats(10.68, 92.40, allow_nan=False)
offset = st.floats(-3.0, 3.0, allow_nan=False)
angle = st.floats(-np.pi, np.pi, allow_nan=False)
W_CM, H_CM = 25.0, 17.5
CORNERS = np.array(
    [[-W_CM / 2, -H_CM / 2], [W_CM / 2, -H_CM / 2], [W_CM / 2, H_CM / 2], [-W_CM / 2, H_CM / 2]]
)


def test_intrinsics_match_spec_and_halve() -> None:
    A2 = intrinsics((160, 120))
    np.testing.assert_allclose(
        A2[[0, 1, 0, 1], [0, 1, 2, 2]], [206.0358, 205.1238, 80.0534, 49.8627]
    )
    np.testing.assert_allclose(intrinsics((80, 60))[:2], A2[:2] / 2)


@settings(max_examples=200, deadline=None)
@given(coord, coord, height, offset, offset, angle)
def test_dlt_pose_recovers_camera_centre(x, y, z, tx, ty, roll) -> None:
    c = np.array([x, y, z])
    R = look_at(c, [tx, ty, 0.0], roll)
    t = translation(R, c)
    A = intrinsics((160, 120))
    pixels = project_points(A, R, t, np.column_stack([CORNERS, np.zeros(4)]))
    H = dlt_homography(CORNERS, pixels)
    R2, t2 = pose_from_homography(H, A)
    c2 = camera_centre(R2, t2)
    assert np.linalg.norm(c2 - c) <= 1e-6 * np.linalg.norm(c)
    np.testing.assert_allclose(R2, R, atol=1e-6)
    # The homography from the pose maps the corners to the same pixels.
    np.testing.assert_allclose(
        apply_homography(homography_from_pose(A, R, t), CORNERS), pixels, atol=1e-6
    )


@settings(max_examples=200, deadline=None)
@given(coord, coord, height, offset, offset)
def test_look_at_is_rotation_and_centres_target(x, y, z, tx, ty) -> None:
    c, target = np.array([x, y, z]), np.array([tx, ty, 0.0])
    assume(np.linalg.norm(target - c) > 1e-3)
    R = look_at(c, target)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    A = intrinsics((160, 120))
    uv = project_points(A, R, translation(R, c), target[None])[0]
    np.testing.assert_allclose(uv, A[:2, 2], atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(coord, coord, height, offset, offset)
def test_camera_is_level_world_up_is_image_up(x, y, z, tx, ty) -> None:
    c, target = np.array([x, y, z]), np.array([tx, ty, 0.0])
    assume(np.hypot(*(target - c)[:2]) > 1e-3)  # not looking straight down
    R = look_at(c, target)
    assert abs(R[0, 2]) < 1e-12  # image x axis is horizontal in the world: no roll
    assert R[1, 2] < 0  # image y (down) has a negative world z: +z projects upward
    A = intrinsics((160, 120))
    t = translation(R, c)
    below, above = project_points(A, R, t, [target, target + [0, 0, 1.0]])
    assert above[1] < below[1]


@settings(max_examples=100, deadline=None)
@given(coord, coord, height, angle)
def test_roll_turns_image_about_principal_point(x, y, z, roll) -> None:
    c = np.array([x, y, z])
    assume(np.hypot(x, y) > 1e-3)
    A = intrinsics((160, 120))
    p = np.array([[5.0, 3.0, 0.0]])
    R0, R1 = look_at(c, np.zeros(3)), look_at(c, np.zeros(3), roll)
    d0 = project_points(A, R0, translation(R0, c), p)[0] - A[:2, 2]
    d1 = project_points(A, R1, translation(R1, c), p)[0] - A[:2, 2]
    # Undo the (anisotropic) focal lengths; then the two differ by a pure rotation by +roll
    # in display coordinates (image y down): atan2(-v, u) grows by roll.
    f = np.array([A[0, 0], A[1, 1]])
    a0 = np.arctan2(-d0[1] / f[1], d0[0] / f[0])
    a1 = np.arctan2(-d1[1] / f[1], d1[0] / f[0])
    assert np.angle(np.exp(1j * (a1 - a0 - roll))) == pytest.approx(0.0, abs=1e-9)


def test_vertical_axis_uses_world_x() -> None:
    R = look_at([0.0, 0.0, 50.0], [0.0, 0.0, 0.0])
    np.testing.assert_allclose(R[0], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(R[2], [0.0, 0.0, -1.0])


def test_camera_on_plus_y_sees_top_edge_at_bottom() -> None:
    c = np.array([0.0, 50.0, 50.0])
    R = look_at(c, np.zeros(3))
    A = intrinsics((160, 120))
    top, bottom = project_points(A, R, translation(R, c), [[0, H_CM / 2, 0], [0, -H_CM / 2, 0]])
    assert top[1] > bottom[1]


eps = 1e-9


@pytest.mark.parametrize(
    ("c", "expected"),
    [
        ((0.0, 0.0, 59.999), 1),
        ((0.0, 0.0, 60.0), 5),
        ((-eps, 0.0, 30.0), 2),
        ((-eps, -eps, 30.0), 3),
        ((0.0, -eps, 30.0), 4),
        ((eps, eps, 80.0), 5),
        ((-eps, eps, 80.0), 6),
        ((-eps, -eps, 80.0), 7),
        ((eps, -eps, 60.0 + eps), 8),
    ],
)
def test_region_labels_near_split_planes(c, expected) -> None:
    assert int(pose_class(np.array(c), 60.0)) == expected


@given(coord, coord, height, st.floats(20, 80))
def test_region_labels_match_definition(x, y, z, z_split) -> None:
    quadrant = {(True, True): 1, (False, True): 2, (False, False): 3, (True, False): 4}
    expected = quadrant[(x >= 0, y >= 0)] + (4 if z >= z_split else 0)
    assert int(pose_class([x, y, z], z_split)) == expected


def test_pose_class_vectorised_shape() -> None:
    pts = np.random.default_rng(0).uniform(-30, 30, size=(4, 5, 3))
    assert pose_class(pts, 0.0).shape == (4, 5)


def test_fibonacci_hemisphere_equal_area_and_radius() -> None:
    pts = fibonacci_hemisphere(2000, 40.0, 10.0)
    r = np.linalg.norm(pts - [0, 0, 10.0], axis=1)
    np.testing.assert_allclose(r, 40.0)
    assert pts[:, 2].min() >= 10.0
    # Equal area: heights uniform on the hemisphere (Archimedes), azimuths spread evenly.
    counts, _ = np.histogram(pts[:, 2], bins=10, range=(10.0, 50.0))
    assert counts.min() >= 195 and counts.max() <= 205
    az, _ = np.histogram(np.arctan2(pts[:, 1], pts[:, 0]), bins=8, range=(-np.pi, np.pi))
    assert az.min() >= 230 and az.max() <= 270


def test_camera_lattice_inside_box_and_covers_all_classes() -> None:
    pts = camera_lattice(GEOM, radii=[20, 40, 60, 80], heights=[0, 15, 30], n_per_hemisphere=400)
    assert GEOM.contains(pts).all()
    classes = pose_class(pts, GEOM.z_split_cm)
    assert set(np.unique(classes)) == set(range(1, 9))


def test_dlt_rejects_degenerate_input() -> None:
    with pytest.raises(ValueError, match=">= 4"):
        dlt_homography(np.zeros((3, 2)), np.zeros((3, 2)))
    line = np.column_stack([np.arange(5.0), np.arange(5.0)])
    with pytest.raises(ValueError, match="degenerate"):
        dlt_homography(line, line * 2)


def test_dlt_with_noise_is_least_squares_close() -> None:
    rng = np.random.default_rng(1)
    H_true = np.array([[1.2, 0.1, 30.0], [-0.05, 0.9, 20.0], [1e-4, 2e-4, 1.0]])
    src = rng.uniform(-50, 50, size=(40, 2))
    dst = apply_homography(H_true, src) + rng.normal(0, 0.01, size=(40, 2))
    H = dlt_homography(src, dst)
    assert np.abs(apply_homography(H, src) - dst).max() < 0.05
