"""The classical peer a user would pick for a ChArUco board: OpenCV's ChArUco detector + PnP.

Like `train.compare.chessboard_peer`, for each image (RGB uint8 [H, W, 3] at the data set's
size): enlarged `enlarge` times with its intrinsics, the ChArUco corners found by OpenCV's
detector (inverted markers where the board is printed so, at least
`train.real.charuco.MIN_CORNERS`), their object coordinates from their ids, planar PnP (IPPE)
with the image's intrinsics, the camera centre and the region rule. Fewer corners (or no
usable pose) means class 0. Every step is inside the measured time.
"""

from __future__ import annotations

import cv2
import numpy as np

from service.core.geometry import camera_centre
from service.core.regions import pose_class
from train.compare.baseline import BaselinePrediction
from train.compare.chessboard_peer import ENLARGE, NOT_FOUND, enlarge_camera
from train.real.calibration import Camera
from train.real.charuco import CharucoFinder, CharucoSpec


class CharucoPeer:
    """OpenCV's ChArUco detector + IPPE PnP + the region rule for one ChArUco profile."""

    name = "charuco"

    def __init__(self, spec: CharucoSpec, z_split_cm: float, enlarge: float = ENLARGE):
        if enlarge < 1:
            raise ValueError(f"enlarge must be >= 1, got {enlarge}")
        self.finder, self.z_split, self.enlarge = CharucoFinder(spec), float(z_split_cm), enlarge

    def predict(self, rgb: np.ndarray, camera: Camera) -> BaselinePrediction:
        """Class of one RGB uint8 [H, W, 3] image whose intrinsics are `camera` (at H x W)."""
        h, w = rgb.shape[:2]
        cam = enlarge_camera(camera, self.enlarge, (w, h))
        if self.enlarge != 1:
            size = (round(w * self.enlarge), round(h * self.enlarge))
            rgb = cv2.resize(rgb, size, interpolation=cv2.INTER_CUBIC)
        corr = self.finder.find(rgb)
        if corr is None:
            return BaselinePrediction(0, None, NOT_FOUND, "", 0)
        object_xyz = np.column_stack([corr.object_xy, np.zeros(len(corr.object_xy))])
        ok, rvec, tvec = cv2.solvePnP(
            object_xyz, corr.image_uv.reshape(-1, 1, 2), cam.K, cam.dist, flags=cv2.SOLVEPNP_IPPE
        )
        if not ok:
            return BaselinePrediction(0, None, "PnP failed", "charuco", len(corr.image_uv))
        R, _ = cv2.Rodrigues(rvec)
        centre = camera_centre(R, tvec.ravel())
        if not np.all(np.isfinite(centre)) or centre[2] <= 0:
            return BaselinePrediction(0, None, "camera behind the board", "charuco", 0)
        label = int(pose_class(centre, self.z_split))
        return BaselinePrediction(label, centre, "", "charuco", len(corr.image_uv))
