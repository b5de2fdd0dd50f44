"""The classical peer a user would pick for a chessboard: OpenCV's detector + PnP + SPEC's rule.

For each image (RGB uint8 [H, W, 3] at the data set's size, e.g. the network's 80x60 or
160x120 input, blurred or not):

1. enlarged `enlarge` times (cubic, default 4x; 1 = as given), the camera intrinsics scaled
   with it (pixel centres kept: u' = (u + 0.5) s - 0.5, distortion unchanged);
2. the inner corners found by `cv2.findChessboardCornersSB` (exhaustive), falling back to
   `cv2.findChessboardCorners` + `cv2.cornerSubPix` (`train.real.corners.find_grid`);
3. their object coordinates (cm, object frame) by the colour parity rule
   (`train.real.corners.orient_grid`);
4. planar PnP (`cv2.solvePnP`, IPPE) with the image's own intrinsics and distortion, the camera
   centre c = -R^T t (cm, object frame) and SPEC section 3's class with the profile's z split.

No board found (or no usable pose) means class 0. Every step is inside the measured time.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import cv2
import numpy as np

from service.core.geometry import camera_centre
from service.core.regions import pose_class
from train.compare.baseline import BaselinePrediction, Peer, failure_summary, run_baseline
from train.network.evaluate import compute_metrics
from train.real.calibration import Camera
from train.real.corners import ChessboardPattern, find_grid, orient_grid, to_grey

#: How much a network-size image is enlarged before the detector runs (cubic).
ENLARGE = 4
#: Reason given when the detector finds no board.
NOT_FOUND = "no board found"


def enlarge_camera(camera: Camera, factor: float, size: tuple[int, int]) -> Camera:
    """`camera` (K px of an image of `size` (W, H)) for the image enlarged `factor` times."""
    if factor == 1:
        return camera
    K = np.diag([factor, factor, 1.0]) @ np.asarray(camera.K, np.float64)
    K[0, 2] += 0.5 * factor - 0.5
    K[1, 2] += 0.5 * factor - 0.5
    new = (round(size[0] * factor), round(size[1] * factor))
    return Camera(K, np.asarray(camera.dist, np.float64), new, camera.images)


def enlarged_grey(rgb: np.ndarray, factor: float) -> np.ndarray:
    """RGB uint8 [H, W, 3] -> grey uint8 enlarged `factor` times (cubic; 1: as given)."""
    grey = to_grey(rgb)
    if factor == 1:
        return grey
    h, w = grey.shape
    size = (round(w * factor), round(h * factor))
    return cv2.resize(grey, size, interpolation=cv2.INTER_CUBIC)


class ChessboardPeer:
    """OpenCV's chessboard detector + IPPE PnP + the region rule for one chessboard profile.

    `pattern`: the inner corner grid and square size (`train.real.label.chessboard_pattern`);
    `z_split_cm`: the near / far split of the profile's regions; `enlarge`: see module doc.
    """

    name = "chessboard"

    def __init__(self, pattern: ChessboardPattern, z_split_cm: float, enlarge: float = ENLARGE):
        if enlarge < 1:
            raise ValueError(f"enlarge must be >= 1, got {enlarge}")
        self.pattern, self.z_split, self.enlarge = pattern, float(z_split_cm), float(enlarge)

    def predict(self, rgb: np.ndarray, camera: Camera) -> BaselinePrediction:
        """Class of one RGB uint8 [H, W, 3] image whose intrinsics are `camera` (at H x W)."""
        h, w = rgb.shape[:2]
        cam = enlarge_camera(camera, self.enlarge, (w, h))
        grey = enlarged_grey(rgb, self.enlarge)
        raw = find_grid(grey, self.pattern)
        if raw is None:
            return BaselinePrediction(0, None, NOT_FOUND, "", 0)
        object_xy, _ = orient_grid(grey, raw, self.pattern, cam.undistort, cam.K)
        object_xyz = np.column_stack([object_xy, np.zeros(len(object_xy))])
        ok, rvec, tvec = cv2.solvePnP(
            object_xyz, raw.reshape(-1, 1, 2), cam.K, cam.dist, flags=cv2.SOLVEPNP_IPPE
        )
        if not ok:
            return BaselinePrediction(0, None, "PnP failed", "chessboard", len(raw))
        R, _ = cv2.Rodrigues(rvec)
        centre = camera_centre(R, tvec.ravel())
        if not np.all(np.isfinite(centre)) or centre[2] <= 0:
            return BaselinePrediction(0, None, "camera behind the board", "chessboard", 0)
        label = int(pose_class(centre, self.z_split))
        return BaselinePrediction(label, centre, "", "chessboard", len(raw))


def evaluate_peer(
    peer: Peer,
    images: np.ndarray | Sequence[np.ndarray],
    labels: np.ndarray,
    cameras: Sequence[Camera],
    progress: Callable[[int], Any] | None = None,
    margin_cm: np.ndarray | None = None,
) -> tuple[dict[str, Any], dict[str, int]]:
    """SPEC 10 metrics (`train.network.evaluate.compute_metrics`, by the cameras' margins
    [N] cm when given) and the failure reasons."""
    preds, ms = run_baseline(peer, images, cameras, progress)
    predicted = np.array([p.label for p in preds], np.int64)
    metrics = compute_metrics(labels, predicted, ms, margin_cm)
    return metrics, failure_summary(preds)
