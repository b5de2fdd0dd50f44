"""The focal length a request knows (`KnownFocal`), and the range of one it may give.

Where it came from: the request's `fx`, a stored camera (`service.cameras`), the photo's
EXIF (`exif.py`) or the camera a stream learns. The range is checked once, where a number
becomes a `KnownFocal`: the HTTP query's bounds (`service.api.deps`), a stream's query
(`fx_problem`), a stored camera's record (`service.cameras.schema`); the pipeline takes a
`KnownFocal` as checked.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from service.core.pose import Camera
from service.pipeline.results import FocalSource

#: The range of a camera's focal length `fx` a request or a stored camera may give, in pixels
#: of its images: a fisheye of 1 px per radian on a tiny image to a long lens on a large
#: sensor (a 600 mm lens on a 24 mm wide 8000 px sensor is 200,000 px: 1e5 is f = 300 mm
#: there). Outside, float32 would turn it to 0 (unknown) or inf.
FX_MIN_PX, FX_MAX_PX = 1.0, 100_000.0


def fx_problem(fx: float) -> str | None:
    """Why `fx` px is not a focal length a request may give, or None where it is."""
    if math.isfinite(fx) and FX_MIN_PX <= fx <= FX_MAX_PX:
        return None
    return f"fx: must be {FX_MIN_PX:g} to {FX_MAX_PX:g} pixels, got {fx}"


@dataclass(frozen=True)
class KnownFocal:
    """A focal length a request knows and where it came from: fx (and optionally fy, the
    principal point, OpenCV's distortion) px of images `size` (W, H) (None: any size);
    `lens_learned`: the distortion was learned from photos (`service.core.calibration`): each
    image fits its own lens instead, which answered more of the ChArUco val frames."""

    fx: float
    source: FocalSource
    size: tuple[int, int] | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    dist: tuple[float, ...] | None = None
    lens_learned: bool = False

    @classmethod
    def of_camera(cls, camera: Camera, source: FocalSource = "camera") -> KnownFocal:
        """A calibrated camera (`service.core.pose.Camera`) as a request knows it."""
        return cls(camera.fx, source, camera.size, camera.fy, camera.cx, camera.cy, camera.dist)

    def scale(self, size: tuple[int, int]) -> float:
        """Pixels of an image of `size` (W, H) per pixel of the camera's own images."""
        return 1.0 if self.size is None else max(size) / max(self.size)

    def camera(self, size: tuple[int, int]) -> Camera:
        """The camera for an image of `size` (W, H): the intrinsics scaled to it (a principal
        point given for the camera's own size moves with it; turned with a portrait photo of
        a landscape camera, where it would be the wrong way round, it is the centre)."""
        s = self.scale(size)
        same_way = self.size is None or (size[0] >= size[1]) == (self.size[0] >= self.size[1])
        return Camera(
            self.fx * s,
            size,
            None if self.fy is None else self.fy * s,
            None if self.cx is None or not same_way else self.cx * s,
            None if self.cy is None or not same_way else self.cy * s,
            self.dist,
        )
