"""Pydantic models of the HTTP answers (they are the OpenAPI documentation)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, Field

Mode = Literal["whole", "sliding", "proposals"]
FocalSource = Literal["query", "exif"]  # where a known focal length came from


class RegionOut(BaseModel):
    """A pose class in words (`service.core.regions`); for class 0 only `present` and `label`
    matter."""

    present: bool
    depth: Literal["near", "far"] | None
    x: Literal["+", "-"] | None
    y: Literal["+", "-"] | None
    label: str = Field(examples=["near, x+, y-"])


class Box(BaseModel):
    """A window in pixels of the uploaded image after EXIF orientation (origin top left)."""

    x: int
    y: int
    w: int
    h: int


class Detection(BaseModel):
    """A window kept by non-maximum suppression (sliding mode), best first."""

    class_id: int = Field(ge=1, le=8)
    confidence: float
    box: Box


class ImageResult(BaseModel):
    """The answer for one image."""

    filename: str | None
    class_id: int = Field(ge=0, le=8, description="0 = object not in view, 1-8 = pose region.")
    region: RegionOut
    probabilities: list[float] = Field(description="9 probabilities, index = class id, sum 1.")
    confidence: float = Field(description="The largest probability.")
    box: Box | None = Field(description="Best window (sliding mode, object found), else null.")
    detections: list[Detection] | None = Field(
        default=None, description="Sliding mode: all windows kept by NMS, best first."
    )
    corners: list[list[float]] | None = Field(
        default=None,
        description="Whole mode, models with a corners output (the keypoint networks), object "
        "in view: the object's four corners [x, y] in pixels of the uploaded image (after "
        "EXIF orientation, pixel centres at integers), in the order (-X,-Y), (+X,-Y), "
        "(+X,+Y), (-X,+Y) of the object frame (a corner the photo cuts off lies outside "
        "the image); with the camera's intrinsics they give the "
        "full pose (e.g. cv2.solvePnP). Else null.",
    )
    fx: float | None = Field(
        default=None,
        description="Whole mode: the camera's focal length the pose used, in pixels of the "
        "uploaded image, where it was known; null where the pose estimated it.",
    )
    fx_source: FocalSource | None = Field(
        default=None,
        description="Where `fx` came from: the request's fx parameter or the photo's EXIF "
        "35 mm equivalent focal length (service/exif.py); null where it was estimated.",
    )
    elapsed_ms: float = Field(
        description="Decoding and preprocessing this image plus its share of the batched "
        "network call (milliseconds)."
    )


class PredictResponse(BaseModel):
    model: str = Field(description="Name of the model that answered.")
    mode: Mode
    results: list[ImageResult]


class ErrorBody(BaseModel):
    code: str = Field(examples=["undecodable_image"])
    message: str


class ErrorResponse(BaseModel):
    error: ErrorBody


class Status(BaseModel):
    status: str = Field(examples=["ok"])
    model: str | None = None


#: OpenAPI `responses` of the error statuses, all in the one error shape.
ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorResponse, "description": text}
    for code, text in {
        400: "Undecodable or empty image, malformed body.",
        401: "API key missing or wrong (when POSE_API_KEY is set).",
        413: "Body too large, too many images, or too many pixels in an image.",
        415: "Unsupported content type.",
        422: "Bad parameters (e.g. mode).",
        503: "Model not loaded (yet).",
    }.items()
}


class ModelInfo(BaseModel):
    """One served model, from its card."""

    name: str = Field(description="Name in URLs (/v1/models/{name}/predict): the file stem.")
    default: bool = Field(description="True for the model /v1/predict answers with.")
    card_name: str
    version: str | None = None
    profile: str | None = Field(default=None, description="The object the model knows.")
    input: list[int] = Field(description="Network input (W, H) in pixels.")
    accuracy: dict[str, Any] = Field(default_factory=dict, description="Measured, per data set.")


class ModelsResponse(BaseModel):
    default: str = Field(description="Name of the default model.")
    models: list[ModelInfo]
    problems: dict[str, str] = Field(
        default_factory=dict, description="Model files that could not be loaded, and why."
    )


class ReloadResponse(BaseModel):
    models: list[str] = Field(description="Names served after the reload.")
    loaded: list[str] = Field(description="Loaded anew (new or changed files).")
    removed: list[str] = Field(description="No longer served (files gone).")
    problems: dict[str, str] = Field(description="Files refused; a model keeps its old session.")
