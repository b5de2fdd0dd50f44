"""A stored camera's record (pydantic: it validates the rows of the store and the JSON of
`POST /v1/cameras`), checked against the bounds of real lenses and sensors."""

from __future__ import annotations

from typing import Annotated, Literal, Self

from pydantic import BaseModel, ConfigDict, Field, model_validator

from service.pipeline.focal import FX_MAX_PX, FX_MIN_PX

#: The bounds of a camera's intrinsics (docs/pose.md, "Stored cameras"): what real lenses and
#: sensors give, with room to spare. fx, fy px; fy / fx (the pixel aspect); the principal point
#: within the image; OpenCV's distortion (k1, k2, p1, p2[, k3[, k4, k5, k6]]): 4, 5 or 8
#: coefficients, tangential |p| and radial |k| at most these (the rational model's k1-k6, 8
#: coefficients, cancel each other and run larger). The SDK's models check the same bounds.
FX_BOUNDS_PX = (FX_MIN_PX, FX_MAX_PX)  # the range a request's fx may take too
FY_OVER_FX = (0.5, 2.0)
DIST_LENGTHS = (4, 5, 8)
DIST_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")
TANGENTIAL_MAX = 0.1
RADIAL_MAX = 10.0
RATIONAL_MAX = 100.0
SIZE_MAX_PX = 100_000


def _distortion_problem(dist: list[float]) -> str | None:
    """Why OpenCV's distortion coefficients `dist` are not a real lens's, or None."""
    if len(dist) not in DIST_LENGTHS:
        return (
            f"dist: OpenCV's 4, 5 or 8 coefficients (k1, k2, p1, p2[, k3[, k4, k5, k6]]), "
            f"got {len(dist)}"
        )
    radial = RATIONAL_MAX if len(dist) == 8 else RADIAL_MAX
    for name, value in zip(DIST_NAMES, dist, strict=False):
        bound = TANGENTIAL_MAX if name.startswith("p") else radial
        if abs(value) > bound:
            return (
                f"dist: {name} must lie within +-{bound:g} with {len(dist)} coefficients, "
                f"got {value:g}"
            )
    return None


class CameraFields(BaseModel):
    """A camera's intrinsics, px of images `width` x `height`, checked strictly (numbers only,
    no booleans or strings) against the bounds above."""

    model_config = ConfigDict(strict=True)

    fx: float = Field(ge=FX_BOUNDS_PX[0], le=FX_BOUNDS_PX[1], allow_inf_nan=False)
    fy: float | None = Field(
        default=None, ge=FX_BOUNDS_PX[0], le=FX_BOUNDS_PX[1], allow_inf_nan=False
    )
    cx: float | None = Field(default=None, allow_inf_nan=False, description="0 to width, px.")
    cy: float | None = Field(default=None, allow_inf_nan=False, description="0 to height, px.")
    dist: list[Annotated[float, Field(allow_inf_nan=False)]] | None = Field(
        default=None,
        min_length=4,
        max_length=8,
        description="OpenCV distortion coefficients k1, k2, p1, p2[, k3[, k4, k5, k6]] "
        f"(4, 5 or 8; |p| <= {TANGENTIAL_MAX:g}, |k| <= {RADIAL_MAX:g}, rational model "
        f"{RATIONAL_MAX:g}).",
    )
    width: int | None = Field(default=None, ge=1, le=SIZE_MAX_PX, description="Image width, px.")
    height: int | None = Field(default=None, ge=1, le=SIZE_MAX_PX, description="Image height, px.")

    @model_validator(mode="after")
    def _real(self) -> Self:
        problem = self._size_problem() or self._lens_problem()
        if problem is not None:
            raise ValueError(problem)
        return self

    def _size_problem(self) -> str | None:
        if (self.width is None) != (self.height is None):
            return "width and height: give both or neither"
        if self.width is None or self.height is None:
            if self.cx is not None or self.cy is not None:
                return "cx, cy: give the image's width and height with them"
            return None
        for name, value, side in (("cx", self.cx, self.width), ("cy", self.cy, self.height)):
            if value is not None and not 0.0 <= value <= side:
                return f"{name}: must lie within the image (0 to {side} px), got {value:g}"
        return None

    def _lens_problem(self) -> str | None:
        if self.fy is not None and not FY_OVER_FX[0] <= self.fy / self.fx <= FY_OVER_FX[1]:
            return (
                f"fy / fx: must lie within {FY_OVER_FX[0]:g} to {FY_OVER_FX[1]:g} (the pixel "
                f"aspect), got {self.fy:g} / {self.fx:g}"
            )
        return None if self.dist is None else _distortion_problem(self.dist)


class CameraIn(CameraFields):
    """A camera's intrinsics (POST /v1/cameras as JSON), px of images `width` x `height`."""

    model_config = ConfigDict(strict=True, extra="forbid")

    name: str | None = Field(default=None, max_length=100)


class CameraOut(CameraFields):
    """A stored camera (docs/pose.md)."""

    id: str
    name: str | None = None
    source: Literal["intrinsics", "photos"]
    photos_used: int = Field(default=0, ge=0, description="From photos: those the fit kept.")
    residual_px: float | None = Field(
        default=None,
        ge=0.0,
        allow_inf_nan=False,
        description="From photos: RMS reprojection error of their corners, px.",
    )
    fx_range: list[Annotated[float, Field(allow_inf_nan=False)]] | None = Field(
        default=None,
        min_length=2,
        max_length=2,
        description="From photos: the focal lengths [lo, hi] px they allow.",
    )
    k1_se: float | None = Field(
        default=None,
        description="From photos: the standard error of the learned lens's k1 (`dist`, "
        "OpenCV's coefficients; null where the photos fitted no lens: fx alone is learned "
        "where it is above 0.05).",
    )
    created: str
