"""Pose geometry of a planar object (SPEC sections 2-5, 7), as small pure numpy functions.

Frames and units:

* World frame = object frame: origin at the centre of the rectangle, the object in z = 0,
  x along its width, y towards the top of its texture, z towards the side that shows the
  texture (the viewer). Units: cm.
* Camera frame: x right, y down (image rows), z forward along the optical axis. A pose is
  (R, t) with X_cam = R @ X_world + t; R is world -> camera, t in cm.
* Image: pixels (u, v), u to the right, v down, origin at the top-left pixel's centre.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from service.core.inputs import spec_camera
from service.core.regions import RegionGeometry

FloatArray = NDArray[np.float64]


def intrinsics(size: tuple[int, int], focal_scale: float = 1.0) -> FloatArray:
    """Intrinsic matrix A (3, 3) for an image of `size` = (W, H) pixels.

    The SPEC camera at that width (`spec_camera`); `focal_scale` further multiplies fx and fy
    (a longer or shorter lens with the same principal point).
    """
    fx, fy, u0, v0 = spec_camera(size[0])
    return np.array([[fx * focal_scale, 0.0, u0], [0.0, fy * focal_scale, v0], [0, 0, 1.0]])


def look_at(c: ArrayLike, t: ArrayLike, roll_rad: float = 0.0) -> FloatArray:
    """World -> camera rotation R (3, 3) of a camera at `c` looking at `t` (cm), SPEC section 5.

    Rows of R are the camera axes in world coordinates: zC = (t - c) / |t - c|; xC horizontal
    (zero z component) and orthogonal to zC; yC = zC x xC with a negative z component, so the
    camera is level and world +z points up in the image. When zC is vertical, xC = (1, 0, 0).
    `roll_rad` then turns the camera about its optical axis: the image content rotates by
    +roll_rad (counter-clockwise as displayed, image y pointing down).
    """
    c = np.asarray(c, dtype=float)
    d = np.asarray(t, dtype=float) - c
    norm = np.linalg.norm(d)
    if norm == 0:
        raise ValueError("camera centre and target coincide")
    z_c = d / norm
    h_norm = float(np.hypot(z_c[0], z_c[1]))
    # Of the two horizontal unit vectors orthogonal to zC, (zy, -zx, 0) / |.| is the one giving
    # yC = zC x xC the z component -(zx^2 + zy^2) / |.| < 0; straight down/up: world x.
    x_c = np.array([1.0, 0.0, 0.0]) if h_norm < 1e-12 else np.array([z_c[1], -z_c[0], 0.0]) / h_norm
    # zC x xC written out (xC has no z component): hot in data generation.
    y_c = np.array([-z_c[2] * x_c[1], z_c[2] * x_c[0], z_c[0] * x_c[1] - z_c[1] * x_c[0]])
    level = np.stack([x_c, y_c, z_c])
    if roll_rad == 0.0:
        return level
    cr, sr = np.cos(roll_rad), np.sin(roll_rad)
    # Camera axes turned by -roll about zC, so the image content turns by +roll.
    roll = np.array([[cr, sr, 0.0], [-sr, cr, 0.0], [0.0, 0.0, 1.0]])
    return roll @ level


def translation(R: ArrayLike, c: ArrayLike) -> FloatArray:
    """Translation t = -R c (cm) of a camera with rotation R (3, 3) and centre c (3,)."""
    return -np.asarray(R, dtype=float) @ np.asarray(c, dtype=float)


def camera_centre(R: ArrayLike, t: ArrayLike) -> FloatArray:
    """Camera centre c = -R^T t (cm, world frame) of the pose (R, t)."""
    return -np.asarray(R, dtype=float).T @ np.asarray(t, dtype=float)


def project_points(A: ArrayLike, R: ArrayLike, t: ArrayLike, X: ArrayLike) -> FloatArray:
    """Project world points X (N, 3) cm to pixels (N, 2) through A (3, 3) and the pose (R, t)."""
    Xc = np.asarray(X, dtype=float).reshape(-1, 3) @ np.asarray(R, dtype=float).T + t
    uvw = Xc @ np.asarray(A, dtype=float).T
    return uvw[:, :2] / uvw[:, 2:3]


def homography_from_pose(A: ArrayLike, R: ArrayLike, t: ArrayLike) -> FloatArray:
    """Homography H = A [r1 r2 t] (3, 3): object plane point (x, y) cm -> pixel (u, v)."""
    R = np.asarray(R, dtype=float)
    H = np.asarray(A, dtype=float) @ np.column_stack([R[:, 0], R[:, 1], t])
    return H / H[2, 2]


def apply_homography(H: ArrayLike, pts: ArrayLike) -> FloatArray:
    """Map points (N, 2) through the homography H (3, 3) -> (N, 2)."""
    p = np.asarray(pts, dtype=float).reshape(-1, 2)
    q = np.column_stack([p, np.ones(len(p))]) @ np.asarray(H, dtype=float).T
    return q[:, :2] / q[:, 2:3]


def _normalising_transform(p: FloatArray) -> FloatArray:
    """Similarity T (3, 3) moving points (N, 2) to zero mean and mean distance sqrt(2)."""
    mean = p.mean(axis=0)
    dist = np.linalg.norm(p - mean, axis=1).mean()
    if dist == 0:
        raise ValueError("degenerate points: all coincide")
    s = np.sqrt(2.0) / dist
    return np.array([[s, 0.0, -s * mean[0]], [0.0, s, -s * mean[1]], [0.0, 0.0, 1.0]])


def dlt_homography(src: ArrayLike, dst: ArrayLike) -> FloatArray:
    """Homography H (3, 3), dst ~ H src, from N >= 4 point pairs (N, 2) by normalised DLT.

    Hartley normalisation of both point sets, the 2N x 9 DLT system solved by SVD, then
    denormalised and scaled so that H[2, 2] = 1 (or |H| = 1 if H[2, 2] vanishes).
    """
    s = np.asarray(src, dtype=float).reshape(-1, 2)
    d = np.asarray(dst, dtype=float).reshape(-1, 2)
    if len(s) != len(d) or len(s) < 4:
        raise ValueError(f"need >= 4 point pairs of equal count, got {len(s)} and {len(d)}")
    Ts, Td = _normalising_transform(s), _normalising_transform(d)
    sn = apply_homography(Ts, s)
    dn = apply_homography(Td, d)
    rows = []
    for (x, y), (u, v) in zip(sn, dn, strict=True):
        rows.append([-x, -y, -1.0, 0.0, 0.0, 0.0, u * x, u * y, u])
        rows.append([0.0, 0.0, 0.0, -x, -y, -1.0, v * x, v * y, v])
    _, sv, vt = np.linalg.svd(np.asarray(rows))
    if sv[-2] < 1e-12 * sv[0]:
        raise ValueError("degenerate point configuration (collinear points?)")
    H = np.linalg.inv(Td) @ vt[-1].reshape(3, 3) @ Ts
    return H / H[2, 2] if abs(H[2, 2]) > 1e-12 else H / np.linalg.norm(H)


def pose_from_homography(H: ArrayLike, A: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Pose (R (3, 3), t (3,) cm) from an object-plane homography H and intrinsics A.

    M = A^-1 H = lambda [r1 r2 t]; lambda from the mean norm of the first two columns, the
    sign chosen so the object lies in front of the camera (t_z > 0); R = [r1 r2 r1 x r2]
    projected onto the nearest rotation by SVD.
    """
    M = np.linalg.solve(np.asarray(A, dtype=float), np.asarray(H, dtype=float))
    scale = 2.0 / (np.linalg.norm(M[:, 0]) + np.linalg.norm(M[:, 1]))
    if M[2, 2] < 0:
        scale = -scale
    r1, r2, t = M[:, 0] * scale, M[:, 1] * scale, M[:, 2] * scale
    U, _, Vt = np.linalg.svd(np.column_stack([r1, r2, np.cross(r1, r2)]))
    R = U @ Vt
    if np.linalg.det(R) < 0:
        R = U @ np.diag([1.0, 1.0, -1.0]) @ Vt
    return R, t


