"""Camera intrinsics for real photographs: a calibration file, or a documented default guess.

Calibration JSON, either one camera

    {"K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], "dist": [k1, k2, p1, p2, k3],
     "image_size_wh": [W, H]}

or several, as train/assets/real/chessboard-stereo/calibration.json has them

    {"cameras": {"left": {"K": ..., "dist_k1k2p1p2k3": [...], "image_size_wh": [W, H],
                          "per_image": {"left01.jpg": {...}, ...}}, "right": {...}}}

`dist` (OpenCV order k1, k2, p1, p2[, k3 ...]) and `image_size_wh` are optional. An image uses
the camera that lists it under `per_image`, else the only camera, else the camera whose name
starts the file name (left01.jpg -> "left"). K is scaled to the image's size when it differs
from `image_size_wh` (same aspect ratio expected); distortion coefficients do not depend on
the scale.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from service.core.geometry import intrinsics


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics K (3, 3) px, OpenCV distortion (k,) and the calibrated size (W, H)."""

    K: np.ndarray
    dist: np.ndarray
    size: tuple[int, int] | None = None
    images: frozenset[str] = field(default_factory=frozenset)

    def scaled(self, size: tuple[int, int]) -> Camera:
        """The same camera for images of `size` (W, H): K scaled by the width ratio."""
        if self.size is None or tuple(size) == tuple(self.size):
            return self
        sx, sy = size[0] / self.size[0], size[1] / self.size[1]
        if abs(sx - sy) > 0.02 * sx:
            raise ValueError(
                f"image size {size[0]}x{size[1]} has another aspect ratio than the "
                f"calibrated {self.size[0]}x{self.size[1]}"
            )
        K = np.diag([sx, sy, 1.0]) @ self.K
        # Pixel centres at integers: (u + 0.5) * s - 0.5.
        K[0, 2] += 0.5 * sx - 0.5
        K[1, 2] += 0.5 * sy - 0.5
        return Camera(K, self.dist, (int(size[0]), int(size[1])), self.images)

    def undistort(self, uv: np.ndarray) -> np.ndarray:
        """Raw pixels (N, 2) -> ideal pinhole pixels (N, 2) of the same K."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        if not np.any(self.dist):
            return uv
        pts = cv2.undistortPoints(uv.reshape(-1, 1, 2), self.K, self.dist, P=self.K)
        return pts.reshape(-1, 2)


def default_camera(size: tuple[int, int]) -> Camera:
    """The default guess for an uncalibrated photograph of `size` (W, H).

    The SPEC camera's field of view (fx = fy scaled from 206 px at 160 px wide, about 42 deg
    horizontally, `service.core.geometry.intrinsics`) with the principal point at the image centre
    and no distortion. Positions in cm are only as good as this guess: calibrate for real
    measurements.
    """
    A = intrinsics(size)
    A[0, 2], A[1, 2] = (size[0] - 1) / 2, (size[1] - 1) / 2
    return Camera(A, np.zeros(5), (int(size[0]), int(size[1])))


def _camera(entry: dict[str, Any], where: str) -> Camera:
    try:
        K = np.asarray(entry["K"], dtype=np.float64)
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{where}: needs a 3x3 'K' of numbers") from exc
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"{where}: 'K' must be a 3x3 matrix with positive focal lengths")
    dist = np.asarray(entry.get("dist", entry.get("dist_k1k2p1p2k3", [])), dtype=np.float64)
    if dist.size not in (0, 4, 5, 8, 12, 14):
        raise ValueError(f"{where}: distortion needs 4, 5, 8, 12 or 14 OpenCV coefficients")
    size = entry.get("image_size_wh")
    if size is not None and (len(size) != 2 or min(size) <= 0):
        raise ValueError(f"{where}: 'image_size_wh' must be [W, H]")
    images = frozenset(entry.get("per_image", {}))
    wh = None if size is None else (int(size[0]), int(size[1]))
    return Camera(K, dist if dist.size else np.zeros(5), wh, images)


class Calibration:
    """The cameras of a calibration file, chosen per image (see the module docstring)."""

    def __init__(self, cameras: dict[str, Camera], source: str) -> None:
        if not cameras:
            raise ValueError(f"{source}: no camera in the calibration")
        self.cameras, self.source = cameras, source

    @classmethod
    def load(cls, path: Path) -> Calibration:
        """Read a calibration JSON file; ValueError / FileNotFoundError with a precise message."""
        if not path.is_file():
            raise FileNotFoundError(f"calibration file not found: {path}")
        try:
            doc = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ValueError(f"{path}: not valid JSON ({exc})") from None
        if not isinstance(doc, dict):
            raise ValueError(f"{path}: expected a JSON object")
        if "cameras" in doc:
            if not isinstance(doc["cameras"], dict):
                raise ValueError(f"{path}: 'cameras' must be an object of named cameras")
            cams = {n: _camera(c, f"{path} camera {n!r}") for n, c in doc["cameras"].items()}
        else:
            cams = {"camera": _camera(doc, str(path))}
        return cls(cams, str(path))

    def camera_name(self, file: str) -> str:
        """Which camera took `file` (a file name)."""
        for name, cam in self.cameras.items():
            if file in cam.images:
                return name
        if len(self.cameras) == 1:
            return next(iter(self.cameras))
        prefixed = [n for n in self.cameras if Path(file).name.lower().startswith(n.lower())]
        if len(prefixed) == 1:
            return prefixed[0]
        raise ValueError(f"{self.source}: cannot tell which camera took {file}")

    def for_image(self, file: str, size: tuple[int, int]) -> Camera:
        """The camera of `file`, scaled to the image's `size` (W, H)."""
        return self.cameras[self.camera_name(file)].scaled(size)
