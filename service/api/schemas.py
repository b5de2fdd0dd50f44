"""Pydantic models of the HTTP answers (they are the OpenAPI documentation), and the one
turn of the pipeline's results (`service.pipeline.results`) into them (`image_result_out`)."""

from __future__ import annotations

from dataclasses import asdict
from typing import Any, Literal

from pydantic import BaseModel, Field

from service.cameras.schema import CameraOut
from service.pipeline import results
from service.pipeline.results import CornersSource, FocalSource, Lens, Mode, Training


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


class Pose(BaseModel):
    """The camera's pose relative to the object (docs/pose.md): object frame in cm (origin at
    the object's centre, +x right and +y up on its texture, +z out of its face), OpenCV's
    camera frame (x right, y down, z forward)."""

    camera_cm: list[float] = Field(description="Camera centre in the object frame, cm.")
    distance_cm: float = Field(description="|camera_cm|: from the object's centre, cm.")
    azimuth_deg: float = Field(description="atan2(y, x) of the centre: 0 = +x side, 90 = top.")
    elevation_deg: float = Field(description="asin(z / distance): 90 = head-on, 0 = grazing.")
    rvec: list[float] = Field(description="OpenCV rotation vector, object -> camera.")
    tvec_cm: list[float] = Field(description="OpenCV translation, object -> camera, cm.")
    fx: float = Field(description="The focal length the pose used, px of the uploaded image.")
    fx_source: FocalSource
    fx_range: list[float] | None = Field(
        default=None,
        description="fx estimated: the focal lengths [lo, hi] px the view allows (the corners "
        "fit within their noise); null where fx is known.",
    )
    distance_range_cm: list[float] | None = Field(
        default=None, description="fx estimated: the distance over `fx_range`, cm."
    )
    residual_px: float = Field(description="RMS reprojection error of the corners, px.")
    lens: Lens = Field(
        default="none",
        description="The lens undone before the pose: `camera` (the stored camera's "
        "distortion coefficients), `fitted` (one radial coefficient fitted with the texture's "
        "alignment at the photo's resolution), `network` (the radial k1 the corner network "
        "fitted), `none` (a pinhole).",
    )


class RefinementOut(BaseModel):
    """The alignment of the object's texture to the photo at its own resolution."""

    score: float | None = Field(
        description="Correlation of the texture with the photo at the refined corners (-1..1); "
        "null where it was not aligned."
    )
    start_score: float | None = Field(
        description="The same at the start (the network's corners, or the texture's matched "
        "features where the network's were far off); null where not measured."
    )
    half_turned: bool = Field(
        description="The texture matched the photo better turned by a half turn than in the "
        "network's corner order, and the corners were reordered."
    )
    reason: str | None = Field(
        description="Why the network's corners were kept (corners_source = network)."
    )
    elapsed_ms: float


class CellShare(BaseModel):
    index: int
    probability: float


class CellOut(BaseModel):
    """The finer region of the pose in the grid `regions=` asked for (docs/pose.md)."""

    grid: str = Field(examples=["8x3x60"])
    index: int
    azimuth_deg: list[float]
    elevation_deg: list[float]
    distance_cm: list[float | None] = Field(description="[lo, hi) cm; hi null: no limit.")
    label: str
    probability: float = Field(description="Share of the pose's samples in this cell.")
    neighbours: list[CellShare] = Field(
        description="Other cells the pose may be in (the corners' noise and the focal range "
        "sampled), most likely first; empty where the pose is sure."
    )


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
    corners_source: CornersSource | None = Field(
        default=None,
        description="With corners: `refined` (the object's texture aligned to the photo at its "
        "own resolution, started from the network's corners) or `network` (the network's "
        "corners from its 160 x 120 input: the model carries no texture, refinement is off, "
        "or the alignment did not hold, `refinement.reason`).",
    )
    refinement: RefinementOut | None = Field(
        default=None, description="With corners, where the refinement ran: how it went."
    )
    tracked: bool | None = Field(
        default=None,
        description="Streams: the corners were refined from the previous frame's (the network "
        "answers a frame where the track is lost; every STREAM_TRACK_EVERY frames it checks "
        "the track, which stands where the network finds the object within 1 px of it); null "
        "outside streams.",
    )
    fx: float | None = Field(
        default=None,
        description="Whole mode: the camera's focal length the class used, in pixels of the "
        "uploaded image, where it was known; null where the network estimated it.",
    )
    fx_source: FocalSource | None = Field(
        default=None,
        description="Where `fx` came from: the request's fx, a stored camera, the photo's "
        "EXIF 35 mm equivalent focal length (service/pipeline/exif.py), the stream's learned "
        "camera or the photos of a same_camera request; null where it was estimated.",
    )
    image_size: list[int] | None = Field(
        default=None,
        description="(W, H) px of the uploaded image after EXIF orientation: the frame of "
        "`corners`, `box` and `pose`.",
    )
    pose: Pose | None = Field(
        default=None,
        description="Whole mode, corner models, object in view: the camera's full pose.",
    )
    cell: CellOut | None = Field(
        default=None, description="With regions=GRID and a pose: the pose's finer region."
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
        404: "Unknown model or camera.",
        415: "Unsupported content type.",
        422: "Bad parameters (e.g. mode).",
        503: "Model not loaded (yet).",
    }.items()
}


class CameraList(BaseModel):
    cameras: list[CameraOut]


class ModelInfo(BaseModel):
    """One served model, from its card."""

    name: str = Field(description="Name in URLs (/v1/models/{name}/predict): the file stem.")
    default: bool = Field(description="True for the model /v1/predict answers with.")
    loaded: bool = Field(
        description="Its graph is loaded in the worker that answered (else it loads on its "
        "first request, within a second for a corner model; POSE_MODEL_MEMORY_MB)."
    )
    card_name: str
    version: str | None = None
    profile: str | None = Field(default=None, description="The object the model knows.")
    input: list[int] = Field(description="Network input (W, H) in pixels.")
    accuracy: dict[str, Any] = Field(default_factory=dict, description="Measured, per data set.")
    training: Training = Field(
        description="How it knows its object: `zero-shot` (the generic corner network with the "
        "object's picture, not trained on it; its card's `zero_shot` says what it measured), "
        "`fine-tuned` (trained from that network) or `trained`."
    )


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


def image_result_out(result: results.ImageResult) -> ImageResult:
    """The API's answer for one image from the pipeline's (field for field, the same JSON)."""
    return ImageResult.model_validate(asdict(result))
