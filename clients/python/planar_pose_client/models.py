"""Typed answers of the service (pydantic), mirroring its JSON.

Classes (docs/SPEC.md section 3): 0 = the object is not in view; 1-8 = the camera centre lies in
one octant around the object, in the object frame (origin at its centre, x along its width,
y towards the top of its texture, z towards the viewer): near/far, x side, y side.
"""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal, Self

from pydantic import BaseModel, ConfigDict, Field, model_validator

Mode = Literal["whole", "sliding", "proposals"]
#: Where the focal length of a pose came from (docs/pose.md): the request's `fx=`, a stored
#: camera (`camera=ID`), the photo's EXIF, the stream's learned camera, or this view alone.
FxSource = Literal["query", "camera", "exif", "stream", "estimated"]


class _Answer(BaseModel):
    """Read-only; fields the service adds later are ignored, not an error."""

    model_config = ConfigDict(frozen=True, extra="ignore")


class Region(_Answer):
    """A class in words. For class 0 (`present` False) depth, x and y are None."""

    present: bool
    depth: Literal["near", "far"] | None
    x: Literal["+", "-"] | None
    y: Literal["+", "-"] | None
    label: str = Field(description='e.g. "near, x+, y-" or "object not in view"')


class Box(_Answer):
    """A window in pixels of the uploaded image (after EXIF orientation): top-left corner
    (x, y), width w and height h."""

    x: int
    y: int
    w: int
    h: int


class Detection(_Answer):
    """A window the sliding search kept (after non-maximum suppression)."""

    class_id: int = Field(ge=1, le=8)
    confidence: float = Field(ge=0.0, le=1.0)
    box: Box


class Pose(_Answer):
    """The camera's pose (docs/pose.md). Object frame: origin at the object's centre, object in
    z = 0, +x right and +y up on its texture, +z out of the printed face, centimetres. Camera
    frame: OpenCV's (x right, y down, z forward)."""

    camera_cm: tuple[float, float, float] = Field(
        description="the camera centre in the object frame, cm (c = -R^T t)"
    )
    distance_cm: float = Field(ge=0.0, description="|c|: from the object's centre, cm")
    azimuth_deg: float = Field(
        description="atan2(c_y, c_x) in (-180, 180]: 0 = from the object's +x side, 90 = from "
        "its top (+y)"
    )
    elevation_deg: float = Field(description="asin(c_z / |c|): 90 = straight on, 0 = grazing")
    rvec: tuple[float, float, float] = Field(
        description="OpenCV's rotation (object -> camera), Rodrigues vector"
    )
    tvec_cm: tuple[float, float, float] = Field(
        description="OpenCV's translation (object -> camera), cm: X_cam = R X_obj + t"
    )
    fx: float = Field(gt=0.0, description="the focal length used, px of the uploaded image")
    fx_source: FxSource = Field(description="where fx came from")
    fx_range: tuple[float, float] | None = Field(
        None,
        description="fx estimated: the focal lengths the view allows; None where fx is known",
    )
    distance_range_cm: tuple[float, float] | None = Field(
        None, description="the distance over fx_range (how sure it is); None where fx is known"
    )
    residual_px: float = Field(
        ge=0.0, description="RMS reprojection error of the four corners, px of the image"
    )


class CellNeighbour(_Answer):
    """A cell next to the pose's that the pose's uncertainty reaches."""

    index: int = Field(ge=0)
    probability: float = Field(ge=0.0, le=1.0)


class Cell(_Answer):
    """The finer region of the pose on the grid asked for with `regions=` (docs/pose.md)."""

    grid: str = Field(description='the grid, e.g. "8x3x60" (azimuth x elevation x distances)')
    index: int = Field(ge=0, description="the cell's number on the grid")
    azimuth_deg: tuple[float, float] = Field(description="the cell's azimuth bounds, degrees")
    elevation_deg: tuple[float, float] = Field(description="its elevation bounds, degrees")
    distance_cm: tuple[float, float | None] | None = Field(
        None, description="its distance bounds, cm (upper None: unbounded)"
    )
    label: str = Field(description='e.g. "az 22.5..67.5, el 30..60, d 0..60"')
    probability: float = Field(ge=0.0, le=1.0, description="how likely the pose lies in it")
    neighbours: list[CellNeighbour] = Field(
        default_factory=list, description="neighbouring cells and their probabilities"
    )


