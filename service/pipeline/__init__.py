"""The inference pipeline: image bytes to plain results (`results.py`), no HTTP.

Its public entry points, the ones the training side uses (`.importlinter`): a graph loaded by
the ONNX contract (`PoseModel`), the batched predictor on it (`Predictor`, configured by the
service's `Settings`, told a camera per image by `KnownFocal`), the zoom pass (`zoomed`,
`detail_of`) and the object proposals (`propose_boxes`).
"""

from service.pipeline.focal import KnownFocal
from service.pipeline.model import Answer, ModelLoadError, PoseModel
from service.pipeline.predictor import Predictor
from service.pipeline.proposals import propose_boxes
from service.pipeline.zoom import detail_of, zoomed
from service.settings import Settings

__all__ = [
    "Answer",
    "KnownFocal",
    "ModelLoadError",
    "PoseModel",
    "Predictor",
    "Settings",
    "detail_of",
    "propose_boxes",
    "zoomed",
]
