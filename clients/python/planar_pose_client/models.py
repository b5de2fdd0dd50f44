"""Typed answers of the service (pydantic), mirroring its JSON.

Classes (docs/SPEC.md section 3): 0 = the object is not in view; 1-8 = the camera centre lies in
one octant around the object, in the object frame (origin at its centre, x along its width,
y towards the top of its texture, z towards the viewer): near/far, x side, y side.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

Mode = Literal["whole", "sliding", "proposals"]


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
        description="whole mode: the camera's focal length in image pixels the pose used, "
        "where it was known; None where the service estimated it",
    )
    fx_source: Literal["query", "exif"] | None = Field(
        None, description="where fx came from: the request's fx= or the photo's EXIF"
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


class ModelList(_Answer):
    """GET /v1/models: every served model, the default's name, files that did not load."""

    default: str
    models: list[ModelInfo]
    problems: dict[str, str] = Field(default_factory=dict)
