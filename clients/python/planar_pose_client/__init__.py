"""Python SDK of the planar-pose service: which region of space a planar object is seen from.

    from planar_pose_client import PoseClient

    with PoseClient("http://127.0.0.1:8000") as client:
        pred = client.predict("photo.jpg")          # or bytes, a binary file, a numpy array
        print(pred.class_id, pred.label, f"{pred.confidence:.2f}")

`AsyncPoseClient` has the same methods as coroutines. Failures raise `PoseError` subclasses.
"""

from ._core import RetryPolicy
from .client import AsyncPoseClient, PoseClient
from .errors import (
    AuthError,
    BadImageError,
    InvalidRequestError,
    ModelNotFoundError,
    PoseConnectionError,
    PoseError,
    ServiceUnavailable,
    TooLargeError,
    UnsupportedMediaError,
)
from .images import ImageInput, encode_png
from .models import (
    Box,
    ClassInfo,
    Detection,
    Mode,
    ModelCard,
    ModelInfo,
    ModelList,
    Prediction,
    PredictResponse,
    Region,
)

__all__ = [
    "AsyncPoseClient",
    "AuthError",
    "BadImageError",
    "ClassInfo",
    "Detection",
    "Box",
    "ImageInput",
    "InvalidRequestError",
    "ModelCard",
    "ModelNotFoundError",
    "ModelInfo",
    "ModelList",
    "Mode",
    "PoseClient",
    "PoseConnectionError",
    "PoseError",
    "PredictResponse",
    "Prediction",
    "Region",
    "RetryPolicy",
    "ServiceUnavailable",
    "TooLargeError",
    "UnsupportedMediaError",
    "encode_png",
]
