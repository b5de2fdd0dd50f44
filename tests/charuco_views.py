"""Synthetic views of the ChArUco profile's printed board, for the ChArUco tests."""

from __future__ import annotations

import cv2
import numpy as np

from service.core.frame import texture_to_object
from service.core.geometry import homography_from_pose, look_at, translation
from service.core.profile import load_profile
from train.real.charuco import board_texture, charuco_spec

PROFILE = load_profile("charuco")
SPEC = charuco_spec(PROFILE)
assert SPEC is not None
K = np.array([[700.0, 0.0, 639.5], [0.0, 700.0, 359.5], [0.0, 0.0, 1.0]])


def view(centre: tuple[float, float, float], roll_deg: float = 20.0) -> np.ndarray:
    """The printed board (on white paper) seen from `centre` (cm, object frame): RGB 1280x720."""
    texture = board_texture(SPEC)
    R = look_at(centre, (1.0, -2.0, 0.0), np.radians(roll_deg))
    H = homography_from_pose(K, R, translation(R, centre))
    tex = texture_to_object((texture.shape[1], texture.shape[0]), *SPEC.size_cm)
    paper = cv2.copyMakeBorder(texture, 40, 40, 40, 40, cv2.BORDER_CONSTANT, value=(240,) * 3)
    shift = np.array([[1.0, 0, -40], [0, 1, -40], [0, 0, 1]])
    warp = H @ tex @ shift
    return cv2.warpPerspective(paper, warp, (1280, 720), flags=cv2.INTER_AREA, borderValue=90)
