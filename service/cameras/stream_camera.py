"""The camera a stream learns from its own frames (`WS /v1/stream` without fx or camera=).

Each answered frame whose object was found offers its corners. A view is kept when the camera
has turned by `MIN_TURN_DEG` or more since every kept view (a still camera adds nothing);
once `MIN_VIEWS` are kept, their camera (`service.core.calibration.fit_camera`, the fit of
`POST /v1/cameras`: views that do not fit are dropped; the lens too where the frames' refinements
pin it) is taken when the views pin its focal length, and fitted again with every new view,
over the latest `MAX_VIEWS`.
"""

from __future__ import annotations

import math
from collections import deque

import cv2
import numpy as np

from service.core.calibration import fit_camera
from service.core.frame import object_corners
from service.core.pose import Camera, focal_prior, solve_pose
from service.core.refine import Features
from service.pipeline.focal import KnownFocal

MIN_VIEWS = 5
MAX_VIEWS = 30
MIN_TURN_DEG = 4.0


class StreamCamera:
    """The focal length a stream of frames of one size has shown so far (`known`)."""

    def __init__(self, size_cm: tuple[float, float]) -> None:
        self.object = object_corners(*size_cm, z=True)
        self.size: tuple[int, int] | None = None
        self.views: deque[np.ndarray] = deque(maxlen=MAX_VIEWS)
        self.kappas: deque[float | None] = deque(maxlen=MAX_VIEWS)  # each view's fitted lens
        self.features: deque[Features | None] = deque(maxlen=MAX_VIEWS)  # followed features
        self.turns: deque[np.ndarray] = deque(maxlen=MAX_VIEWS)  # each view's rotation
        self.known: KnownFocal | None = None

    def offer(
        self,
        corners: np.ndarray,
        size: tuple[int, int],
        kappa: float | None = None,
        features: Features | None = None,
    ) -> None:
        """A frame's pinhole corners [4, 2] px of an image of `size` (W, H), the radial lens
        its refinement fitted (kappa px^-2, `service.pipeline.predictor.Prediction.kappas`)
        and the texture's features it followed (`Prediction.features`): kept if the camera
        turned since the kept views, then the camera fitted again (`fit_camera`). Frames of
        another size start over (another camera, or another resolution)."""
        if size != self.size:
            self.size, self.known = size, None
            self.views.clear()
            self.kappas.clear()
            self.features.clear()
            self.turns.clear()
        q = np.asarray(corners, np.float64)
        try:
            R = cv2.Rodrigues(solve_pose(q, self.object, Camera(focal_prior(size), size)).rvec)[0]
        except (ValueError, cv2.error):
            return
        if any(_angle_deg(R, other) < MIN_TURN_DEG for other in self.turns):
            return
        self.views.append(q)
        self.kappas.append(kappa)
        self.features.append(features)
        self.turns.append(R)
        if len(self.views) < MIN_VIEWS:
            return
        try:
            views, kappas, seen = list(self.views), list(self.kappas), list(self.features)
            fit = fit_camera(views, kappas, self.object, size, seen)
        except (ValueError, cv2.error):
            return
        if fit.pinned:  # fx and the lens: the answers state fx alone (`fx_source: stream`)
            self.known = KnownFocal(fit.fx, "stream", size, dist=fit.dist, lens_learned=True)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle (degrees) of the rotation between two rotations (3, 3)."""
    cos = (np.trace(a @ b.T) - 1.0) / 2.0
    return math.degrees(math.acos(max(-1.0, min(1.0, cos))))