class Prediction(_Answer):
    """The answer for one image."""

    filename: str | None = Field(description="the upload's file name (None for a raw body)")
    class_id: int = Field(ge=0, le=8, description="0 = not in view, 1..8 = octant")
    region: Region
    probabilities: list[float] = Field(min_length=9, max_length=9, description="classes 0..8")
    confidence: float = Field(ge=0.0, le=1.0, description="probability of class_id")
    box: Box | None = Field(description="sliding mode: the best window; else None")
    detections: list[Detection] | None = Field(
        None, description="sliding mode: every window kept, best first; whole mode: None"
    )
    corners: list[tuple[float, float]] | None = Field(
        None,
        description="whole mode, models with corners, object in view: the object's four "
        "corners (x, y) in image pixels, order (-X,-Y), (+X,-Y), (+X,+Y), (-X,+Y) (a corner "
        "the photo cuts off lies outside the image); else None",
    )
    fx: float | None = Field(
        None,
        description="whole mode: the camera's focal length in image pixels the class used, "
        "where it was known; None where the service estimated it (then see pose.fx)",
    )
    fx_source: FxSource | None = Field(
        None, description="where fx came from: the request's fx=, the photo's EXIF, a camera"
    )
    image_size: tuple[int, int] | None = Field(
        None,
        description="(W, H) px of the uploaded image after EXIF orientation: the frame of "
        "corners, box and pose (services without it: None)",
    )
    pose: Pose | None = Field(
        None,
        description="whole mode, corner models, object in view: the camera's full pose "
        "(services without it: None)",
    )
    cell: Cell | None = Field(
        None, description="with `regions=`: the finer region of the pose and its neighbours"
    )
    elapsed_ms: float = Field(ge=0.0, description="time the service spent on this image")

    @property
    def present(self) -> bool:
        """True when the object is in view (class 1..8)."""
        return self.region.present

    @property
    def label(self) -> str:
        """The region in words, e.g. "far, x-, y+"."""
        return self.region.label


class PredictResponse(_Answer):
    """The whole answer of POST /v1/predict: one result per image, in the order sent."""

    model: str
    mode: Mode
    results: list[Prediction]


class ClassInfo(_Answer):
    """One of the 9 classes on the model card."""

    id: int = Field(ge=0, le=8)
    label: str = Field(description='the region in words, e.g. "near, x+, y-"')
    description: str = Field("", description="where the camera centre is, in the object frame")


class ModelCard(BaseModel):
    """GET /v1/model: the served model's card. Named fields are the ones every card has; any
    other field the service sends is kept as an extra attribute (see `model_extra`)."""

    model_config = ConfigDict(frozen=True, extra="allow", protected_namespaces=())

    name: str
    version: str
    date: str | None = Field(None, description="export time, ISO 8601")
    input: tuple[int, int] = Field(description="network input size (W, H) in pixels")
    classes: list[ClassInfo] = Field(min_length=9, max_length=9)
    profile: dict[str, Any] = Field(default_factory=dict, description="the object it knows")
    training: dict[str, Any] = Field(default_factory=dict, description="data, seed, epochs")
    accuracy: dict[str, Any] = Field(default_factory=dict, description="measured, per data set")
    notes: str = ""


class ModelInfo(_Answer):
    """One served model (GET /v1/models)."""

    model_config = ConfigDict(frozen=True, extra="ignore", protected_namespaces=())

    name: str = Field(description="the name to pass as `model=`")
    default: bool = Field(description="True for the model that answers without `model=`")
    card_name: str
    version: str | None = None
    profile: str | None = Field(None, description="the object the model knows")
    input: tuple[int, int] = Field(description="network input size (W, H) in pixels")
    accuracy: dict[str, Any] = Field(default_factory=dict, description="measured, per data set")
    training: Literal["zero-shot", "fine-tuned", "trained"] | None = Field(
        None,
        description="how it knows its object: zero-shot (the generic corner network with the "
        "object's picture, not trained on it), fine-tuned (from that network) or trained "
        "(None: a server that does not say)",
    )


class ModelList(_Answer):
    """GET /v1/models: every served model, the default's name, files that did not load."""

    default: str
    models: list[ModelInfo]
    problems: dict[str, str] = Field(default_factory=dict)