def fibonacci_hemisphere(n: int, radius: float, centre_z: float = 0.0) -> FloatArray:
    """`n` points (n, 3) spread with equal area over the upper hemisphere (z >= centre_z).

    Fibonacci lattice: equal steps in height (equal area on a sphere) and golden-angle steps
    in azimuth. Centre (0, 0, centre_z), radius in cm.
    """
    if n < 1 or radius <= 0:
        raise ValueError(f"need n >= 1 and radius > 0, got n={n}, radius={radius}")
    i = np.arange(n)
    z = (i + 0.5) / n
    phi = i * np.pi * (3.0 - np.sqrt(5.0))
    r_xy = np.sqrt(1.0 - z**2)
    pts = np.column_stack([r_xy * np.cos(phi), r_xy * np.sin(phi), z]) * radius
    pts[:, 2] += centre_z
    return pts


def camera_lattice(
    geometry: RegionGeometry,
    radii: Iterable[float],
    heights: Iterable[float],
    n_per_hemisphere: int,
) -> FloatArray:
    """Camera centres (M, 3) cm: hemispheres of each radius centred at (0, 0, h) for each h,
    kept inside the geometry's box (SPEC section 4)."""
    parts = [fibonacci_hemisphere(n_per_hemisphere, r, h) for r in radii for h in heights]
    if not parts:
        raise ValueError("need at least one radius and one height")
    pts = np.concatenate(parts)
    return pts[geometry.contains(pts)]


def roll_of_pose(R: np.ndarray) -> float:
    """Roll (degrees, in (-180, 180]) of a camera with world -> camera rotation R (3, 3).

    The angle about the optical axis between R and the level camera of SPEC 5 with the same
    optical axis: R = Rz(roll) @ look_at(...), the convention of `look_at`
    (the image content turns counter-clockwise by +roll).
    """
    R = np.asarray(R, dtype=float)
    axis = R[2]
    level = look_at(np.zeros(3), axis)
    turn = R @ level.T  # a rotation about the optical axis
    return float(np.degrees(np.arctan2(turn[0, 1], turn[0, 0])))
