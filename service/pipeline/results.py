"""What the pipeline answers: plain dataclasses, no HTTP (`service.api.schemas` turns them into
the API's JSON, field for field: the names and meanings are the schemas').

An `ImageResult` is built by the predictor step by step (class, then corners, pose, cell);
the stream's smoothing replaces fields of a copy (`dataclasses.replace`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

Mode = Literal["whole", "sliding", "proposals"]
#: Where the focal length of a pose came from: the request's `fx`, a stored camera
#: (`camera=`), the photo's EXIF, the stream's learned camera, or the view itself.
FocalSource = Literal["query", "camera", "exif", "stream", "estimated"]
#: The lens a pose undid before its pinhole geometry: the stored camera's distortion
#: (OpenCV's coefficients), the radial lens fitted by aligning the object's texture, the
#: radial k1 the corner network fitted, or none.
Lens = Literal["camera", "fitted", "network", "none"]
#: Where an answer's corners come from: the texture aligned at the photo's own resolution
#: (service/core/refine.py), or the corner network's as they are.
CornersSource = Literal["refined", "network"]
#: How a model came to know its object (`service.pipeline.model.training_of`).
Training = Literal["zero-shot", "fine-tuned", "trained"]


@dataclass(frozen=True)
class Region:
    """A pose class in words (`service.core.regions.region_of_class`)."""

    present: bool
    depth: Literal["near", "far"] | None
    x: Literal["+", "-"] | None
    y: Literal["+", "-"] | None
    label: str


@dataclass(frozen=True)
class Box:
    """A window in pixels of the uploaded image after EXIF orientation (origin top left)."""

    x: int
    y: int
    w: int
    h: int


@dataclass(frozen=True)
class Detection:
    """A window kept by non-maximum suppression (sliding mode), best first."""

    class_id: int
    confidence: float
    box: Box


@dataclass(frozen=True)
class Pose:
    """The camera's pose relative to the object (docs/pose.md), cm and px of the upload."""

    camera_cm: list[float]
    distance_cm: float
    azimuth_deg: float
    elevation_deg: float
    rvec: list[float]
    tvec_cm: list[float]
    fx: float
    fx_source: FocalSource
    fx_range: list[float] | None
    distance_range_cm: list[float] | None
    residual_px: float
    lens: Lens = "none"


@dataclass(frozen=True)
class RefinementReport:
    """How the alignment of the object's texture at the photo's resolution went."""

    score: float | None
    start_score: float | None
    half_turned: bool
    reason: str | None
    elapsed_ms: float


@dataclass(frozen=True)
class CellShare:
    index: int
    probability: float


@dataclass(frozen=True)
class Cell:
    """The finer region of a pose in a `RegionGrid` (docs/pose.md)."""

    grid: str
    index: int
    azimuth_deg: list[float]
    elevation_deg: list[float]
    distance_cm: list[float | None]
    label: str
    probability: float
    neighbours: list[CellShare]


@dataclass
class ImageResult:
    """The answer for one image (the API's `ImageResult` says what each field means)."""

    filename: str | None
    class_id: int
    region: Region
    probabilities: list[float]
    confidence: float
    elapsed_ms: float
    box: Box | None = None
    detections: list[Detection] | None = None
    corners: list[list[float]] | None = None
    corners_source: CornersSource | None = None
    refinement: RefinementReport | None = None
    tracked: bool | None = None
    fx: float | None = None
    fx_source: FocalSource | None = None
    image_size: list[int] | None = None
    pose: Pose | None = None
    cell: Cell | None = None