#: The bounds of a camera's intrinsics, the service's own (its docs/pose.md, "Stored cameras";
#: `service/cameras/schema.py`): fx, fy px; fy / fx; OpenCV's 4, 5 or 8 distortion coefficients
#: (k1, k2, p1, p2[, k3[, k4, k5, k6]]) with |p| and |k| at most these (the rational model's,
#: 8 coefficients, larger); the principal point within the image.
FX_BOUNDS_PX = (1.0, 100_000.0)
FY_OVER_FX = (0.5, 2.0)
DIST_LENGTHS = (4, 5, 8)
DIST_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")
TANGENTIAL_MAX = 0.1
RADIAL_MAX = 10.0
RATIONAL_MAX = 100.0
SIZE_MAX_PX = 100_000

_Finite = Annotated[float, Field(allow_inf_nan=False)]


def camera_problem(
    fx: float,
    fy: float | None,
    cx: float | None,
    cy: float | None,
    dist: list[float] | None,
    size: tuple[int, int] | None,
) -> str | None:
    """Why intrinsics are not a real camera's (the service's rules), or None."""
    if size is None and (cx is not None or cy is not None):
        return "cx, cy: give the image's width and height with them"
    for name, value, side in (("cx", cx, size and size[0]), ("cy", cy, size and size[1])):
        if value is not None and side and not 0.0 <= value <= side:
            return f"{name}: must lie within the image (0 to {side} px), got {value:g}"
    if fy is not None and not FY_OVER_FX[0] <= fy / fx <= FY_OVER_FX[1]:
        return f"fy / fx: must lie within {FY_OVER_FX[0]:g} to {FY_OVER_FX[1]:g}, got {fy / fx:g}"
    if dist is None:
        return None
    if len(dist) not in DIST_LENGTHS:
        return f"dist: OpenCV's 4, 5 or 8 coefficients, got {len(dist)}"
    radial = RATIONAL_MAX if len(dist) == 8 else RADIAL_MAX
    for name, value in zip(DIST_NAMES, dist, strict=False):
        bound = TANGENTIAL_MAX if name.startswith("p") else radial
        if abs(value) > bound:
            return f"dist: {name} must lie within +-{bound:g} with {len(dist)} coefficients"
    return None


class CameraIntrinsics(BaseModel):
    """A camera's intrinsics as POST /v1/cameras takes them, checked as the service does
    (strict types: numbers, not booleans or strings; the bounds above): a camera the service
    would refuse fails here, before anything is sent."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    fx: float = Field(ge=FX_BOUNDS_PX[0], le=FX_BOUNDS_PX[1], allow_inf_nan=False)
    fy: float | None = Field(None, ge=FX_BOUNDS_PX[0], le=FX_BOUNDS_PX[1], allow_inf_nan=False)
    cx: float | None = Field(None, allow_inf_nan=False)
    cy: float | None = Field(None, allow_inf_nan=False)
    dist: list[_Finite] | None = Field(None, min_length=4, max_length=8)
    width: int | None = Field(None, ge=1, le=SIZE_MAX_PX)
    height: int | None = Field(None, ge=1, le=SIZE_MAX_PX)
    name: str | None = Field(None, max_length=100)

    @model_validator(mode="after")
    def _real(self) -> Self:
        if (self.width is None) != (self.height is None):
            raise ValueError("width and height: give both or neither")
        size = None if self.width is None or self.height is None else (self.width, self.height)
        problem = camera_problem(self.fx, self.fy, self.cx, self.cy, self.dist, size)
        if problem is not None:
            raise ValueError(problem)
        return self


class Camera(_Answer):
    """A camera the service stores (POST /v1/cameras): a focal length (and optionally fy,
    principal point, distortion) at an image size. `camera=ID` on predict and the stream
    uses it; its fx is scaled to each image's width when `width` is known."""

    id: str = Field(description='the id to pass as `camera=`, e.g. "c-3f2a9b1c"')
    name: str | None = None
    fx: float = Field(gt=0.0, description="focal length, px at `width`")
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    dist: list[float] | None = Field(None, description="OpenCV distortion [k1, k2, p1, p2, k3]")
    width: int | None = Field(None, description="the image width fx is given at, px")
    height: int | None = None
    source: Literal["intrinsics", "photos"] = Field(
        description="intrinsics: given as numbers; photos: learned from photos of the object"
    )
    photos_used: int | None = Field(None, description="source photos: the photos the fit used")
    residual_px: float | None = Field(None, description="source photos: RMS error of the fit")
    fx_range: tuple[float, float] | None = Field(
        None, description="source photos: the focal lengths the photos allow, where sent"
    )
    created: datetime | None = None


class CameraList(_Answer):
    """GET /v1/cameras: every stored camera, newest first."""

    cameras: list[Camera]
